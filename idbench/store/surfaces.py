"""What a run shows: its surface at the stored steps, kept beside its results.

A report draws the organ from these files without simulating anything again
(:mod:`idbench.report.scene`). They sit in ``DIR/surfaces/``, plain ``.npz``
(never pickle), each written atomically and holding its own key and a digest
of its arrays:

- ``mesh-<key>.npz``, once per model (a mesh on a scenario, ``key`` its model
  key in the manifest's ``inputs``): ``vertices`` (V, 3) float32, the
  undeformed surface (only the vertices its triangles use), ``triangles``
  (T, 3) int32, ``role``, ``mesh``, ``scenario``, and ``described``, a hash of
  the model's ``describe()`` (what it read, with its files' digests).
- ``truth-<key>.npz``, once per data set (``key`` the run's truth key):
  ``mesh_key`` (a ``mesh-`` file of role truth), ``steps`` (S,) int32 and
  ``displacement`` (S, V, 3) float32 of the truth's surface vertices.
- ``run-<run_id>.npz``, one per run: ``mesh_key``, ``truth_key`` (empty for a
  recording: no truth field), ``steps`` (S,), ``displacement`` (S, V, 3)
  float32 of the model's surface vertices as the run scored them (the
  estimator's state, or the model at its estimate), and, where the run
  observes a depth camera, ``cloud_points`` (S, N, 3) float32,
  ``cloud_outliers`` (S, N) bool (the points the gate clips against the
  model's surface at that step) and ``camera`` (8,): position (3), look-at
  point (3), vertical field of view (degrees) and aspect (width / height).
  Where the model places its points
  (:class:`~idbench.core.optional.PlacedPointsModel`), positions (the
  undeformed point plus its displacement), float32: where the run observes
  markers, ``markers_observed`` (S, M, 3) (plus the step's observed values,
  NaN where occluded or the step is not observed) and ``markers_predicted``
  (S, M, 3) (plus ``observe`` at the run's state); where the run scores
  hidden targets (:mod:`idbench.score.targets`), ``targets_true`` and
  ``targets_predicted`` (S, T, 3), and, for a run that reached its last
  step, ``targets_cov`` (T, 3, 3) float64: each target's predicted
  covariance at that step, as the scores computed it (its 95% region is the
  ellipsoid ``tre_covered_final`` counts).

Stored steps: every step up to :data:`MAX_STEPS` steps, else every k-th
(k = ceil(K / MAX_STEPS)) and the last (:func:`stored_steps`). A run's file is
written before its result parts (:mod:`idbench.store.results`), so a finished
run has its surfaces; a diverged run's file ends at its last scored step.
:func:`check` is part of a resume's content checks: a file whose model is not
the manifest's model of that key (another mesh content, another body) is
refused like a changed mesh, naming the file.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from idbench.core.capabilities import marker_points_of, member, target_points_of
from idbench.core.interfaces import FloatArray, ForwardModel, Observation
from idbench.observe import kinds
from idbench.observe.cloud import Cloud
from idbench.observe.surface import point_to_surface, surface_of
from idbench.store.files import atomic_write, digest, stable_hash

FOLDER = "surfaces"
"""The folder of a results directory that holds the surfaces."""

MAX_STEPS = 50
"""Longest run stored step by step; longer ones keep every k-th step."""

ROW_KEY = "_surfaces"
"""Where :func:`idbench.run.harness.execute` hands a run's captured surfaces
over in its row (popped before the row is stored: not a column)."""


POINTS = ("markers_observed", "markers_predicted", "targets_true",
          "targets_predicted")  # fmt: skip
"""The positions a run's file may hold per stored step, each (S, n, 3)."""


class SurfaceError(ValueError):
    """A stored surface file cannot be used (damaged, foreign, stale)."""


def stored_steps(n_steps: int) -> list[int]:
    """The load steps 1..K whose surfaces are stored (see the module)."""
    every = max(1, math.ceil(n_steps / MAX_STEPS))
    steps = list(range(every, n_steps + 1, every))
    if n_steps >= 1 and (not steps or steps[-1] != n_steps):
        steps.append(n_steps)
    return steps


