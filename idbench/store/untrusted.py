"""A recording read as untrusted input: its manifest's types, its arrays' sizes.

A recording folder is passed between labs and from an operating room, like a
mesh or a plugin: nothing in it is trusted before it is checked.
:func:`manifest` checks ``recording.toml`` against :data:`MANIFEST_KEYS` (every
key known, every value of its type); :func:`arrays` reads ``frames.npz`` member
by member, with each member's ``.npy`` header read first (its name, dtype and
shape), so that an object array (a pickle), an unknown member or a member
larger than the manifest's frames, markers and points can need is refused
before any of its data is decompressed. Each refusal is one
:class:`RecordingError` line naming the recording, the member or key and what
is allowed.
"""

from __future__ import annotations

import math
import re
import zipfile
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

import numpy as np

from idbench.core.interfaces import ConfigError, FloatArray


class RecordingError(ConfigError):
    """A recording that cannot be used, in one line naming the frame."""


def _whole(low: int) -> Callable[[Any], bool]:
    def check(v: Any) -> bool:
        return isinstance(v, int) and not isinstance(v, bool) and v >= low

    return check


def _number(v: Any) -> bool:
    return (
        isinstance(v, int | float) and not isinstance(v, bool) and math.isfinite(v)
    )


def _name(v: Any) -> bool:
    return isinstance(v, str) and v != "" and v.isprintable()


MANIFEST_KEYS: dict[str, tuple[Callable[[Any], bool], str]] = {
    "format": (_whole(1), "a whole number"),
    "units": (_name, "a string"),
    "model": (_name, "a non-empty printable string"),
    "scenario": (_name, "a non-empty printable string"),
    "observe": (_name, "a non-empty printable string"),
    "noise": (lambda v: _number(v) and v >= 0, "a number >= 0 (m)"),
    "markers": (_whole(0), "a whole number >= 0"),
    "steps": (_whole(1), "a whole number >= 1"),
    "held_out": (
        lambda v: isinstance(v, list) and all(_name(x) for x in v),
        "a list of names",
    ),
    "model_settings": (lambda v: isinstance(v, dict), "a table"),
    "observe_settings": (
        lambda v: isinstance(v, dict) and all(isinstance(t, dict) for t in v.values()),
        "a table of tables ([observe_settings.NAME])",
    ),
    "true": (
        lambda v: isinstance(v, dict) and all(_number(x) for x in v.values()),
        "a table of finite numbers",
    ),
    "frame": (
        lambda v: v in ("body", "camera"),
        '"body" or "camera" (the clouds\' coordinates)',
    ),
}
"""Each key of ``recording.toml``: its check and what it must be."""

REQUIRED = ("format", "units", "model", "scenario", "observe", "steps", "markers",
            "noise")  # fmt: skip
"""The keys every manifest has."""


def manifest(raw: Mapping[str, Any], where: str) -> None:
    """Check a parsed ``recording.toml``: known keys, each of its type.

    Raises
    ------
    RecordingError
        Naming the first unknown, missing or mistyped key and what is allowed.
    """
    for key, value in raw.items():
        if key not in MANIFEST_KEYS:
            raise RecordingError(
                f"{where}: unknown key {key!r} in recording.toml; allowed: "
                f"{', '.join(MANIFEST_KEYS)}"
            )
        check, what = MANIFEST_KEYS[key]
        if not check(value):
            raise RecordingError(
                f"{where}: {key} = {value!r} ({type(value).__name__}) in "
                f"recording.toml: need {what}"
            )
    for key in REQUIRED:
        if key not in raw:
            raise RecordingError(f"{where}: recording.toml needs {key} = ...")


FRAME = re.compile(r"frame\.(\d{5})/(?:([a-z][a-z0-9_-]*)/)?([a-z][a-z0-9_]*)")
"""A frame member: ``frame.FFFFF/NAME`` or ``frame.FFFFF/BLOCK/NAME``."""

HELD_OUT = ("markers", "targets", "points")
"""What a recording may hold out (``held_out/NAME``), for scoring only."""

FRAME_DATA = ("markers", "points", "origin", "sigma", "force")
"""The frame data of the core's observation kinds."""

SLACK = 4.0
"""How many times what the manifest needs a recording's arrays may hold."""

MAX_TARGETS = 1000
"""Hidden targets a recording may hold out per step (bounds held_out/targets)."""

MAX_FORCE = 64
"""Force channels a frame may hold (bounds ``force``)."""


def budget(steps: int, markers: int, points: int) -> int:
    """Bytes the arrays of a recording of this size may decompress to.

    :data:`SLACK` times what ``steps`` frames of ``markers`` markers and up to
    ``points`` cloud points need (with the held-out tracks, targets and clouds,
    a camera origin and noise, force channels), plus one MiB.
    """
    per_frame = 3 * markers + 3 * points + 4 + MAX_FORCE
    held = 3 * markers + 3 * MAX_TARGETS + 3 * points
    need = 8 * (2 * steps + steps * (per_frame + held) + 3 * points)  # + at rest
    return int(SLACK * need) + 2**20


