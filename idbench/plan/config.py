"""The settings of a comparison, validated at the edge.

A :class:`CompareConfig` comes from keyword arguments (Python API), a TOML
file, the command line, or all three (command line wins over TOML). Every
value is checked here, with a one-line :class:`ConfigError` that names the bad
value and what is allowed.
"""

from __future__ import annotations

import dataclasses
import os
import tomllib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from idbench.core.capabilities import by_default, settings_member
from idbench.core.interfaces import ConfigError, ModelDefaults
from idbench.core.scenario import Sparsity
from idbench.core.settings import build_settings, proposed_defaults, suggest
from idbench.core.settings import finite_number as _finite

MAX_RUNS_ENV = "IDBENCH_MAX_RUNS"
DEFAULT_MAX_RUNS = 100_000
"""Runs a comparison may have before it is refused (``$IDBENCH_MAX_RUNS``)."""

MAX_TIMEOUT = 30 * 24 * 3600.0
"""The longest ``timeout`` accepted: 30 days, in seconds."""

MAX_NOISE = 1e100
"""The largest noise sigma accepted (its square must not overflow)."""

REGISTRATIONS = ("rigid", "with-model")
"""How a camera's recording is put in the body's frame (``registration``)."""


@dataclass(frozen=True)
class CompareConfig:
    """A grid of runs: scenarios x meshes x estimators x sparsity x seeds.

    Fields left at None are filled by :meth:`resolve` from what the plugins
    registered: the model's :class:`~idbench.core.interfaces.ModelDefaults`, every
    registered estimator, the registered reference estimator.

    Attributes
    ----------
    estimators
        Registered estimator names (None: all registered).
    meshes
        Model discretisations, as the model reads them (None: its defaults).
    truth_mesh
        The truth's discretisation (None: the model's default).
    scenarios
        Registered scenario names (None: the model's defaults).
    obs_every, obs_points, noise
        Sparsity sweep axes: observe every k-th step, M markers, noise sigma
        (model units, e.g. metres).
    seeds
        Number of noise seeds (0..seeds-1).
    steps
        Load steps K.
    true
        True parameter values by parameter name (others: the model's defaults).
    prior
        Prior mean and std of each parameter, natural units (None: the model's).
    model
        Registered model name (None: the default model).
    model_settings
        The models' own settings by model name, e.g. ``{"svk-beam": {"nu": 0.3}}``.
    estimator_settings
        Per-estimator settings, e.g. ``{"ro-ukf": {"sigma_points": "star"}}``.
    reference
        Estimator whose fit on the run's data gives the reference value
        (None: the registered reference estimator).
    timeout
        Seconds per run before it is stopped and recorded as failed.
    quick
        Use the model's ``--quick`` defaults for what is not given.
    posterior
        Compute the reference posterior of each run's data on its model mesh
        (expensive: a grid of path simulations for p = 1, MCMC otherwise) and
        add its columns; default False.
    posterior_settings
        Its :class:`~idbench.estimate.posterior.PosteriorSettings` fields, e.g.
        ``{"points": 101, "max_solves": 20000}``.
    observe
        Observation-model sweep axis (:mod:`idbench.observe.kinds`): ``markers``
        (default), ``cloud``, ``force``, a name of an ``[observe.NAME]`` table,
        or blocks joined by ``+`` (``cloud+force``).
    observe_settings
        ``[observe.NAME]`` tables of settings, e.g. ``{"cloud": {"points": 500}}``;
        a table with ``kind`` defines a variant of that kind.
    data
        A recording folder (:mod:`idbench.store.recording`) to observe instead of a
        simulated truth; it sets the scenario, steps, observation model,
        markers and noise, and there is no truth mesh.
    calibration
        :class:`~idbench.calibrate.design.CalibrationSettings` fields of the
        offline calibration that the runs of an estimator with ``correction =
        "approximation-error"`` use, e.g. ``{"mesh": "40x5x5", "scenarios":
        ["bend-y", "mixed-30"]}``; the mesh defaults to the truth mesh spec,
        the scenarios to the run's own.
    registration
        How a recording in the camera's frame is moved into the body's:
        ``"rigid"`` (None, the default: its rest cloud registered to each model
        mesh's rest surface) or ``"with-model"`` (that pose then refined with the
        model, the pose and the moduli fitted together on every frame:
        :mod:`idbench.calibrate.pose`).
    """

    estimators: tuple[str, ...] | None = None
    meshes: tuple[str, ...] | None = None
    truth_mesh: str | None = None
    scenarios: tuple[str, ...] | None = None
    obs_every: tuple[int, ...] = (2,)
    obs_points: tuple[int, ...] = (2,)
    noise: tuple[float, ...] = (1e-4,)
    seeds: int = 3
    steps: int = 20
    true: dict[str, float] = field(default_factory=dict)
    prior: tuple[float, float] | None = None
    model: str | None = None
    model_settings: dict[str, dict[str, Any]] = field(default_factory=dict)
    estimator_settings: dict[str, dict[str, Any]] = field(default_factory=dict)
    reference: str | None = None
    timeout: float | None = None
    quick: bool = False
    posterior: bool = False
    posterior_settings: dict[str, Any] = field(default_factory=dict)
    observe: tuple[str, ...] = ("markers",)
    observe_settings: dict[str, dict[str, Any]] = field(default_factory=dict)
    data: str | None = None
    calibration: dict[str, Any] = field(default_factory=dict)
    registration: str | None = None

    def __post_init__(self) -> None:
        if self.registration is not None and self.registration not in REGISTRATIONS:
            raise ConfigError(
                f"registration {self.registration!r}: allowed: "
                f"{', '.join(REGISTRATIONS)}"
            )
        for name in ("estimators", "meshes", "scenarios"):
            if getattr(self, name) is not None:
                _check_names(name, getattr(self, name))
        if self.truth_mesh is not None and (
            not isinstance(self.truth_mesh, str) or not self.truth_mesh
        ):
            raise ConfigError(f"truth_mesh {self.truth_mesh!r}: need a mesh spec")
        for axis in ("obs_every", "obs_points", "noise"):
            _check_axis(axis, getattr(self, axis))
        _check_names("observe", self.observe)
        for k in self.obs_every:
            _check_int("obs_every", k, 1)
        for m in self.obs_points:
            _check_int("obs_points", m, 1)
        for s in self.noise:
            if not _finite(s) or s < 0:
                raise ConfigError(f"noise {s!r}: must be a number >= 0")
            if s > MAX_NOISE:
                raise ConfigError(
                    f"noise {s!r}: must be <= {MAX_NOISE:g} (a larger sigma "
                    "overflows the estimators' arithmetic)"
                )
        _check_int("seeds", self.seeds, 1)
        _check_int("steps", self.steps, 1)
        never = [k for k in self.obs_every if k > self.steps]
        if never:
            raise ConfigError(
                f"obs_every {never[0]} > steps {self.steps}: no step of the path "
                f"would be observed; need obs_every <= steps"
            )
        if not isinstance(self.true, dict):
            raise ConfigError(f"true {self.true!r}: need a table of NAME = value")
        for name, value in self.true.items():
            if not _finite(value):
                raise ConfigError(f"true value {name} = {value!r}: need a number")
        if self.prior is not None and (
            not isinstance(self.prior, tuple | list)
            or len(self.prior) != 2
            or not all(_finite(v) for v in self.prior)
            or not self.prior[1] > 0
        ):
            raise ConfigError(
                f"prior {self.prior!r}: need MEAN,STD, numbers, STD > 0"
            )
        for name in ("model", "reference"):
            value = getattr(self, name)
            if value is not None and (not isinstance(value, str) or not value.strip()):
                raise ConfigError(f"{name} {value!r}: need a registered name")
        if self.timeout is not None and (
            not _finite(self.timeout) or not 0 < self.timeout <= MAX_TIMEOUT
        ):
            raise ConfigError(
                f"timeout {self.timeout!r}: must be a number in (0, {MAX_TIMEOUT:g}] "
                "(seconds)"
            )
        if not isinstance(self.posterior, bool):
            raise ConfigError(f"posterior {self.posterior!r}: need true or false")
        if not isinstance(self.posterior_settings, dict):
            raise ConfigError(
                f"posterior_settings {self.posterior_settings!r}: need a table of "
                "name = value"
            )
        if not isinstance(self.calibration, dict):
            raise ConfigError(
                f"calibration {self.calibration!r}: need a table of name = value"
            )
        for what in ("model_settings", "estimator_settings", "observe_settings"):
            tables = getattr(self, what)
            if not isinstance(tables, dict):
                raise ConfigError(
                    f"{what} {tables!r}: need a table of [NAME] tables of settings"
                )
            for name, settings in tables.items():
                if not isinstance(settings, dict):
                    raise ConfigError(
                        f"{what.split('_')[0]} settings for {name!r}: {settings!r} "
                        "is not a table of name = value"
                    )
        if self.is_resolved():
            self.check_size()

    def is_resolved(self) -> bool:
        """Whether every default has been filled in (see :meth:`resolve`)."""
        return None not in (
            self.estimators, self.meshes, self.truth_mesh, self.scenarios,
            self.prior, self.model, self.reference,
        )  # fmt: skip

    def check_size(self) -> None:
        """Refuse a grid of more than :func:`max_runs` runs before building it."""
        n_runs = self.n_runs()
        if n_runs > max_runs():
            raise ConfigError(
                f"{n_runs:,} runs: more than the limit of {max_runs():,} "
                f"(set {MAX_RUNS_ENV} to raise it)"
            )

    def n_runs(self) -> int:
        """Number of runs of the grid (resolved config), counted without building it."""
        return (
            len(self.scenarios or ())
            * len(self.meshes or ())
            * len(self.obs_every)
            * len(self.obs_points)
            * len(self.noise)
            * len(self.observe)
            * len(self.estimators or ())
            * self.seeds
        )

    @classmethod
    def quick_config(cls, **overrides: Any) -> CompareConfig:
        """The small comparison of ``--quick``: coarse truth, one seed."""
        return cls(**{"quick": True, "seeds": 1, **overrides})

    def resolve(self, registry: Any) -> CompareConfig:
        """A copy with every None filled from ``registry``.

        Raises
        ------
        ConfigError
            If no model can be chosen or the model has no defaults for a value
            the config leaves open.
        """
        try:
            model = self.model or registry.default_model()
        except KeyError as exc:
            raise ConfigError(str(exc.args[0])) from None
        if model not in registry.models:
            allowed = ", ".join(sorted(registry.models)) or "none registered"
            raise ConfigError(
                f"unknown model {model!r}{suggest(model, registry.models)}; "
                f"allowed: {allowed}{registry.broken()}"
            )
        proposed = self._proposed(registry, model)
        defaults = proposed or registry.models[model].defaults
        fill: dict[str, Any] = {"model": model}
        if defaults is not None:
            quick = dict(defaults.quick) if self.quick else {}
            fill["truth_mesh"] = quick.get("truth_mesh", defaults.truth_mesh)
            fill["meshes"] = tuple(quick.get("meshes", defaults.meshes))
            fill["scenarios"] = tuple(quick.get("scenarios", defaults.scenarios))
            fill["prior"] = tuple(defaults.prior)
        fill["estimators"] = tuple(
            n for n, e in registry.estimators.items() if by_default(e.obj)
        )
        if self.reference is None:
            try:
                fill["reference"] = registry.reference_estimator()
            except KeyError as exc:
                raise ConfigError(str(exc.args[0])) from None
        given = {k: v for k, v in dataclasses.asdict(self).items() if v is not None}
        missing = [k for k in fill if k not in given and fill[k] is None]
        merged = {**fill, **given}
        for name in ("truth_mesh", "meshes", "scenarios", "prior"):
            empty = name not in given and merged.get(name) == ()  # proposed empty
            if merged.get(name) is None or empty:
                missing.append(name)
        if missing:
            who = "with these settings proposes" if proposed else "registers"
            raise ConfigError(
                f"model {model!r} {who} no default for {', '.join(missing)}: "
                "give them (see idbench compare --help)"
            )
        merged["model_settings"] = self.model_settings
        merged["estimator_settings"] = self.estimator_settings
        merged["true"] = self.true
        merged["posterior_settings"] = self.posterior_settings
        merged["observe_settings"] = self.observe_settings
        merged["calibration"] = self.calibration
        return CompareConfig(**merged)

    def _proposed(self, registry: Any, model: str) -> ModelDefaults | None:
        """The defaults the model's settings propose (see :func:`proposed_defaults`).

        Settings that cannot be built propose nothing here: the plan names
        the bad value.
        """
        cls = registry.models[model].settings
        if cls is None or settings_member(cls, "proposed_defaults") is None:
            return None
        given = self.model_settings.get(model, {})
        try:
            settings = build_settings(cls, given, f"model {model!r}")
        except ConfigError:
            return None
        return proposed_defaults(settings, model)

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
        out = dataclasses.asdict(self)
        for name in ("data", "registration"):  # folders written before match
            if out[name] is None:
                del out[name]
        return out