def described(entry: Mapping[str, Any]) -> str:
    """The hash of one ``inputs`` entry's ``describe()`` (what a mesh file holds)."""
    return stable_hash(entry.get("describe"), length=24)


def compact(triangles: NDArray[np.int64]) -> tuple[NDArray[np.int64], NDArray[Any]]:
    """The vertices ``triangles`` use (U,) and the triangles renumbered into them."""
    tri = np.asarray(triangles, dtype=np.int64)
    used, renumbered = np.unique(tri, return_inverse=True)
    return used, renumbered.reshape(tri.shape).astype(np.int32)


class Recorder:
    """Captures one run's surfaces at the stored steps (in the run's process).

    Parameters
    ----------
    model
        The model the run is scored with; without ``surface`` nothing is kept.
    n_steps
        The run's load steps K.
    keys
        ``run_id``, ``mesh_key`` and ``truth_key`` of the run (see the module).
    observation, frames
        The run's observation model and its frames (None: markers only); a
        depth-camera block's points are kept, with the points its gate clips,
        and a markers block's values (the observation stream's without
        frames).
    truth_targets
        The truth's target displacements (K, T, 3) where the run scores
        targets (None: it does not).
    """

    def __init__(
        self,
        model: ForwardModel,
        n_steps: int,
        keys: Mapping[str, str],
        observation: Any = None,
        frames: Sequence[kinds.Frame] | None = None,
        truth_targets: Any = None,
    ) -> None:
        self.model = model
        self.keys = dict(keys)
        self.steps = set(stored_steps(n_steps))
        self.kept: list[int] = []
        self.moved: list[FloatArray] = []
        self.points: list[FloatArray] = []
        self.outliers: list[NDArray[np.bool_]] = []
        self.camera: FloatArray | None = None
        self.rest: FloatArray | None = None
        self.triangles: NDArray[Any] | None = None
        self.placed: dict[str, list[FloatArray]] = {}
        self.covariance: FloatArray | None = None
        try:
            vertices, triangles = surface_of(model, model.reset())
        except ValueError:  # the model has no surface: nothing to show
            return
        self.used, self.triangles = compact(triangles)
        self.rest = vertices[self.used]
        self.cloud = _cloud_block(observation) if frames else None
        self.frames = frames
        markers = marker_points_of(model)
        self.markers = _marker_block(observation) if markers is not None else None
        self.marker_points = markers
        self.target_points = target_points_of(model)
        self.truth_targets = truth_targets
        if self.target_points is None or not len(self.target_points):
            self.truth_targets = None

    def step(
        self, k: int, state: FloatArray, observation: Observation | None = None
    ) -> None:
        """Keep step ``k``'s surface (cloud, markers, targets) if it is stored.

        ``observation``: the run's observation of step ``k`` (None: none).
        """
        if self.rest is None or k not in self.steps:
            return
        vertices, triangles = surface_of(self.model, state)
        self.kept.append(k)
        self.moved.append(vertices[self.used] - self.rest)
        if self.cloud is not None and self.frames is not None:
            self._cloud(k, vertices, triangles)
        if self.markers is not None:
            self._markers(k, state, observation)
        if self.truth_targets is not None:
            self._targets(k, state)

    def region(self, covariance: Any) -> None:
        """Keep the targets' predicted covariance (T, 3, 3) at the last step."""
        if self.truth_targets is not None and self.kept:
            self.covariance = np.asarray(covariance, dtype=np.float64)

    def _keep(self, name: str, positions: FloatArray) -> None:
        self.placed.setdefault(name, []).append(positions.astype(np.float32))

    def _markers(self, k: int, state: FloatArray, observation: Any) -> None:
        points = self.marker_points
        assert points is not None and self.markers is not None
        predicted = np.asarray(self.model.observe(state), dtype=float)
        seen = np.full(points.shape, np.nan)
        if observation is not None:
            name, block = self.markers
            if self.frames is None:  # plain markers: the stream's values
                values = np.asarray(observation.values, dtype=float)
            else:
                frame = self.frames[k - 1]
                if name:
                    frame = kinds.Frame(frame.step, {
                        key.removeprefix(f"{name}/"): v
                        for key, v in frame.data.items() if key.startswith(f"{name}/")
                    })  # fmt: skip
                values = np.asarray(block.values(frame), dtype=float)
            if values.size == points.size:
                seen = points + values.reshape(points.shape)
        if predicted.size != points.size:  # not the markers': keep none
            self.markers = None
            self.placed.pop("markers_observed", None)
            self.placed.pop("markers_predicted", None)
            return
        self._keep("markers_observed", seen)
        self._keep("markers_predicted", points + predicted.reshape(points.shape))

    def _targets(self, k: int, state: FloatArray) -> None:
        points = self.target_points
        assert points is not None and self.truth_targets is not None
        moved = np.asarray(member(self.model, "targets")(state), dtype=float)
        true = np.asarray(self.truth_targets[k - 1], dtype=float)
        if moved.size != points.size or true.size != points.size:  # not these
            self.truth_targets = None
            self.placed.pop("targets_true", None)
            self.placed.pop("targets_predicted", None)
            return
        self._keep("targets_true", points + true.reshape(points.shape))
        self._keep("targets_predicted", points + moved.reshape(points.shape))

    def _cloud(self, k: int, vertices: FloatArray, triangles: Any) -> None:
        name, block = self.cloud  # type: ignore[misc]
        data = self.frames[k - 1].data  # type: ignore[index]
        prefix = f"{name}/" if name else ""
        points = np.asarray(data[prefix + "points"], dtype=float)
        sigma = float(data.get(prefix + "sigma", block.noise or 0.0))
        gate = max(block.gate * sigma, block.gate_min)
        r = point_to_surface(points, vertices, triangles, candidates=block.candidates)
        self.points.append(points)
        self.outliers.append(np.abs(r) >= gate)
        if self.camera is None and self.rest is not None:
            origin = np.asarray(data[prefix + "origin"], dtype=float)
            _, look = block.pose(self.rest)
            width, height = block.resolution
            self.camera = np.array([*origin, *look, block.fov, width / height])

    def arrays(self) -> dict[str, Any] | None:
        """What :func:`write_run` stores (None: nothing captured)."""
        if self.rest is None or not self.kept:
            return None
        out: dict[str, Any] = {
            **self.keys,
            "vertices": self.rest.astype(np.float32),
            "triangles": self.triangles,
            "steps": np.array(self.kept, dtype=np.int32),
            "displacement": np.array(self.moved, dtype=np.float32),
        }
        if self.points and len({len(p) for p in self.points}) == 1:
            out["cloud_points"] = np.array(self.points, dtype=np.float32)
            out["cloud_outliers"] = np.array(self.outliers, dtype=bool)
            out["camera"] = self.camera
        out.update({name: np.array(kept) for name, kept in self.placed.items()})
        if self.covariance is not None and self.kept[-1] == max(self.steps):
            out["targets_cov"] = self.covariance
        return out


