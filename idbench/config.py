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
import types
import typing
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from idbench.scenario import Sparsity

MAX_RUNS_ENV = "IDBENCH_MAX_RUNS"
DEFAULT_MAX_RUNS = 100_000
"""Runs a comparison may have before it is refused (``$IDBENCH_MAX_RUNS``)."""

MAX_TIMEOUT = 30 * 24 * 3600.0
"""The longest ``timeout`` accepted: 30 days, in seconds."""

MAX_NOISE = 1e100
"""The largest noise sigma accepted (its square must not overflow)."""


class ConfigError(ValueError):
    """A setting is invalid; the message names the value and what is allowed."""


@dataclass(frozen=True)
class CompareConfig:
    """A grid of runs: scenarios x meshes x estimators x sparsity x seeds.

    Fields left at None are filled by :meth:`resolve` from what the plugins
    registered: the model's :class:`~idbench.interfaces.ModelDefaults`, every
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
        Its :class:`~idbench.posterior.PosteriorSettings` fields, e.g.
        ``{"points": 101, "max_solves": 20000}``.
    calibration
        :class:`~idbench.discrepancy.CalibrationSettings` fields of the
        offline calibration that the runs of an estimator with ``correction =
        "approximation-error"`` use, e.g. ``{"mesh": "40x5x5", "scenarios":
        ["bend-y", "mixed-30"]}``; the mesh defaults to the truth mesh spec,
        the scenarios to the run's own.
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
    calibration: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        for name in ("estimators", "meshes", "scenarios"):
            if getattr(self, name) is not None:
                _check_names(name, getattr(self, name))
        if self.truth_mesh is not None and (
            not isinstance(self.truth_mesh, str) or not self.truth_mesh
        ):
            raise ConfigError(f"truth_mesh {self.truth_mesh!r}: need a mesh spec")
        for axis in ("obs_every", "obs_points", "noise"):
            _check_axis(axis, getattr(self, axis))
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
        for what in ("model_settings", "estimator_settings"):
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
        defaults = registry.models[model].defaults
        fill: dict[str, Any] = {"model": model}
        if defaults is not None:
            quick = dict(defaults.quick) if self.quick else {}
            fill["truth_mesh"] = quick.get("truth_mesh", defaults.truth_mesh)
            fill["meshes"] = tuple(quick.get("meshes", defaults.meshes))
            fill["scenarios"] = tuple(quick.get("scenarios", defaults.scenarios))
            fill["prior"] = tuple(defaults.prior)
        fill["estimators"] = tuple(registry.estimators)
        if self.reference is None:
            try:
                fill["reference"] = registry.reference_estimator()
            except KeyError as exc:
                raise ConfigError(str(exc.args[0])) from None
        given = {k: v for k, v in dataclasses.asdict(self).items() if v is not None}
        missing = [k for k in fill if k not in given and fill[k] is None]
        merged = {**fill, **given}
        for name in ("truth_mesh", "meshes", "scenarios", "prior"):
            if merged.get(name) is None:
                missing.append(name)
        if missing:
            raise ConfigError(
                f"model {model!r} registers no default for {', '.join(missing)}: "
                "give them (see idbench compare --help)"
            )
        merged["model_settings"] = self.model_settings
        merged["estimator_settings"] = self.estimator_settings
        merged["true"] = self.true
        merged["posterior_settings"] = self.posterior_settings
        merged["calibration"] = self.calibration
        return CompareConfig(**merged)

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


FIELDS = {f.name for f in dataclasses.fields(CompareConfig)} - {
    "model_settings",
    "estimator_settings",
}
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


def build_settings(cls: type, given: dict[str, Any], what: str) -> Any:
    """``cls(**given)`` for a settings dataclass, or one ConfigError line.

    Parameters
    ----------
    cls
        The settings dataclass (an estimator, a model's settings, ...).
    given
        The user's values by setting name.
    what
        How messages name the owner, e.g. ``"estimator 'rls'"``.

    Raises
    ------
    ConfigError
        Naming an unknown setting (with a suggestion and the allowed ones) or
        the bad value (the class's own ValueError or TypeError message).
    """
    allowed = public_settings(cls)
    for key in given:
        if key not in allowed:
            raise ConfigError(
                f"{what} has no setting {key!r}{suggest(key, allowed)}; "
                f"allowed: {', '.join(allowed)}"
            )
    try:
        return cls(**given)
    except (TypeError, ValueError) as exc:
        raise ConfigError(f"{what}: {exc}") from None


def typed_values(cls: type, given: dict[str, Any], what: str) -> dict[str, Any]:
    """``given`` checked against the field types of settings dataclass ``cls``.

    A value of the wrong kind (text where a number is needed, a number where
    true or false is, a non-finite number) is refused with one line naming the
    setting, the value and the type expected. Whole numbers become floats
    where the field is a float, so that ``nu=0`` and ``nu=0.0`` are one
    setting, and text where it is text only (``reference=200``, a mesh spec
    that the command line reads as a number). Types other than numbers,
    bools, text, lists and their unions (``X | None``, ``Literal``) are not
    checked here: the class checks them.

    Raises
    ------
    ConfigError
        For the first value that does not fit its field's type.
    """
    try:
        hints = typing.get_type_hints(cls)
    except Exception:  # unresolvable annotations: leave the values as given
        return dict(given)
    out = dict(given)
    for name, value in given.items():
        hint = hints.get(name)
        whole = isinstance(value, int) and not isinstance(value, bool)
        if whole and _takes(hint, str) and not _takes(hint, int | float):
            value = out[name] = str(value)  # a mesh spec "200" read as a number
        if hint is None or _fits(hint, value):
            if _takes(hint, float) and whole:
                out[name] = float(value)
            continue
        raise ConfigError(
            f"{what}: {name} {value!r}: need {_kind(hint)}, got {type(value).__name__}"
        )
    return out


def _arms(hint: Any) -> tuple[Any, ...]:
    """The alternatives of a union type (the type itself otherwise)."""
    if typing.get_origin(hint) in (typing.Union, types.UnionType):
        return typing.get_args(hint)
    return (hint,)


def _takes(hint: Any, kind: Any) -> bool:
    """Whether one alternative of ``hint`` is one of the classes of ``kind``."""
    kinds = typing.get_args(kind) or (kind,)
    return any(arm in kinds for arm in _arms(hint))


def _fits(hint: Any, value: Any) -> bool:
    """Whether ``value`` has the kind ``hint`` asks for (unknown kinds: yes)."""
    for arm in _arms(hint):
        origin = typing.get_origin(arm)
        if arm is Any or (arm is type(None) and value is None):
            return True
        if arm is float and _finite(value):
            return True
        if arm is int and isinstance(value, int) and not isinstance(value, bool):
            return True
        if arm is bool and isinstance(value, bool):
            return True
        if arm is str and isinstance(value, str | os.PathLike):
            return True
        if origin is typing.Literal and value in typing.get_args(arm):
            return True
        if origin in (tuple, list) and isinstance(value, tuple | list):
            args = [a for a in typing.get_args(arm) if a is not Ellipsis]
            if all(any(_fits(a, v) for a in args or [Any]) for v in value):
                return True
        known = (float, int, bool, str, type(None), tuple, list)
        if arm not in known and origin not in (*known, typing.Literal):
            return True  # a kind the settings class checks itself
    return False


_KINDS = {
    float: ("a finite number", "numbers"),
    int: ("a whole number", "whole numbers"),
    bool: ("true or false", "bools"),
    str: ("a text", "texts"),
}


def _kind(hint: Any, plural: bool = False) -> str:
    """How a message names the kind of value ``hint`` asks for."""
    parts = []
    for arm in _arms(hint):
        origin = typing.get_origin(arm)
        if arm in _KINDS:
            parts.append(_KINDS[arm][plural])
        elif origin is typing.Literal:
            parts.append("one of " + ", ".join(map(repr, typing.get_args(arm))))
        elif origin in (tuple, list):
            args = [a for a in typing.get_args(arm) if a is not Ellipsis]
            inner = " or ".join(dict.fromkeys(_kind(a, True) for a in args))
            parts.append(f"a list of {inner or 'values'}")
    return " or ".join(parts) or str(hint)


def suggest(key: str, allowed: Any) -> str:
    """A ``did you mean`` hint, or an empty string."""
    close = difflib.get_close_matches(key, sorted(allowed), n=1)
    return f" (did you mean {close[0]!r}?)" if close else ""


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
        if k in ("estimators", "model") and isinstance(value, dict):
            target = "estimator_settings" if k == "estimators" else "model_settings"
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
              "calibration")  # fmt: skip
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