def max_runs() -> int:
    """The largest comparison accepted: ``$IDBENCH_MAX_RUNS`` or 100,000 runs."""
    text = os.environ.get(MAX_RUNS_ENV, "")
    try:
        return int(text) if text else DEFAULT_MAX_RUNS
    except ValueError:
        raise ConfigError(f"{MAX_RUNS_ENV}={text!r}: need a whole number") from None


FIELDS = {f.name for f in dataclasses.fields(CompareConfig)} - {
    "model_settings",
    "estimator_settings",
    "observe_settings",
}
LIST_FIELDS = {
    "estimators", "meshes", "scenarios", "obs_every", "obs_points", "noise", "observe",
}


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


def normalise(
    raw: dict[str, Any], origin: str, shorthands: dict[str, str] | None = None
) -> dict[str, Any]:
    """Turn TOML or CLI keys and values into :class:`CompareConfig` fields.

    Dashes in keys become underscores; list axes accept a list or a scalar;
    ``[estimators.NAME]`` tables become ``estimator_settings``, ``[model.NAME]``
    tables ``model_settings``; a key in ``shorthands`` (a model's shorthand
    option -> its setting, or ``true.NAME``) goes to ``shorthand_settings``,
    which :func:`build_config` hands to the chosen model (or to ``true``).
    """
    shorthands = {k.replace("-", "_"): v for k, v in (shorthands or {}).items()}
    out: dict[str, Any] = {}
    for key, value in raw.items():
        k = key.replace("-", "_")
        if k in ("estimators", "model", "observe") and isinstance(value, dict):
            target = {"estimators": "estimator_settings", "model": "model_settings",
                      "observe": "observe_settings"}[k]  # fmt: skip
            for n, v in value.items():
                if not isinstance(v, dict):
                    raise ConfigError(
                        f"{origin}: [{k}] {n} = {v!r}: need a table [{k}.{n}] of "
                        "settings"
                    )
            out[target] = {str(n): dict(v) for n, v in value.items()}
            continue
        if k in shorthands:
            target = shorthands[k]
            if target.startswith("true."):
                out.setdefault("true", {})[target.removeprefix("true.")] = value
            else:
                out.setdefault("shorthand_settings", {})[target] = value
            continue
        if k not in FIELDS:
            allowed = FIELDS | set(shorthands)
            raise ConfigError(f"{origin}: unknown key {key!r}{suggest(k, allowed)}")
        if k in LIST_FIELDS:
            value = tuple(value) if isinstance(value, list | tuple) else (value,)
        elif k == "prior" and isinstance(value, list):
            value = tuple(value)
        out[k] = value
    return out


