"""Recordings: what sensors delivered along a load path, on disk, for ``--data``.

A recording is a folder with two files::

    recording.toml   the manifest (below)
    frames.npz       the arrays (numpy's zip of .npy files, never pickle)

``recording.toml``::

    format = 1
    units = "m"                  # every length is in metres
    model = "solid"              # the model it is for (compare --model)
    scenario = "grasp-lift"      # the load: one of the body's manipulations
    observe = "cloud"            # the observation model of the frames
    noise = 0.0001               # m, the markers' noise std (--noise)
    markers = 8                  # markers per frame (--obs-points)
    steps = 20                   # load steps K; one frame per step, in order
    held_out = ["markers", "points", "targets"]   # in frames.npz, scoring only
    frame = "body"               # or "camera": clouds in the camera's frame

    [model_settings]             # the model options (--model-option)
    body = "liver"

    [true]                       # optional: the true parameters, if known
    E = 4000.0

    [observe_settings.cloud]     # optional: the observation model's settings
    points = 1000

``frames.npz`` holds ``time`` (K,) in seconds (increasing), ``load`` (K,) the
applied load as the fraction k/K of the scenario's end load (the load in the
body's terms: step k of its manipulation), and for each frame k (1..K,
``FFFFF`` = ``k`` in five digits) the observation model's frame data
``frame.FFFFF/NAME``: ``markers`` (3M,) the marker displacements (NaN in
x, y and z of a marker occluded in that frame: the estimators assimilate the
visible ones, :mod:`idbench.observe.occlusion`; a frame with every marker NaN is a
step without observation); ``points``
(N, 3) (N may differ from frame to frame), ``origin`` (3,) and ``sigma`` ()
for a cloud (points in the body's coordinates, m; ``origin`` the camera
centre; ``sigma`` the noise std along the rays); ``force`` (c,) in N; in a
combination ``BLOCK/NAME`` (``cloud/points``, ``force/force``). Held out,
never given to an estimator: ``held_out/markers`` (K, 3M) marker tracks (NaN
where occluded), ``held_out/targets`` (K, T, 3), the displacements of the
body's ``[targets]``, and ``held_out/points`` (K, N, 3), a cloud per frame
without correspondence (positions, m; NaN rows where a frame has fewer),
scored per step as ``heldout_points_mm``, the mean distance of the points to
the model's deformed surface
(:func:`idbench.observe.surface.heldout_points_mm`). With ``frame =
"camera"`` (clouds only) every position is in the camera's frame and
``rest/points`` (N, 3) is the organ's cloud at rest: each model mesh
registers it to its surface before any run (:mod:`idbench.store.registered`).

:func:`read` checks a recording and says what is wrong in one line naming the
frame (:class:`RecordingError`); :func:`check_body` checks it against the
model's body (a cloud far from it, displacements larger than it);
:func:`write` writes one (``idbench simulate --record``).
"""

from __future__ import annotations

import functools
import hashlib
import math
import os
import tomllib
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from idbench.core.interfaces import FloatArray, ParameterSpec
from idbench.observe.cloud import Cloud
from idbench.observe.kinds import BUILTIN, COMBINE, Frame
from idbench.store import untrusted
from idbench.store.files import atomic_write
from idbench.store.untrusted import HELD_OUT, RecordingError

FORMAT = 1
MANIFEST = "recording.toml"
ARRAYS = "frames.npz"
REST = "rest/points"
UNITS = ("m",)

__all__ = ["HELD_OUT", "Recording", "RecordingError", "read", "write"]


@dataclass(frozen=True)
class Recording:
    """A recording read from disk (see the module).

    Attributes
    ----------
    path
        Its folder.
    model, model_settings, scenario, observe, observe_settings
        What it is of: the model and its options, the load (scenario), the
        observation model and its settings per table.
    steps, markers, noise
        Load steps K, markers per frame M, the markers' noise std.
    true
        The true parameters if the manifest gives them.
    time, load
        Per frame (K,): seconds, and the load-step fraction k/K.
    frames
        One :class:`~idbench.observe.kinds.Frame` per step.
    held_out
        ``markers`` (K, 3M), ``targets`` (K, T, 3) where recorded.
    digest
        SHA-256 of both files (keys the runs).
    frame, rest
        ``"body"`` (the default) or ``"camera"``: the clouds are in the
        camera's frame, and ``rest`` (N, 3) is the organ's cloud at rest in
        it (:mod:`idbench.store.registered` moves them into the body's).
    """

    path: Path
    model: str
    model_settings: dict[str, Any]
    scenario: str
    observe: str
    observe_settings: dict[str, dict[str, Any]]
    steps: int
    markers: int
    noise: float
    true: dict[str, float]
    time: FloatArray
    load: FloatArray
    frames: list[Frame]
    held_out: dict[str, FloatArray] = field(default_factory=dict)
    digest: str = ""
    frame: str = "body"
    rest: FloatArray | None = None


