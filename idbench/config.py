"""The settings of a comparison, validated at the edge.

A :class:`CompareConfig` comes from keyword arguments (Python API), a TOML
file, the command line, or all three (command line wins over TOML). Every
value is checked here, with a one-line :class:`ConfigError` that names the bad
value and what is allowed.
"""

from __future__ import annotations

import dataclasses
import difflib
import math
import os
import tomllib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from idbench.scenario import Sparsity

ALL_ESTIMATORS = ("ro-ukf", "ukf", "rls", "lms", "batch-ls")

MAX_RUNS_ENV = "IDBENCH_MAX_RUNS"
DEFAULT_MAX_RUNS = 100_000
"""Runs a comparison may have before it is refused (``$IDBENCH_MAX_RUNS``)."""

MAX_TIMEOUT = 30 * 24 * 3600.0
"""The longest ``timeout`` accepted: 30 days, in seconds."""


class ConfigError(ValueError):
    """A setting is invalid; the message names the value and what is allowed."""


@dataclass(frozen=True)
class CompareConfig:
    """A grid of runs: scenarios x meshes x estimators x sparsity x seeds.

    Attributes
    ----------
    estimators
        Registered estimator names.
    meshes
        Model mesh specs (``NXxNYxNZ``, a node-count target, or a mesh file).
    truth_mesh
        Mesh spec of the truth (fine mesh).
    scenarios
        Registered scenario names.
    obs_every, obs_points, noise
        Sparsity sweep axes: observe every k-th step, M markers, noise sigma (m).
    seeds
        Number of noise seeds (0..seeds-1).
    steps
        Load steps K.
    E_true, nu
        True Young's modulus (Pa) and Poisson ratio.
    prior
        Prior mean and std of each parameter (Pa).
    model
        Registered model name.
    parameters
        What is identified: ``"E"`` or ``"E_regions"``.
    model_options
        Model-specific options, e.g. ``{"regions": 2}``.
    estimator_settings
        Per-estimator settings, e.g. ``{"ro-ukf": {"sigma_points": "star"}}``.
    grid
        Shape-error grid points per axis (nx, ny, nz).
    reference
        Estimator whose fit on the run's data gives E_ref.
    timeout
        Seconds per run before it is stopped and recorded as failed.
    """

    estimators: tuple[str, ...] = ALL_ESTIMATORS
    meshes: tuple[str, ...] = ("9x2x2", "14x3x3", "20x4x4")
    truth_mesh: str = "80x11x11"
    scenarios: tuple[str, ...] = ("bend-y",)
    obs_every: tuple[int, ...] = (2,)
    obs_points: tuple[int, ...] = (2,)
    noise: tuple[float, ...] = (1e-4,)
    seeds: int = 3
    steps: int = 20
    E_true: float = 5000.0
    nu: float = 0.45
    prior: tuple[float, float] = (2500.0, 2500.0)
    model: str = "svk-beam"
    parameters: str = "E"
    model_options: dict[str, Any] = field(default_factory=dict)
    estimator_settings: dict[str, dict[str, Any]] = field(default_factory=dict)
    grid: tuple[int, int, int] = (20, 4, 4)
    reference: str = "batch-ls"
    timeout: float | None = None

    def __post_init__(self) -> None:
        _check_names("estimators", self.estimators)
        _check_names("meshes", self.meshes)
        _check_names("scenarios", self.scenarios)
        if not isinstance(self.truth_mesh, str) or not self.truth_mesh:
            raise ConfigError(f"truth_mesh {self.truth_mesh!r}: need a mesh spec")
        for axis in ("obs_every", "obs_points", "noise"):
            _check_axis(axis, getattr(self, axis))
        for k in self.obs_every:
            _check_int("obs_every", k, 1)
        for m in self.obs_points:
            _check_int("obs_points", m, 1)
        for s in self.noise:
            if not _finite(s) or s < 0:
                raise ConfigError(f"noise {s!r}: must be a number >= 0 (metres)")
        _check_int("seeds", self.seeds, 1)
        _check_int("steps", self.steps, 1)
        if not _finite(self.E_true) or self.E_true <= 0:
            raise ConfigError(f"E_true {self.E_true!r}: must be a number > 0 (Pa)")
        if not _finite(self.nu) or not -1.0 < self.nu < 0.5:
            raise ConfigError(f"nu {self.nu!r}: must be in (-1, 0.5)")
        if (
            not isinstance(self.prior, tuple | list)
            or len(self.prior) != 2
            or not all(_finite(v) and v > 0 for v in self.prior)
        ):
            raise ConfigError(f"prior {self.prior!r}: need MEAN,STD, both > 0 (Pa)")
        for name in ("model", "reference"):
            value = getattr(self, name)
            if not isinstance(value, str) or not value.strip():
                raise ConfigError(f"{name} {value!r}: need a registered name")
        if not isinstance(self.parameters, str) or self.parameters not in (
            "E",
            "E_regions",
        ):
            raise ConfigError(f"parameters {self.parameters!r}: allowed: E, E_regions")
        if not isinstance(self.grid, tuple | list) or len(self.grid) != 3:
            raise ConfigError(f"grid {self.grid!r}: need three counts NX,NY,NZ")
        for g in self.grid:
            _check_int("grid", g, 1)
        if self.timeout is not None and (
            not _finite(self.timeout) or not 0 < self.timeout <= MAX_TIMEOUT
        ):
            raise ConfigError(
                f"timeout {self.timeout!r}: must be a number in (0, {MAX_TIMEOUT:g}] "
                "(seconds)"
            )
        if not isinstance(self.model_options, dict):
            raise ConfigError(
                f"model_options {self.model_options!r}: need a table of name = value"
            )
        if not isinstance(self.estimator_settings, dict):
            raise ConfigError(
                f"estimator_settings {self.estimator_settings!r}: need a table of "
                "[estimators.NAME] tables"
            )
        for name, settings in self.estimator_settings.items():
            if not isinstance(settings, dict):
                raise ConfigError(
                    f"estimator settings for {name!r}: {settings!r} is not a table "
                    f"(write [estimators.{name}] with name = value lines)"
                )
        n_runs = self.n_runs()
        if n_runs > max_runs():
            raise ConfigError(
                f"{n_runs:,} runs: more than the limit of {max_runs():,} "
                f"(set {MAX_RUNS_ENV} to raise it)"
            )

    def n_runs(self) -> int:
        """Number of runs of the grid, counted without building it."""
        return (
            len(self.scenarios)
            * len(self.meshes)
            * len(self.obs_every)
            * len(self.obs_points)
            * len(self.noise)
            * len(self.estimators)
            * self.seeds
        )

    @classmethod
    def quick(cls, **overrides: Any) -> CompareConfig:
        """The small comparison of ``--quick``: coarse truth, one seed."""
        base: dict[str, Any] = {
            "truth_mesh": "40x5x5",
            "meshes": ("14x3x3", "20x4x4"),
            "seeds": 1,
        }
        return cls(**{**base, **overrides})

    def sparsities(self) -> list[Sparsity]:
        """Every combination of the sparsity axes."""
        return [
            Sparsity(obs_every=k, obs_points=m, noise=s)
            for k in self.obs_every
            for m in self.obs_points
            for s in self.noise
        ]

    def to_dict(self) -> dict[str, Any]:
        """Plain, JSON-serialisable settings (for the manifest)."""
        return dataclasses.asdict(self)


