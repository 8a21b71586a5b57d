"""Observation models: what a sensor makes of a body, between the truth and the filters.

An observation model turns a load path into *frames* (what a sensor delivered
at each step, simulated from the truth or read from a recording) and a frame
into what an estimator sees: a fixed-length vector ``values`` y with its
noise std, and the model-side prediction h(x) of the same length for any
model state. The estimators are not changed: they see
:class:`~idbench.core.interfaces.Observation` ``(values, noise_std, step)`` and
call ``model.observe(state)`` as before, on a
:class:`~idbench.observe.observed_model.ObservedModel` that answers with h(x).

Built in (model-agnostic; each needs the model members it names):

- ``markers``: today's marker displacements (``observe``), noise sigma the
  run's ``--noise``. Its path is exactly the old one (same draws, same values).
- ``cloud``: a virtual depth camera (:mod:`idbench.observe.cloud`) on the
  truth's deformed surface (``surface``); y = 0 and h(x) = each observed
  point's gated signed distance to the model's deformed surface.
- ``force``: the reaction force of the manipulation (``reaction``), noise its
  own ``noise`` setting (force units).
- combinations ``A+B``: the blocks' values concatenated, each with its noise
  (``noise_std`` an array then).

Plugins add observation models with the ``register_observations`` hook
(``register(name, cls)``, ``cls`` a settings dataclass implementing
:class:`idbench.ObservationModel`, checked when it registers); a comparison
picks them with ``observe`` and configures them in ``[observe.NAME]`` tables
(a table with ``kind = "cloud"`` defines a variant, e.g. ``[observe.cloud500]
kind = "cloud" points = 500``, so that realism knobs become a sweep axis).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np

from idbench.core.capabilities import member, needs_theta_of
from idbench.core.interfaces import ConfigError, FloatArray, ForwardModel
from idbench.core.observation_model import Frame
from idbench.core.settings import build_settings
from idbench.observe.cloud import Cloud

COMBINE = "+"
"""Joins the blocks of a combined observation: ``cloud+force``."""


IF_SET = "if-set"
"""Field metadata ``{"identity": IF_SET}``: a setting that enters the runs'
keys only when it differs from its default (one added after runs were keyed
without it), see :func:`settings_items`."""


@dataclass(frozen=True)
class Markers:
    """Marker displacements with perfect correspondence (today's observation).

    The markers are the model's (``--obs-points``), the noise sigma the run's
    ``--noise``.

    Attributes
    ----------
    occlusion
        Fraction in [0, 1) of markers hidden (behind an instrument) in each
        frame: each marker of each frame independently with this probability,
        drawn after the noise from the run's generator, so the visible values
        are those of ``occlusion = 0``; a hidden marker is NaN in x, y and z
        (the estimators assimilate the visible ones, :mod:`idbench.observe.occlusion`).
        0 (default) hides none, and keeps the runs' keys.
    """

    occlusion: float = dataclasses.field(default=0.0, metadata={"identity": IF_SET})
    requires: tuple[str, ...] = dataclasses.field(
        default=("observe",), init=False, repr=False
    )

    def __post_init__(self) -> None:
        f = self.occlusion
        ok = isinstance(f, int | float) and not isinstance(f, bool)
        if not (ok and math.isfinite(f) and 0 <= f < 1):
            raise ValueError(
                f"occlusion = {f!r} is not allowed; it must be a fraction "
                "0 <= occlusion < 1"
            )

    def sense(
        self, model: ForwardModel, theta: FloatArray, k: int, state: FloatArray
    ) -> dict[str, FloatArray]:
        """``{"markers": model.observe(state)}``."""
        return {"markers": np.asarray(model.observe(state), dtype=float)}

    def measure(
        self, clean: Sequence[Mapping[str, FloatArray]], rng: np.random.Generator,
        noise: float,
    ) -> list[dict[str, FloatArray]]:  # fmt: skip
        """Clean markers plus N(0, noise^2), drawn for all K steps at once.

        With ``occlusion`` > 0, then, each marker of each frame hidden (NaN)
        with that probability.
        """
        y = np.array([c["markers"] for c in clean])
        draws = rng.standard_normal(y.shape) * noise
        out = y + draws
        if self.occlusion > 0:
            xyz = out.reshape(len(clean), -1, 3)
            xyz[rng.random(xyz.shape[:2]) < self.occlusion] = np.nan
        return [{"markers": out[i]} for i in range(len(clean))]

    def values(self, frame: Frame) -> FloatArray:
        """The noisy marker displacements (3M,)."""
        return np.asarray(frame.data["markers"])

    def noise_std(self, frame: Frame, noise: float) -> float:
        """The run's noise sigma."""
        return noise

    def predict(
        self, model: ForwardModel, frame: Frame, theta: FloatArray, k: int,
        state: FloatArray,
    ) -> FloatArray:  # fmt: skip
        """``model.observe(state)``."""
        return np.asarray(model.observe(state), dtype=float)

    def linearize(
        self, model: ForwardModel, frame: Frame, theta: FloatArray, k: int,
        state: FloatArray,
    ) -> tuple[Any, FloatArray]:  # fmt: skip
        """The model's own ``observation_jacobian`` (its ``observe`` is this)."""
        return _needed(model, "observation_jacobian", "markers")(theta, k, state)

    def positions(self, model: ForwardModel, frame: Frame, k: int) -> FloatArray:
        """The model's ``observation_points`` of step k."""
        return np.asarray(_needed(model, "observation_points", "markers")(k), float)

    def identity(self) -> list[Any]:
        """Nothing: the markers' draws keep today's seed (the run's noise key)."""
        return []


@dataclass(frozen=True)
class Force:
    """The reaction force of the manipulation, an observed channel.

    Attributes
    ----------
    noise
        Noise std of each force component (the model's force unit, N for the
        built-in models); must be > 0.
    """

    noise: float = 1e-3
    requires: tuple[str, ...] = dataclasses.field(
        default=("reaction",), init=False, repr=False
    )
    needs_theta: ClassVar[bool] = True
    """Its prediction depends on theta itself (not only through the state)."""

    def __post_init__(self) -> None:
        _positive("noise", self.noise)

    def sense(
        self, model: ForwardModel, theta: FloatArray, k: int, state: FloatArray
    ) -> dict[str, FloatArray]:
        """``{"force": model.reaction(theta, k, state)}``."""
        return {"force": _reaction(model, theta, k, state)}

    def measure(
        self, clean: Sequence[Mapping[str, FloatArray]], rng: np.random.Generator,
        noise: float,
    ) -> list[dict[str, FloatArray]]:  # fmt: skip
        """Clean force plus N(0, self.noise^2) per component."""
        f = np.array([c["force"] for c in clean])
        draws = rng.standard_normal(f.shape) * self.noise
        return [{"force": f[i] + draws[i]} for i in range(len(clean))]

    def values(self, frame: Frame) -> FloatArray:
        """The measured force (c,)."""
        return np.asarray(frame.data["force"])

    def noise_std(self, frame: Frame, noise: float) -> float:
        """The ``noise`` setting (not the run's length sigma)."""
        return self.noise

    def predict(
        self, model: ForwardModel, frame: Frame, theta: FloatArray, k: int,
        state: FloatArray,
    ) -> FloatArray:  # fmt: skip
        """``model.reaction(theta, k, state)``."""
        return _reaction(model, theta, k, state)

    def linearize(
        self, model: ForwardModel, frame: Frame, theta: FloatArray, k: int,
        state: FloatArray,
    ) -> tuple[Any, FloatArray]:  # fmt: skip
        """The model's ``reaction_jacobian``: (d/du (c, n), d/dtheta (c, p))."""
        return _needed(model, "reaction_jacobian", "force")(theta, k, state)

    def positions(self, model: ForwardModel, frame: Frame, k: int) -> FloatArray:
        """NaN (c, 3): a resultant force is nowhere in particular."""
        return np.full((len(self.values(frame)), 3), np.nan)

    def identity(self) -> list[Any]:
        """The kind only (the sigma scales common draws)."""
        return ["force"]


def _needed(model: ForwardModel, name: str, block: str) -> Any:
    """The model's optional member ``name``; ValueError naming it if absent."""
    found = member(model, name)
    if found is None:
        raise ValueError(
            f"observe {block}: model {type(model).__name__} has no {name} (needed "
            "to linearize the observation)"
        )
    return found


def _reaction(
    model: ForwardModel, theta: FloatArray, k: int, state: FloatArray
) -> FloatArray:
    reaction = member(model, "reaction")
    if reaction is None:
        raise ConfigError(
            f"observe force: model {type(model).__name__} has no reaction"
        )
    return np.asarray(reaction(theta, k, state), dtype=float).ravel()


@dataclass(frozen=True)
class Combined:
    """Several observation models at once: values concatenated block by block.

    Attributes
    ----------
    blocks
        (name, model) per block, in the order of the ``A+B`` name.
    """

    blocks: tuple[tuple[str, Any], ...]

    @property
    def needs_theta(self) -> bool:
        """Whether a block's prediction depends on theta itself."""
        return any(needs_theta_of(b) for _, b in self.blocks)

    @property
    def requires(self) -> tuple[str, ...]:
        """Every block's requirements."""
        return tuple(r for _, b in self.blocks for r in b.requires)

    def split(self, frame: Frame) -> list[Frame]:
        """The frame of each block (keys ``BLOCK/NAME`` -> ``NAME``)."""
        out = []
        for name, _ in self.blocks:
            prefix = f"{name}/"
            data = {
                key.removeprefix(prefix): v
                for key, v in frame.data.items()
                if key.startswith(prefix)
            }
            out.append(Frame(frame.step, data))
        return out

    def values(self, frame: Frame) -> FloatArray:
        """Every block's y, concatenated."""
        parts = self.split(frame)
        return np.concatenate(
            [b.values(f) for (_, b), f in zip(self.blocks, parts, strict=True)]
        )

    def noise_std(self, frame: Frame, noise: float) -> FloatArray:
        """Per value: each block's noise std, repeated over its values."""
        parts = self.split(frame)
        return np.concatenate([
            np.broadcast_to(np.asarray(b.noise_std(f, noise), float), b.values(f).shape)
            for (_, b), f in zip(self.blocks, parts, strict=True)
        ])  # fmt: skip

    def predict(
        self, model: ForwardModel, frame: Frame, theta: FloatArray, k: int,
        state: FloatArray,
    ) -> FloatArray:  # fmt: skip
        """Every block's h(x), concatenated."""
        parts = self.split(frame)
        return np.concatenate([
            b.predict(model, f, theta, k, state)
            for (_, b), f in zip(self.blocks, parts, strict=True)
        ])  # fmt: skip

    @staticmethod
    def merge(named: Sequence[tuple[str, Mapping[str, FloatArray]]]) -> dict[str, Any]:
        """One frame's data from each block's (name, data)."""
        return {f"{n}/{key}": v for n, data in named for key, v in data.items()}


BUILTIN: dict[str, type] = {"markers": Markers, "cloud": Cloud, "force": Force}
"""The core's observation models by kind."""

DEFAULT = "markers"


def kinds(registry: Any = None) -> dict[str, type]:
    """Observation model classes by kind: the built-ins and the plugins'."""
    out = dict(BUILTIN)
    for name, entry in ({} if registry is None else registry.observations).items():
        out.setdefault(name, entry.obj)
    return out


def block_names(name: str) -> list[str]:
    """The blocks of an ``observe`` value: ``"cloud+force"`` -> cloud, force."""
    parts = [p.strip() for p in str(name).split(COMBINE)]
    if not all(parts):
        raise ConfigError(f"observe {name!r}: an empty block; write e.g. cloud+force")
    if len(set(parts)) != len(parts):
        raise ConfigError(f"observe {name!r}: a block repeats")
    return parts


def block_settings(
    block: str, tables: Mapping[str, Mapping[str, Any]], registry: Any = None
) -> tuple[str, dict[str, Any]]:
    """(kind, settings) of one block from the ``[observe.NAME]`` tables.

    Raises
    ------
    ConfigError
        For a name that is neither a kind nor a table with a known ``kind``.
    """
    known = kinds(registry)
    table = dict(tables.get(block, {}))
    kind = str(table.pop("kind", block))
    if kind not in known:
        allowed = ", ".join(sorted(known))
        raise ConfigError(
            f"observe {block!r}: unknown observation model"
            + (f" kind {kind!r}" if kind != block else "")
            + f"; allowed: {allowed}, or a [observe.{block}] table with kind = one "
            "of them"
        )
    return kind, table


def build(
    name: str, tables: Mapping[str, Mapping[str, Any]], registry: Any = None
) -> Any:
    """The observation model of an ``observe`` value (a block or ``A+B``).

    Raises
    ------
    ConfigError
        Naming an unknown observation model, setting or bad value.
    """
    models = []
    for block in block_names(name):
        kind, settings = block_settings(block, tables, registry)
        cls = kinds(registry)[kind]
        models.append((block, build_settings(cls, settings, f"observe {block!r}")))
    if len(models) == 1:
        return models[0][1]
    return Combined(tuple(models))


def leaves(obs: Any) -> list[tuple[str, Any]]:
    """(name, model) of each block of ``obs`` (itself, named ``""``, if single)."""
    return list(obs.blocks) if isinstance(obs, Combined) else [("", obs)]


def settings_items(
    name: str, tables: Mapping[str, Mapping[str, Any]], registry: Any = None
) -> tuple[tuple[str, Any], ...]:
    """The resolved settings of every block of ``name``, for the run's identity.

    ``(("BLOCK", ((kind, KIND), (setting, value), ...)), ...)`` with every
    default filled in; empty for plain ``markers``, so its runs keep their
    keys (and a setting marked :data:`IF_SET` only where it is not its
    default).
    """
    if name == DEFAULT and DEFAULT not in tables:
        return ()
    obs = build(name, tables, registry)
    out = []
    for block, model in obs.blocks if isinstance(obs, Combined) else [(name, obs)]:
        kind, _ = block_settings(block, tables, registry)
        dc = dataclasses.is_dataclass(model) and not isinstance(model, type)
        fields = dataclasses.asdict(model) if dc else {}
        fields.pop("requires", None)
        for f in dataclasses.fields(model) if dc else ():
            if f.metadata.get("identity") == IF_SET and fields[f.name] == f.default:
                del fields[f.name]  # at its default: the keys it had without it
        items = tuple(sorted((k, _jsonable(v)) for k, v in fields.items()))
        out.append((block, (("kind", kind), *items)))
    return tuple(out)


def from_items(
    name: str, items: tuple[tuple[str, Any], ...], registry: Any = None
) -> Any:
    """The observation model of a run, from :func:`settings_items` output."""
    tables = {block: dict(settings) for block, settings in items}
    return build(name, tables, registry)


def _jsonable(v: Any) -> Any:
    if isinstance(v, tuple | list):
        return tuple(_jsonable(x) for x in v)
    return v


def _positive(name: str, value: Any) -> None:
    ok = isinstance(value, int | float) and not isinstance(value, bool)
    if not (ok and math.isfinite(value) and value > 0):
        raise ValueError(f"{name} = {value!r} is not allowed; it must be finite > 0")