def _cloud_block(observation: Any) -> tuple[str, Cloud] | None:
    """(block name, settings) of the observation's first depth camera, or None."""
    if observation is None:
        return None
    for name, block in kinds.leaves(observation):
        if isinstance(block, Cloud):
            return name, block
    return None


def _marker_block(observation: Any) -> tuple[str, kinds.Markers] | None:
    """(block name, settings) of the observation's markers block, or None."""
    if observation is None:
        return None
    for name, block in kinds.leaves(observation):
        if isinstance(block, kinds.Markers):
            return name, block
    return None


# --- the files ---------------------------------------------------------------


def folder(root: Path) -> Path:
    """``root/surfaces``."""
    return Path(root) / FOLDER


def _save(path: Path, key: str, arrays: Mapping[str, Any]) -> None:
    plain = {name: np.asarray(value) for name, value in arrays.items()}
    body = {"key": np.array(key), **plain, "digest": np.array(_digest(plain))}

    def write(tmp: Path) -> None:
        with open(tmp, "wb") as fh:
            np.savez(fh, **body)  # type: ignore[arg-type]

    path.parent.mkdir(parents=True, exist_ok=True)
    atomic_write(path, write)


def _digest(arrays: Mapping[str, Any]) -> str:
    return stable_hash({name: digest(arrays[name]) for name in sorted(arrays)})


