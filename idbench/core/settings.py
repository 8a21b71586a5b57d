"""The rules of settings: how a settings dataclass takes the user's values.

Models and estimators declare their settings as dataclasses (their fields,
with defaults). This module builds them from what the user gave (unknown
names and values of the wrong kind refused with one :class:`ConfigError`
line), says which of them identify the data and which only change where or
how fast work runs (``EXECUTION``), asks a model's settings what comparison
and scenarios they propose, and fills the true parameter values. The
comparison's own settings are :class:`idbench.plan.config.CompareConfig`.
"""

from __future__ import annotations

import dataclasses
import difflib
import math
import os
import types
import typing
from typing import Any

import numpy as np

from idbench.core.capabilities import settings_member
from idbench.core.interfaces import ConfigError, ModelDefaults, ParameterSpec
from idbench.core.scenario import Scenario


def suggest(key: str, allowed: Any) -> str:
    """A ``did you mean`` hint, or an empty string."""
    close = difflib.get_close_matches(key, sorted(allowed), n=1)
    return f" (did you mean {close[0]!r}?)" if close else ""


def finite_number(x: Any) -> bool:
    """Whether ``x`` is a finite int or float (not a bool)."""
    return isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x)


def check_choice(name: str, value: Any, allowed: typing.Sequence[str]) -> None:
    """Raise ``ValueError`` (one line) unless ``value`` is one of ``allowed``."""
    if value not in allowed:
        raise ValueError(
            f"{name} = {value!r} is not allowed; use one of "
            + ", ".join(repr(a) for a in allowed)
        )


# --- building a settings object ------------------------------------------------


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


def is_classvar(hint: Any) -> bool:
    """Whether an annotation (maybe a string) declares a ``ClassVar`` or ``InitVar``.

    Neither is a setting: the first is a class constant, the second an
    argument of ``__post_init__``.
    """
    if isinstance(hint, str):
        head = hint.split("[", 1)[0].strip().rsplit(".", 1)[-1]
        return head in ("ClassVar", "InitVar")
    origin = typing.get_origin(hint) or hint
    return origin is typing.ClassVar or isinstance(hint, dataclasses.InitVar)


def has_default(value: Any) -> bool:
    """Whether a class attribute gives its field a default.

    Any value does, a :func:`dataclasses.field` only with ``default`` or
    ``default_factory``, :data:`dataclasses.MISSING` (no attribute) not.
    """
    if isinstance(value, dataclasses.Field):
        return (
            value.default is not dataclasses.MISSING
            or value.default_factory is not dataclasses.MISSING
        )
    return value is not dataclasses.MISSING


def undeclared_settings(cls: type) -> list[str]:
    """The settings of a settings dataclass that are no dataclass fields.

    A setting is an annotated public class attribute (not ``ClassVar``) of
    ``cls`` or of a dataclass among its bases; one that is no field of
    ``dataclasses.fields(cls)`` was declared in a class not decorated with
    ``@dataclass``, so ``cls(setting=...)`` cannot set it. Named
    ``Class.setting``.
    """
    fields = set()
    if dataclasses.is_dataclass(cls):
        fields = {f.name for f in dataclasses.fields(cls)}
    out = []
    for base in cls.__mro__:
        if base is cls or dataclasses.is_dataclass(base):
            for name, hint in vars(base).get("__annotations__", {}).items():
                public = not name.startswith("_") and not is_classvar(hint)
                if public and name not in fields:
                    out.append(f"{base.__name__}.{name}")
    return out


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
        if arm is float and finite_number(value):
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


def model_settings(registry: Any, model: str, given: dict[str, Any]) -> Any:
    """The settings object of ``model`` with ``given`` values (None: no settings).

    ``registry``: a :class:`~idbench.registry.registry.Registry`.

    Raises
    ------
    ConfigError
        Naming an unknown setting (and the allowed ones) or a bad value.
    """
    entry = registry.models[model]
    cls = entry.settings
    if cls is None:
        if given:
            raise ConfigError(f"model {model!r} has no settings; got {sorted(given)}")
        return None
    what = f"model {model!r}"
    return build_settings(cls, _typed(cls, given, what), what)


def _typed(cls: type, given: dict[str, Any], what: str) -> dict[str, Any]:
    """``given`` checked against the field types, whole numbers as floats.

    So that ``nu=0`` and ``nu=0.0`` are one setting (one run id, one noise
    seed), and ``nu=abc`` is one line (:func:`typed_values`).
    """
    return typed_values(cls, given, what)


def estimator_arguments(cls: type, settings: Any, seed: int) -> dict[str, Any]:
    """Keyword arguments for an estimator class: its settings, plus the run's seed.

    An estimator with a ``seed`` setting (its own random draws) gets the run's
    seed unless the user set one, so seeds differ between the runs of a sweep
    and repeat with them. The seed is not added to the settings themselves:
    the run id (and resuming) stays as it was.
    """
    kwargs = dict(settings)
    try:
        seeded = "seed" in public_settings(cls)
    except TypeError:  # not a dataclass: no settings we can see
        seeded = False
    if seeded and "seed" not in kwargs:
        kwargs["seed"] = int(seed)
    return kwargs