def write(
    path: str | Path,
    manifest: Mapping[str, Any],
    frames: Sequence[Frame],
    held_out: Mapping[str, FloatArray] | None = None,
    time: FloatArray | None = None,
    rest: FloatArray | None = None,
) -> Path:
    """Write a recording folder: ``manifest`` keys as in the module, and arrays.

    ``time`` defaults to one second a step; ``load`` is k/K of each frame;
    ``rest`` the cloud at rest of a recording in the camera's frame.
    """
    root = Path(path)
    root.mkdir(parents=True, exist_ok=True)
    steps = int(manifest["steps"])
    arrays: dict[str, FloatArray] = {
        "time": np.asarray(
            time if time is not None else [f.step for f in frames], dtype=float
        ),
        "load": np.array([f.step / steps for f in frames], dtype=float),
    }
    for f in frames:
        for name, value in f.data.items():
            arrays[f"frame.{f.step:05d}/{name}"] = np.asarray(value, dtype=float)
    for name, value in (held_out or {}).items():
        arrays[f"held_out/{name}"] = np.asarray(value, dtype=float)
    if rest is not None:
        arrays[REST] = np.asarray(rest, dtype=float)
    values = {"format": FORMAT, "units": "m", **manifest}
    values["model_settings"] = {
        k: _relative(v, root) for k, v in values.get("model_settings", {}).items()
    }
    untrusted.manifest(values, f"recording {str(root)!r}")  # what is written reads
    text = _toml(values)

    def save(tmp: Path) -> None:
        with open(tmp, "wb") as fh:
            np.savez(fh, **arrays)  # type: ignore[arg-type]

    atomic_write(root / ARRAYS, save)

    def manifest_file(tmp: Path) -> None:
        tmp.write_text(text, encoding="utf-8")

    atomic_write(root / MANIFEST, manifest_file)
    return root


def read(path: str | Path) -> Recording:
    """Read and check the recording folder ``path`` (cached by content).

    Raises
    ------
    RecordingError
        One line naming the recording, the frame and the problem: a missing
        or unreadable file, an unknown format or unit, frames out of order or
        not one a step, non-finite cloud points, observed markers missing,
        a marker NaN in some of its components only or infinite.
    """
    root = Path(path)
    for name in (MANIFEST, ARRAYS):
        if not (root / name).is_file():
            raise RecordingError(f"recording {str(root)!r}: no {name} in it")
    h = hashlib.sha256()
    for name in (MANIFEST, ARRAYS):
        h.update((root / name).read_bytes())
    key = h.hexdigest()
    return _read(root.resolve(), key)