def max_runs() -> int:
    """The largest comparison accepted: ``$IDBENCH_MAX_RUNS`` or 100,000 runs."""
    text = os.environ.get(MAX_RUNS_ENV, "")
    try:
        return int(text) if text else DEFAULT_MAX_RUNS
    except ValueError:
        raise ConfigError(f"{MAX_RUNS_ENV}={text!r}: need a whole number") from None


FIELDS = {f.name for f in dataclasses.fields(CompareConfig)}
LIST_FIELDS = {"estimators", "meshes", "scenarios", "obs_every", "obs_points", "noise"}


def _finite(x: Any) -> bool:
    return isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x)


def _check_int(name: str, value: Any, low: int) -> None:
    if isinstance(value, bool) or not isinstance(value, int) or value < low:
        raise ConfigError(f"{name} {value!r}: must be a whole number >= {low}")


def _check_axis(name: str, values: Any) -> None:
    if not isinstance(values, tuple) or not values:
        raise ConfigError(f"{name}: need at least one value")
    if len(set(values)) != len(values):
        raise ConfigError(
            f"{name} {values!r} has duplicates: each value of a sweep axis once"
        )


def _check_names(name: str, values: Any) -> None:
    if not isinstance(values, tuple) or not values:
        raise ConfigError(f"{name}: need at least one value")
    for v in values:
        if not isinstance(v, str) or not v.strip():
            raise ConfigError(f"{name}: {v!r} is not a name")
    if len(set(values)) != len(values):
        raise ConfigError(f"{name}: {values!r} has duplicates")