# --- what identifies the data ---------------------------------------------------


def settings_items(settings: Any) -> tuple[tuple[str, Any], ...]:
    """Sorted (name, value) items of a settings object (empty for None).

    Its execution settings (:func:`execution_names`) are left out.
    """
    if settings is None:
        return ()
    skip = set(execution_names(settings))
    return tuple(sorted(i for i in dataclasses.asdict(settings).items()
                        if i[0] not in skip))  # fmt: skip


def execution_names(settings: Any) -> tuple[str, ...]:
    """The settings that change where or how fast work runs, not its results.

    A settings dataclass names them in a class attribute ``EXECUTION`` (a
    tuple of field names; e.g. helper processes). They reach the model but
    are left out of run ids, model keys, result rows and the check that an
    output folder holds the same comparison, so changing them resumes a
    comparison instead of starting another. A settings class that defines
    ``identity()`` must leave them out of it, and the model out of its
    ``describe()`` (both key data and caches).
    """
    return tuple(settings_member(settings, "EXECUTION"))


def execution_items(settings: Any) -> tuple[tuple[str, Any], ...]:
    """Sorted (name, value) items of the execution settings (empty for None)."""
    if settings is None:
        return ()
    names = execution_names(settings)
    return tuple(sorted((n, getattr(settings, n)) for n in names))


def settings_identity(settings: Any) -> tuple[Any, ...]:
    """What of ``settings`` identifies the data: its ``identity()`` or all of it."""
    identity = settings_member(settings, "identity")
    if identity is not None:
        return tuple(identity())
    return tuple([list(item) for item in settings_items(settings)])


# --- what a model's settings propose --------------------------------------------


def proposed_defaults(settings: Any, model: str) -> ModelDefaults | None:
    """The comparison a model's settings object proposes (None: the registered).

    A settings class may define ``proposed_defaults()`` returning a
    :class:`~idbench.core.interfaces.ModelDefaults` (or None) for what the user
    leaves open (truth mesh, meshes, scenarios, prior, ``--quick``), in place
    of the defaults registered with the model: the ``solid`` model's body
    file proposes its own meshes and manipulation.

    Raises
    ------
    ConfigError
        One line for the method's ValueError (bad input, e.g. a body file)
        or a bug (naming the model), or a result of the wrong type.
    """
    out = _ask(settings, "proposed_defaults", model)
    if out is not None and not isinstance(out, ModelDefaults):
        raise ConfigError(
            f"model {model!r}: proposed_defaults() returned {type(out).__name__}, "
            "not idbench.ModelDefaults or None"
        )
    return out


def proposed_scenarios(settings: Any, model: str) -> tuple[Scenario, ...]:
    """The scenarios a model's settings object brings (empty: none).

    A settings class may define ``proposed_scenarios()`` returning
    :class:`~idbench.Scenario` objects that exist for this configuration only
    (a body file's manipulations). Within a comparison of that model they
    take precedence over registered scenarios of the same name; every worker
    finds them the same way, from the run's settings.

    Raises
    ------
    ConfigError
        As :func:`proposed_defaults`; also for an item that is no Scenario.
    """
    out = _ask(settings, "proposed_scenarios", model)
    scenarios = tuple(out or ())
    for sc in scenarios:
        if not isinstance(sc, Scenario):
            raise ConfigError(
                f"model {model!r}: proposed_scenarios() gave {sc!r}, not an "
                "idbench.Scenario"
            )
    return scenarios


def _ask(settings: Any, method: str, model: str) -> Any:
    """Call ``settings.method()`` if it exists; its errors as one ConfigError."""
    call = settings_member(settings, method)
    if call is None:
        return None
    try:
        return call()
    except ConfigError:
        raise
    except ValueError as exc:  # the user's input, as the model says it
        raise ConfigError(str(exc)) from None
    except Exception as exc:  # a plugin's own bug, still one clean line
        raise ConfigError(
            f"model {model!r}: {method}() raised {type(exc).__name__}: {exc}"
        ) from None


def true_values(
    parameters: ParameterSpec, given: dict[str, float], model: str
) -> tuple[tuple[str, float], ...]:
    """The true value of every parameter: ``given``, else the model's default.

    Raises
    ------
    ConfigError
        For a name the model does not have, a value missing without a default,
        or values outside the parameter bounds.
    """
    names = parameters.names
    for name in given:
        if name not in names:
            raise ConfigError(
                f"true value for {name!r}: model {model!r} has no such parameter; "
                f"its parameters: {', '.join(names)}"
            )
    defaults = parameters.default or (None,) * len(names)
    values = []
    for name, default in zip(names, defaults, strict=True):
        value = given.get(name, default)
        if value is None:
            raise ConfigError(
                f"no true value for parameter {name!r} of model {model!r}: "
                f"give one with --true {name}=VALUE"
            )
        values.append((name, float(value)))
    if not parameters.contains(np.array([v for _, v in values])):
        raise ConfigError(
            f"true values {dict(values)} lie outside the parameter bounds "
            f"{parameters.lower}..{parameters.upper}"
        )
    return tuple(values)