@functools.lru_cache(maxsize=8)
def _read(root: Path, key: str) -> Recording:
    where = f"recording {str(root)!r}"
    try:
        raw = tomllib.loads((root / MANIFEST).read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, tomllib.TOMLDecodeError) as exc:
        raise RecordingError(f"{where}: {MANIFEST} cannot be read: {exc}") from None
    untrusted.manifest(raw, where)
    if raw["format"] != FORMAT:
        raise RecordingError(
            f"{where}: format = {raw['format']!r}; this idbench reads format {FORMAT}"
        )
    units = raw["units"]
    if units not in UNITS:
        raise RecordingError(
            f"{where}: units = {units!r} cannot be right; every length must be in "
            'metres: units = "m" (convert the arrays first)'
        )
    steps = raw["steps"]
    blocks = str(raw["observe"]).split(COMBINE)
    plugin = any(b not in BUILTIN for b in blocks)
    tables = raw.get("observe_settings", {}).values()
    points = [t["points"] for t in tables if isinstance(t.get("points"), int)]
    if "cloud" in blocks or plugin:
        points.append(Cloud.points)
    limit = untrusted.budget(steps, raw["markers"], max(points, default=0))
    arrays = untrusted.arrays(root / ARRAYS, where, steps, limit, plugin)
    time, load = _timeline(where, arrays, steps)
    frames = []
    for i in range(steps):
        k = i + 1
        prefix = f"frame.{k:05d}/"
        data = {
            n.removeprefix(prefix): v for n, v in arrays.items() if n.startswith(prefix)
        }
        if not data:
            raise RecordingError(f"{where}: frame {k} has no data ({prefix}NAME)")
        _check_frame(where, k, data, int(raw["markers"]))
        frames.append(Frame(k, data))
    held = {
        n.removeprefix("held_out/"): v
        for n, v in arrays.items()
        if n.startswith("held_out/")
    }
    for name, value in held.items():
        if name not in HELD_OUT or len(value) != steps:
            raise RecordingError(
                f"{where}: held_out/{name} of shape {value.shape}: allowed "
                f"{', '.join(HELD_OUT)}, one row per frame ({steps})"
            )
        if name == "points" and (value.ndim != 3 or value.shape[2] != 3):
            raise RecordingError(
                f"{where}: held_out/points of shape {value.shape}: need (K, N, 3), "
                "positions (m), NaN rows where a frame has fewer points"
            )
    frame, rest = str(raw.get("frame", "body")), arrays.get(REST)
    _check_rest(where, frame, rest, blocks)
    return Recording(
        path=root,
        model=str(raw["model"]),
        model_settings={
            k: _resolved(v, root) for k, v in raw.get("model_settings", {}).items()
        },
        scenario=str(raw["scenario"]),
        observe=str(raw["observe"]),
        observe_settings={
            k: dict(v) for k, v in raw.get("observe_settings", {}).items()
        },
        steps=steps,
        markers=int(raw["markers"]),
        noise=float(raw["noise"]),
        true={k: float(v) for k, v in raw.get("true", {}).items()},
        time=time,
        load=load,
        frames=frames,
        held_out=held,
        digest=key,
        frame=frame,
        rest=rest,
    )


def _check_rest(
    where: str, frame: str, rest: FloatArray | None, blocks: list[str]
) -> None:
    """A camera's frame needs clouds alone and a rest cloud; a body's none."""
    if frame != "camera":
        if rest is not None:
            raise RecordingError(
                f'{where}: {REST} is only read with frame = "camera" (the clouds '
                "in the camera's frame); this recording is in the body's"
            )
        return
    if blocks != ["cloud"]:
        raise RecordingError(
            f'{where}: frame = "camera" with observe = {COMBINE.join(blocks)!r}: '
            'only a cloud can be registered (observe = "cloud")'
        )
    if rest is None or rest.ndim != 2 or rest.shape[1] != 3 or len(rest) < 10:
        shape = None if rest is None else rest.shape
        raise RecordingError(
            f'{where}: frame = "camera" needs {REST} in {ARRAYS}, the organ at '
            f"rest in the camera's frame, (N, 3) with N >= 10 (m); got {shape}"
        )
    if not np.all(np.isfinite(rest)):
        raise RecordingError(f"{where}: {REST} has non-finite points")


def _timeline(
    where: str, arrays: Mapping[str, FloatArray], steps: int
) -> tuple[FloatArray, FloatArray]:
    """``time`` and ``load`` (K,), checked: increasing, one frame a step."""
    for name in ("time", "load"):
        if name not in arrays or arrays[name].shape != (steps,):
            shape = arrays[name].shape if name in arrays else None
            raise RecordingError(
                f"{where}: {name} of shape {shape}: need one value per frame ({steps},)"
            )
    time, load = arrays["time"], arrays["load"]
    for i in range(steps):
        k = i + 1
        if not (math.isfinite(time[i]) and math.isfinite(load[i])):
            raise RecordingError(f"{where}: frame {k}: time or load is not finite")
        if i and time[i] <= time[i - 1]:
            raise RecordingError(
                f"{where}: frame {k}: time {time[i]:g} s is not after frame {k - 1}'s "
                f"{time[i - 1]:g} s (frames out of order)"
            )
        if abs(load[i] * steps - k) > 1e-6:
            raise RecordingError(
                f"{where}: frame {k}: load {load[i]:g} is not step {k} of {steps} "
                f"({k / steps:g}); frames must be one a load step, in order"
            )
    return time, load