def load_toml(path: Path, shorthands: dict[str, str] | None = None) -> dict[str, Any]:
    """Read a TOML config file into normalised fields (see :func:`normalise`)."""
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
        return {
            **normalise(compare, origin, shorthands),
            **normalise(raw, origin, shorthands),
        }
    return normalise(raw, origin, shorthands)


def build_config(
    *,
    quick: bool = False,
    toml: dict[str, Any] | None = None,
    registry: Any = None,
    **cli: Any,
) -> CompareConfig:
    """Merge TOML fields and CLI fields (CLI wins) into a validated config.

    ``shorthand_settings`` (from a model's shorthand options) and a single
    ``[model.NAME]`` table apply to the chosen model: ``model`` if given, else
    the one ``[model.NAME]`` table, else ``registry``'s default model.
    """
    toml = dict(toml or {})
    given = {k: v for k, v in cli.items() if v is not None}
    fields = {**toml, **given}
    tables = ("estimator_settings", "model_settings", "shorthand_settings", "true",
              "observe_settings", "calibration")  # fmt: skip
    for table in tables:
        if table in toml and table in given:
            fields[table] = {**toml[table], **given[table]}
    short = fields.pop("shorthand_settings", {})
    models = dict(fields.get("model_settings", {}))
    if "model" not in fields and len(models) == 1:
        fields["model"] = next(iter(models))
    if short:
        name = fields.get("model")
        if name is None and registry is not None:
            try:
                name = registry.default_model()
            except KeyError as exc:
                raise ConfigError(str(exc.args[0])) from None
        if name is None:
            raise ConfigError("model options given but no model named (--model)")
        fields["model"] = name
        models[name] = {**models.get(name, {}), **short}  # shorthands win
        fields["model_settings"] = models
    quick = quick or bool(fields.get("quick", False))
    if quick:
        fields.setdefault("seeds", 1)
    try:
        return CompareConfig(**{**fields, "quick": quick})
    except TypeError as exc:
        raise ConfigError(str(exc)) from None