def load(path: Path) -> dict[str, Any]:
    """A surface file's arrays, checked against its own name and digest.

    Raises
    ------
    SurfaceError
        Unreadable, of another name, or altered (naming the file).
    """
    try:
        with np.load(path, allow_pickle=False) as data:
            arrays = {name: np.array(data[name]) for name in data.files}
    except Exception as exc:
        raise SurfaceError(f"{path} is unreadable ({exc})") from None
    key = str(arrays.pop("key", ""))
    stored = str(arrays.pop("digest", ""))
    if path.stem.partition("-")[2] != key:
        raise SurfaceError(f"{path} holds {key or 'no key'}, not its own name")
    if stored != _digest(arrays):
        raise SurfaceError(f"{path} was altered or damaged (its digest differs)")
    return arrays


def write_run(root: Path, captured: Mapping[str, Any], inputs: Sequence[Any]) -> None:
    """Store a run's :meth:`Recorder.arrays` (and its mesh's file, once)."""
    arrays = dict(captured)
    run_id, mesh_key = str(arrays.pop("run_id")), str(arrays["mesh_key"])
    vertices, triangles = arrays.pop("vertices"), arrays.pop("triangles")
    write_mesh(root, mesh_key, vertices, triangles, inputs)
    _save(folder(root) / f"run-{run_id}.npz", run_id, arrays)


def write_mesh(
    root: Path,
    key: str,
    vertices: FloatArray,
    triangles: NDArray[Any],
    inputs: Sequence[Any],
) -> None:
    """Store the undeformed surface of model ``key`` unless already there."""
    path = folder(root) / f"mesh-{key}.npz"
    if path.exists():
        return
    entry = _entry(inputs, key)
    _save(path, key, {
        "vertices": np.asarray(vertices, dtype=np.float32),
        "triangles": np.asarray(triangles, dtype=np.int32),
        "role": np.array(str(entry.get("role", ""))),
        "mesh": np.array(str(entry.get("mesh", ""))),
        "scenario": np.array(str(entry.get("scenario", ""))),
        "described": np.array(described(entry)),
    })  # fmt: skip


def write_truth(
    root: Path,
    key: str,
    mesh_key: str,
    model: ForwardModel,
    states: FloatArray,
    inputs: Sequence[Any],
) -> None:
    """Store the truth's surface at the stored steps (once per data set).

    Nothing for a model without ``surface`` or a truth without states (a
    recording).
    """
    path = folder(root) / f"truth-{key}.npz"
    if path.exists() or not len(states) or not np.asarray(states).size:
        return
    try:
        rest, triangles = surface_of(model, model.reset())
    except ValueError:
        return
    used, renumbered = compact(triangles)
    steps = stored_steps(len(states))
    moved = [surface_of(model, states[k - 1])[0][used] - rest[used] for k in steps]
    write_mesh(root, mesh_key, rest[used], renumbered, inputs)
    _save(path, key, {
        "mesh_key": np.array(mesh_key),
        "steps": np.array(steps, dtype=np.int32),
        "displacement": np.array(moved, dtype=np.float32),
    })  # fmt: skip


def _entry(inputs: Sequence[Any], key: str) -> Mapping[str, Any]:
    for entry in inputs:
        if isinstance(entry, Mapping) and entry.get("key") == key:
            return entry
    return {}


def check(root: Path, inputs: Sequence[Any]) -> str:
    """Why ``root``'s stored surfaces do not fit the models of ``inputs`` ("": fit).

    Each ``mesh-`` file must be readable, hold its own key and digest, and
    record the ``describe()`` hash of the ``inputs`` entry of its key (a mesh
    that another content, body or setting made is refused like a changed
    mesh); a file of a model the inputs do not name is left alone (another
    comparison's, unused). Run and truth files are checked when read.
    """
    for path in sorted(folder(root).glob("mesh-*.npz")):
        try:
            arrays = load(path)
        except SurfaceError as exc:
            return str(exc)
        entry = _entry(inputs, path.stem.partition("-")[2])
        if entry and str(arrays.get("described")) != described(entry):
            return (
                f"{path} holds the surface of mesh {entry.get('mesh')!r} (scenario "
                f"{entry.get('scenario')!r}) of another content than the one this "
                "comparison reads"
            )
    return ""