def _check_frame(
    where: str, k: int, data: Mapping[str, FloatArray], markers: int
) -> None:
    """One frame's arrays: finite cloud points, observed markers all there.

    A marker may be occluded (NaN in x, y and z); a frame where all are is a
    step without observation.
    """
    for name, value in data.items():
        leaf = name.rpartition("/")[2]
        if leaf == "points":
            if value.ndim != 2 or value.shape[1] != 3:
                raise RecordingError(
                    f"{where}: frame {k}: {name} of shape {value.shape}: need (N, 3)"
                )
            bad = int((~np.isfinite(value).all(axis=1)).sum())
            if bad:
                raise RecordingError(
                    f"{where}: frame {k}: the cloud {name} has {bad} of {len(value)} "
                    "points with NaN or infinite coordinates (drop them)"
                )
        elif leaf == "sigma" and not (
            value.shape in ((), (1,)) and np.isfinite(value).all() and value.min() > 0
        ):
            raise RecordingError(
                f"{where}: frame {k}: {name} = {value.tolist()!r}: need one finite "
                "number > 0, the noise std along the rays (m)"
            )
        elif leaf == "origin" and not (
            value.shape == (3,) and np.isfinite(value).all()
        ):
            raise RecordingError(
                f"{where}: frame {k}: {name} of shape {value.shape}: need the "
                "camera centre, 3 finite coordinates (m)"
            )
        elif leaf == "force" and not (value.ndim == 1 and np.isfinite(value).all()):
            raise RecordingError(
                f"{where}: frame {k}: {name} = {np.array2string(value, threshold=6)}"
                ": need a vector of finite forces (N), one per channel"
            )
        elif leaf == "markers" and (value.ndim != 1 or value.size != 3 * markers):
            raise RecordingError(
                f"{where}: frame {k}: {name} of shape {value.shape}; markers = "
                f"{markers} needs {3 * markers} (x, y, z of each)"
            )
        elif leaf == "markers":
            _check_markers(where, k, name, value)


def _check_markers(where: str, k: int, name: str, value: FloatArray) -> None:
    """Observed markers (3M,): each finite, or occluded (NaN in x, y and z)."""
    xyz = np.asarray(value, dtype=float).reshape(-1, 3)
    nan = np.isnan(xyz)
    partial = np.flatnonzero(nan.any(axis=1) & ~nan.all(axis=1))
    if partial.size:
        j = int(partial[0])
        axes = ", ".join("xyz"[i] for i in np.flatnonzero(nan[j]))
        raise RecordingError(
            f"{where}: frame {k}: marker {j + 1} of {name} is NaN in {axes} only; "
            "an occluded marker is NaN in all of x, y and z (a visible one in none)"
        )
    infinite = np.flatnonzero(np.isinf(xyz).any(axis=1))
    if infinite.size:
        j = int(infinite[0])
        raise RecordingError(
            f"{where}: frame {k}: marker {j + 1} of {name} is infinite; a value is "
            "finite, or NaN in x, y and z where the marker is occluded"
        )


def check_frames(rec: Recording, observation: Any) -> None:
    """Every frame has what ``observation`` (its observation model) reads.

    Raises
    ------
    RecordingError
        Naming the first frame whose data the model cannot read.
    """
    for frame in rec.frames:
        try:
            observation.values(frame)
        except (KeyError, ValueError, IndexError) as exc:
            have = ", ".join(sorted(frame.data))
            raise RecordingError(
                f"recording {str(rec.path)!r}: frame {frame.step}: observe "
                f"{rec.observe!r} cannot read it ({type(exc).__name__}: {exc}); "
                f"the frame has {have}"
            ) from None


def check_body(rec: Recording, bounds: Any, scenarios: Sequence[str]) -> None:
    """Check ``rec`` against the model's body: its load, where and how large.

    ``bounds`` is the model's undeformed bounding box (2, 3) (None: not
    checked); ``scenarios`` the loads the model has.

    Raises
    ------
    RecordingError
        A load the body does not have; a cloud farther from the body than its
        size (not registered to the body's coordinates); a marker or target
        displacement larger than the body (units that cannot be metres).
    """
    where = f"recording {str(rec.path)!r}"
    if rec.scenario not in scenarios:
        raise RecordingError(
            f"{where}: load {rec.scenario!r} is not one the body has; it has "
            f"{', '.join(sorted(scenarios))}"
        )
    if bounds is None:
        return
    box = np.asarray(bounds, dtype=float)
    size = float(np.linalg.norm(box[1] - box[0]))
    for frame in rec.frames:
        for name, value in frame.data.items():
            leaf = name.rpartition("/")[2]
            if leaf == "points":
                _registered(where, frame.step, name, value, box, size)
            if leaf == "markers":
                _plausible(where, frame.step, name, value, size)
    for name, value in rec.held_out.items():
        for i, row in enumerate(value):
            if name == "points":  # positions, not displacements
                _registered(where, i + 1, "held_out/points", row, box, size)
            else:
                _plausible(where, i + 1, f"held_out/{name}", row, size)