def arrays(
    path: Path,
    where: str,
    steps: int,
    limit: int,
    plugin_leaves: bool,
) -> dict[str, FloatArray]:
    """The members of ``frames.npz`` as float arrays, checked before they are read.

    Parameters
    ----------
    path
        The ``frames.npz`` file.
    where
        The recording, for messages.
    steps
        Load steps K: frame members are numbered 1..K.
    limit
        Bytes all members may decompress to (:func:`budget`).
    plugin_leaves
        Whether frame data may carry names other than :data:`FRAME_DATA` (the
        recording's observation model is a plugin's).

    Raises
    ------
    RecordingError
        A file that is no zip or is truncated; an unknown member; a member
        that is no ``.npy`` array, an object array, not of real numbers, or
        larger than ``limit`` together with the others.
    """
    label = f"{where}: {path.name}"
    try:
        archive = zipfile.ZipFile(path)
    except (zipfile.BadZipFile, OSError, EOFError) as exc:
        raise RecordingError(
            f"{label} is not a zip archive of .npy arrays (numpy.savez): {exc}"
        ) from None
    with archive:
        members = archive.infolist()
        total = 0
        for info in members:
            key = _member_key(info.filename, label, steps, plugin_leaves)
            dtype, shape = _header(archive, info, label, key)
            total += int(np.prod(shape, dtype=np.int64)) * dtype.itemsize
            if total > limit:
                raise RecordingError(
                    f"{label}: the arrays up to {key} hold {total:,} bytes, more than "
                    f"{limit:,}, {SLACK:g} times what {steps} frames of the "
                    "manifest's markers and points need; refused before reading"
                )
        return {
            info.filename[:-4]: _data(archive, info, label) for info in members
        }


def _member_key(name: str, label: str, steps: int, plugin_leaves: bool) -> str:
    """The array name of zip member ``name``, or one line why it is not allowed."""
    if not name.endswith(".npy"):
        raise RecordingError(f"{label}: member {name!r} is not a .npy array")
    key = name[:-4]
    if key in ("time", "load", "rest/points"):
        return key
    if key.startswith("held_out/"):
        if key.removeprefix("held_out/") in HELD_OUT:
            return key
        raise RecordingError(
            f"{label}: unknown member {key!r}; held out may be "
            f"{', '.join('held_out/' + h for h in HELD_OUT)}"
        )
    match = FRAME.fullmatch(key)
    if match is None:
        raise RecordingError(
            f"{label}: unknown member {key!r}; allowed: time, load, rest/points, "
            "frame.FFFFF/NAME, frame.FFFFF/BLOCK/NAME, held_out/NAME"
        )
    k, leaf = int(match.group(1)), match.group(3)
    if not 1 <= k <= steps:
        raise RecordingError(
            f"{label}: member {key!r} is frame {k}; the manifest has steps = {steps} "
            f"(frames 1 to {steps})"
        )
    if leaf not in FRAME_DATA and not plugin_leaves:
        raise RecordingError(
            f"{label}: unknown frame data {key!r}; allowed: {', '.join(FRAME_DATA)}"
        )
    return key


def _header(
    archive: zipfile.ZipFile, info: zipfile.ZipInfo, label: str, key: str
) -> tuple[np.dtype[Any], tuple[int, ...]]:
    """Dtype and shape from a member's ``.npy`` header (its data is not read)."""
    try:
        with archive.open(info) as fh:
            version = np.lib.format.read_magic(fh)
            if version == (1, 0):
                shape, _, dtype = np.lib.format.read_array_header_1_0(fh)
            else:
                shape, _, dtype = np.lib.format.read_array_header_2_0(fh)
    except (ValueError, OSError, EOFError, zipfile.BadZipFile) as exc:
        raise RecordingError(
            f"{label}: member {key!r} is not a readable .npy array: {exc}"
        ) from None
    if dtype.hasobject:
        raise RecordingError(
            f"{label}: member {key!r} is an object array (a pickle); recordings hold "
            "numbers only and are never unpickled"
        )
    if dtype.kind not in "fiu":
        raise RecordingError(
            f"{label}: member {key!r} has dtype {dtype}; allowed: floats or integers"
        )
    return dtype, tuple(shape)


def _data(archive: zipfile.ZipFile, info: zipfile.ZipInfo, label: str) -> FloatArray:
    """A member's array as floats (its header checked already)."""
    try:
        with archive.open(info) as fh:
            value = np.lib.format.read_array(fh, allow_pickle=False)
    except (ValueError, OSError, EOFError, zipfile.BadZipFile) as exc:
        raise RecordingError(
            f"{label}: member {info.filename[:-4]!r} cannot be read (truncated or "
            f"corrupt): {exc}"
        ) from None
    return np.asarray(value, dtype=float)