def public_settings(cls: type) -> list[str]:
    """The settings a user may give an estimator (or model) class.

    Its dataclass fields that are set in ``__init__`` and not private
    (no leading underscore).
    """
    return [
        f.name
        for f in dataclasses.fields(cls)
        if f.init and not f.name.startswith("_")
    ]


def suggest(key: str, allowed: Any) -> str:
    """A ``did you mean`` hint, or an empty string."""
    close = difflib.get_close_matches(key, sorted(allowed), n=1)
    return f" (did you mean {close[0]!r}?)" if close else ""


def normalise(raw: dict[str, Any], origin: str) -> dict[str, Any]:
    """Turn TOML or CLI keys and values into :class:`CompareConfig` fields.

    Dashes in keys become underscores; list axes accept a list or a scalar;
    ``[estimators.NAME]`` tables become ``estimator_settings``.
    """
    out: dict[str, Any] = {}
    for key, value in raw.items():
        k = key.replace("-", "_")
        if k == "estimators" and isinstance(value, dict):
            for n, v in value.items():
                if not isinstance(v, dict):
                    raise ConfigError(
                        f"{origin}: [estimators] {n} = {v!r}: need a table "
                        f"[estimators.{n}] of settings"
                    )
            out["estimator_settings"] = {str(n): dict(v) for n, v in value.items()}
            continue
        if k == "quick":
            continue
        if k not in FIELDS:
            raise ConfigError(f"{origin}: unknown key {key!r}{suggest(k, FIELDS)}")
        if k in LIST_FIELDS:
            value = tuple(value) if isinstance(value, list | tuple) else (value,)
        elif k in ("prior", "grid") and isinstance(value, list):
            value = tuple(value)
        out[k] = value
    return out


def load_toml(path: Path) -> dict[str, Any]:
    """Read a TOML config file into normalised fields."""
    try:
        raw = tomllib.loads(Path(path).read_text())
    except FileNotFoundError:
        raise ConfigError(f"config file {str(path)!r} does not exist") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise ConfigError(f"config file {str(path)!r} is unreadable: {exc}") from None
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(
            f"config file {str(path)!r} is not valid TOML: {exc}"
        ) from None
    compare = raw.pop("compare", None)
    origin = f"config {path}"
    if compare is not None and not isinstance(compare, dict):
        raise ConfigError(f"{origin}: compare = {compare!r}: need a [compare] table")
    if isinstance(compare, dict):  # normalised apart: [estimators.X] vs a list
        return {**normalise(compare, origin), **normalise(raw, origin)}
    return normalise(raw, origin)


def build_config(
    *, quick: bool = False, toml: dict[str, Any] | None = None, **cli: Any
) -> CompareConfig:
    """Merge TOML fields and CLI fields (CLI wins) into a validated config."""
    fields = {**(toml or {}), **{k: v for k, v in cli.items() if v is not None}}
    if "estimator_settings" in (toml or {}) and "estimator_settings" in cli:
        fields["estimator_settings"] = {
            **toml["estimator_settings"],  # type: ignore[index]
            **cli["estimator_settings"],
        }
    try:
        return CompareConfig.quick(**fields) if quick else CompareConfig(**fields)
    except TypeError as exc:
        raise ConfigError(str(exc)) from None