def _registered(
    where: str, k: int, name: str, value: FloatArray, box: Any, size: float
) -> None:
    """A cloud whose median lies within the body's size of its box, else one line."""
    pts = np.asarray(value, dtype=float).reshape(-1, 3)
    pts = pts[np.isfinite(pts).all(axis=1)]
    if not len(pts):
        return
    centre = np.median(pts, axis=0)
    away = float(np.linalg.norm(centre - np.clip(centre, box[0], box[1])))
    if away > size:
        raise RecordingError(
            f"{where}: frame {k}: the cloud {name} lies {away:.3g} m from the body "
            f"(which is {size:.3g} m across): it is not registered to the body's "
            "coordinates"
        )


def _plausible(where: str, k: int, name: str, value: FloatArray, size: float) -> None:
    """A displacement no larger than the body, else units that cannot be m."""
    u = np.asarray(value, dtype=float).reshape(-1, 3)
    largest = float(np.nanmax(np.linalg.norm(u, axis=1), initial=0.0))
    if largest > size:
        raise RecordingError(
            f"{where}: frame {k}: {name} moves {largest:.3g} m, more than the body's "
            f'size ({size:.3g} m): units = "m" cannot be right'
        )


def _relative(value: Any, root: Path) -> Any:
    """A model option naming a file, as a path relative to the recording folder."""
    if isinstance(value, str) and os.sep in value and Path(value).is_file():
        return os.path.relpath(Path(value).resolve(), root.resolve())
    return value


def _resolved(value: Any, root: Path) -> Any:
    """A model option of the manifest, a relative path resolved against ``root``.

    A string with a path separator is a path, and a relative one is relative
    to the recording's folder, never to the working directory: a recording is
    read wherever it lies. A path that names no file there is passed on as
    one, in that folder (the model then says that it finds no such file).
    """
    if not isinstance(value, str) or Path(value).is_absolute():
        return value
    if "/" in value or os.sep in value or (root / value).is_file():
        return str((root / value).resolve())
    return value


def _toml(values: Mapping[str, Any]) -> str:
    """The manifest as TOML (scalars, lists of scalars, tables of them)."""
    lines: list[str] = []
    tables: list[tuple[str, Mapping[str, Any]]] = []
    for key, value in values.items():
        if isinstance(value, Mapping):
            tables.append((key, value))
        else:
            lines.append(f"{key} = {_value(value)}")
    for key, table in tables:
        inner = [(k, v) for k, v in table.items() if isinstance(v, Mapping)]
        lines += ["", f"[{key}]"]
        lines += [
            f"{k} = {_value(v)}" for k, v in table.items() if k not in dict(inner)
        ]
        for name, sub in inner:
            lines += ["", f"[{key}.{name}]"]
            lines += [f"{k} = {_value(v)}" for k, v in sub.items()]
    return "\n".join(lines) + "\n"


_ESCAPES = {
    **{chr(i): f"\\u{i:04X}" for i in (*range(0x20), 0x7F)},
    '"': '\\"',
    "\\": "\\\\",
}
"""What a TOML basic string escapes (the rest of Unicode is written as it is)."""


def _value(v: Any) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, int | float):
        return repr(float(v)) if isinstance(v, float) else str(v)
    if isinstance(v, str):  # a TOML basic string: control characters escaped
        return '"' + "".join(_ESCAPES.get(c, c) for c in v) + '"'
    if isinstance(v, list | tuple):
        return "[" + ", ".join(_value(x) for x in v) + "]"
    raise ValueError(f"cannot write {v!r} to a recording manifest")


def true_values(rec: Recording, spec: ParameterSpec) -> tuple[tuple[str, float], ...]:
    """The true value of each parameter the recording knows, NaN for the others.

    Raises
    ------
    RecordingError
        A true value of no parameter of the model, or outside its bounds.
    """
    names = spec.names
    unknown = sorted(set(rec.true) - set(names))
    if unknown:
        raise RecordingError(
            f"recording {str(rec.path)!r}: [true] {unknown[0]!r} is not a parameter "
            f"of the model; its parameters: {', '.join(names)}"
        )
    for name, low, high in zip(names, spec.lower, spec.upper, strict=True):
        value = rec.true.get(name)
        if value is not None and not low <= value <= high:
            raise RecordingError(
                f"recording {str(rec.path)!r}: [true] {name} = {value:g} is outside "
                f"the model's bounds [{low:g}, {high:g}]"
            )
    return tuple((n, float(rec.true.get(n, math.nan))) for n in names)
