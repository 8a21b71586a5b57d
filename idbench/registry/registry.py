"""The plugin manager and the registry it fills.

Built-in plugins ship in the ``idbench`` distribution and are declared in its
``[project.entry-points.idbench]`` table, exactly like third-party plugins.
:func:`get_plugin_manager` registers those first (by entry-point name), then
loads third-party entry points unless ``IDBENCH_DISABLE_PLUGIN_AUTOLOAD`` is set.
Nothing is loaded at import time.
"""

from __future__ import annotations

import dataclasses
import importlib.metadata
import logging
import os
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import pluggy

from idbench.core.capabilities import (
    estimator_member,
    is_reference,
    lacking,
    plugin_version_of,
)
from idbench.core.interfaces import ModelDefaults
from idbench.core.observation_model import ObservationModel
from idbench.core.scenario import Scenario
from idbench.core.settings import undeclared_settings
from idbench.registry import hookspecs

log = logging.getLogger(__name__)

GROUP = "idbench"
DISTRIBUTION = "idbench"
AUTOLOAD_ENV = "IDBENCH_DISABLE_PLUGIN_AUTOLOAD"

hookimpl = pluggy.HookimplMarker(GROUP)


class PluginError(RuntimeError):
    """A plugin registered something invalid or a name another plugin owns."""


def _is_builtin(ep: importlib.metadata.EntryPoint) -> bool:
    dist = ep.dist
    return dist is not None and dist.metadata["Name"] == DISTRIBUTION


def get_plugin_manager(*, autoload: bool | None = None) -> pluggy.PluginManager:
    """Build a fresh plugin manager.

    Parameters
    ----------
    autoload
        Load third-party entry points. Default: yes, unless the environment
        variable ``IDBENCH_DISABLE_PLUGIN_AUTOLOAD`` is set to a non-empty value
        other than ``0``. Built-in plugins are always registered.

    Returns
    -------
    pluggy.PluginManager
        With the hook specs added and every plugin registered.
    """
    pm = pluggy.PluginManager(GROUP)
    pm.add_hookspecs(hookspecs)
    if autoload is None:
        autoload = os.environ.get(AUTOLOAD_ENV, "") in ("", "0")
    eps = importlib.metadata.entry_points(group=GROUP)
    for ep in eps:
        if _is_builtin(ep) and pm.get_plugin(ep.name) is None:
            pm.register(ep.load(), name=ep.name)
            _versions(pm)[ep.name] = ep.dist.version if ep.dist else ""
    if autoload:
        for ep in eps:
            if pm.get_plugin(ep.name) is not None or pm.is_blocked(ep.name):
                continue
            try:
                pm.register(ep.load(), name=ep.name)
                pm.check_pending()
            except Exception as exc:  # a broken plugin must not take down the rest
                log.warning("plugin %r failed to load: %s", ep.name, exc)
                pm.set_blocked(ep.name)  # unregisters it if it got registered
                _load_errors(pm)[ep.name] = f"failed to load: {exc!r}"
                continue
            _versions(pm)[ep.name] = ep.dist.version if ep.dist else ""
    pm.check_pending()
    return pm


def _load_errors(pm: pluggy.PluginManager) -> dict[str, str]:
    errors: dict[str, str] = pm.__dict__.setdefault("_idbench_load_errors", {})
    return errors


def _versions(pm: pluggy.PluginManager) -> dict[str, str]:
    versions: dict[str, str] = pm.__dict__.setdefault("_idbench_versions", {})
    return versions


@dataclass
class Entry:
    """One registered thing and the plugin it came from.

    Attributes
    ----------
    name, obj, plugin
        The registry name, what was registered, and by which plugin.
    settings
        Models: the settings dataclass (None: the model has no settings).
    defaults
        Models: their :class:`~idbench.core.interfaces.ModelDefaults`, or None.
    """

    name: str
    obj: Any
    plugin: str
    settings: type | None = None
    defaults: ModelDefaults | None = None


@dataclass(frozen=True)
class Command:
    """A subcommand of ``idbench`` contributed by a plugin.

    Attributes
    ----------
    help
        One line for ``idbench --help``.
    configure
        ``configure(parser)`` adds the command's arguments to an
        :class:`argparse.ArgumentParser`.
    run
        ``run(args) -> int`` executes it (its exit status). Raising
        :class:`idbench.ConfigError` (or ``ValueError``) prints one line and
        exits with status 2.
    """

    help: str
    configure: Callable[[Any], None]
    run: Callable[[Any], int]


@dataclass
class Registry:
    """Models, estimators and scenarios contributed by the plugins.

    Attributes
    ----------
    models, estimators, scenarios, commands, observations
        Name -> :class:`Entry` (observations: the plugins' observation
        models; the core's own are :data:`idbench.observe.kinds.BUILTIN`).
    errors
        Plugin name -> message, for plugins that failed to load or register.
    versions
        Plugin name -> version of the distribution that provides it (``""``
        if unknown), for every plugin whose hooks ran (see
        :func:`plugin_version`); a results folder records those its runs used.
    packages
        Plugin name -> {package: version} that the plugin reported through
        ``register_versions``: the libraries its results depend on.
    """

    models: dict[str, Entry] = field(default_factory=dict)
    estimators: dict[str, Entry] = field(default_factory=dict)
    scenarios: dict[str, Entry] = field(default_factory=dict)
    commands: dict[str, Entry] = field(default_factory=dict)
    observations: dict[str, Entry] = field(default_factory=dict)
    errors: dict[str, str] = field(default_factory=dict)
    versions: dict[str, str] = field(default_factory=dict)
    packages: dict[str, dict[str, str]] = field(default_factory=dict)

    def default_model(self) -> str:
        """The model a comparison uses when none is named.

        The only model with defaults, else the one registered as primary.

        Raises
        ------
        KeyError
            If that does not single one out; the message lists the choices.
        """
        usable = [n for n, e in self.models.items() if e.defaults is not None]
        primary = [n for n in usable if self.models[n].defaults.primary]  # type: ignore[union-attr]
        if len(usable) == 1:
            return usable[0]
        if len(primary) == 1:
            return primary[0]
        allowed = ", ".join(sorted(self.models)) or "none registered"
        raise KeyError(f"no default model: name one with --model ({allowed})")

    def reference_estimator(self) -> str:
        """The estimator whose fit gives E_ref: the one flagged ``reference``.

        An estimator class marks itself with a class attribute
        ``reference = True`` (the best constant fit over the whole path).
        """
        flagged = [
            n for n, e in self.estimators.items() if is_reference(e.obj)
        ]
        if len(flagged) != 1:
            allowed = ", ".join(sorted(self.estimators)) or "none registered"
            raise KeyError(
                f"no single reference estimator registered ({len(flagged)} flagged): "
                f"name one with reference = NAME ({allowed})"
            )
        return flagged[0]

    def model(self, name: str) -> Callable[..., Any]:
        """The model factory registered as ``name``."""
        return _lookup(self.models, name, "model").obj  # type: ignore[no-any-return]

    def estimator(self, name: str) -> type:
        """The estimator class registered as ``name``."""
        return _lookup(self.estimators, name, "estimator").obj  # type: ignore[no-any-return]

    def scenario(self, name: str) -> Scenario:
        """The scenario registered as ``name``."""
        return _lookup(self.scenarios, name, "scenario").obj  # type: ignore[no-any-return]

    def with_scenarios(self, scenarios: list[Scenario], plugin: str) -> Registry:
        """A copy that also knows ``scenarios`` (ad-hoc load paths of a tool)."""
        added = {sc.name: Entry(sc.name, sc, plugin) for sc in scenarios}
        return dataclasses.replace(self, scenarios={**self.scenarios, **added})

    def broken(self) -> str:
        """A note naming the plugins that failed (empty if none), for messages."""
        if not self.errors:
            return ""
        names = ", ".join(sorted(self.errors))
        return f" (disabled plugins: {names}; see 'idbench plugins')"


def _lookup(table: dict[str, Entry], name: str, kind: str) -> Entry:
    try:
        return table[name]
    except KeyError:
        allowed = ", ".join(sorted(table)) or "none registered"
        raise KeyError(f"unknown {kind} {name!r}; allowed: {allowed}") from None


def _add(table: dict[str, Entry], kind: str, name: Any, obj: Any, plugin: str) -> None:
    if not isinstance(name, str) or not name:
        raise PluginError(
            f"plugin {plugin!r} registered a {kind} with bad name {name!r}"
        )
    if name in table:
        raise PluginError(
            f"{kind} {name!r} is registered by both plugin {table[name].plugin!r} "
            f"and plugin {plugin!r}; uninstall or disable one of them"
        )
    table[name] = Entry(name, obj, plugin)


def _check_dataclass(obj: Any, plugin: str, what: str) -> None:
    """Raise :class:`PluginError` unless ``obj`` is a dataclass type."""
    if not (isinstance(obj, type) and dataclasses.is_dataclass(obj)):
        raise PluginError(f"plugin {plugin!r}: {what} must be a dataclass type")


def build_registry(pm: pluggy.PluginManager | None = None) -> Registry:
    """Call every plugin's ``register_*`` hooks and collect the results.

    A plugin whose hook raises, or that registers something invalid or a name
    another plugin already owns, is recorded in :attr:`Registry.errors` (the
    message names both plugins for a duplicate), everything it registered is
    withdrawn, and the others go on. Built-in plugins register first, so a
    third-party plugin can never take a built-in name.
    """
    pm = pm or get_plugin_manager()
    reg = Registry(errors=dict(_load_errors(pm)))

    def model_cb(plugin: str) -> Callable[..., None]:
        def register(
            name: str,
            factory: Callable[..., Any],
            *,
            settings: type | None = None,
            defaults: ModelDefaults | None = None,
        ) -> None:
            if not callable(factory):
                raise PluginError(f"plugin {plugin!r}: model {name!r} is not callable")
            if settings is not None:
                _check_dataclass(settings, plugin, f"settings of model {name!r}")
            if defaults is not None and not isinstance(defaults, ModelDefaults):
                raise PluginError(
                    f"plugin {plugin!r}: defaults of model {name!r} must be an "
                    "idbench.ModelDefaults"
                )
            _add(reg.models, "model", name, factory, plugin)
            reg.models[name].settings = settings
            reg.models[name].defaults = defaults

        return register

    def command_cb(plugin: str) -> Callable[[str, Command], None]:
        def register(name: str, command: Command) -> None:
            if not isinstance(command, Command):
                raise PluginError(
                    f"plugin {plugin!r}: command {name!r} must be an idbench.Command"
                )
            _add(reg.commands, "command", name, command, plugin)

        return register

    def estimator_cb(plugin: str) -> Callable[[str, type], None]:
        def register(name: str, cls: type) -> None:
            _check_dataclass(cls, plugin, f"estimator {name!r}")
            unfielded = undeclared_settings(cls)
            if unfielded:
                raise PluginError(
                    f"plugin {plugin!r}: estimator {name!r} has settings that are "
                    f"no dataclass fields ({', '.join(unfielded)}): decorate their "
                    "class with @dataclass"
                )
            if estimator_member(cls, "abstract"):
                raise PluginError(
                    f"plugin {plugin!r}: estimator {name!r} is an abstract base "
                    f"({cls.__name__}, abstract=True): register its subclasses"
                )
            _add(reg.estimators, "estimator", name, cls, plugin)

        return register

    def observation_cb(plugin: str) -> Callable[[str, type], None]:
        def register(name: str, cls: type) -> None:
            _check_dataclass(cls, plugin, f"observation model {name!r}")
            missing = lacking(cls, ObservationModel)
            if missing:
                raise PluginError(
                    f"plugin {plugin!r}: observation model {name!r} is no "
                    f"idbench.ObservationModel: it lacks {', '.join(missing)}"
                )
            if name in ("markers", "cloud", "force"):
                raise PluginError(
                    f"plugin {plugin!r}: observation model {name!r} is idbench's own"
                )
            _add(reg.observations, "observation model", name, cls, plugin)

        return register

    def versions_cb(plugin: str) -> Callable[[str, str], None]:
        def register(package: str, version: str) -> None:
            for what, value in (("package", package), ("version", version)):
                if not isinstance(value, str) or not value.isprintable():
                    raise PluginError(
                        f"plugin {plugin!r}: register_versions {what} {value!r} "
                        "is not a printable string"
                    )
            reg.packages.setdefault(plugin, {})[package] = version

        return register

    def scenario_cb(plugin: str) -> Callable[[Any], None]:
        def register(scenario: Any) -> None:
            if not isinstance(scenario, Scenario):
                raise PluginError(f"plugin {plugin!r}: {scenario!r} is not a Scenario")
            _add(reg.scenarios, "scenario", scenario.name, scenario, plugin)

        return register

    hooks: list[tuple[Any, Callable[[str], Any]]] = [
        (pm.hook.register_scenarios, scenario_cb),
        (pm.hook.register_models, model_cb),
        (pm.hook.register_estimators, estimator_cb),
        (pm.hook.register_commands, command_cb),
        (pm.hook.register_observations, observation_cb),
        (pm.hook.register_versions, versions_cb),
    ]
    for hook, make_cb in hooks:
        for impl in hook.get_hookimpls():
            plugin = pm.get_name(impl.plugin) or repr(impl.plugin)
            if plugin in reg.errors:
                continue
            reg.versions.setdefault(plugin, plugin_version(pm, plugin))
            try:
                impl.function(register=make_cb(plugin))
            except PluginError as exc:
                _withdraw(reg, plugin, str(exc))
            except Exception as exc:
                _withdraw(reg, plugin, f"failed while registering: {exc!r}")
    return reg


_CACHED: list[Registry] = []


def cached_registry() -> Registry:
    """The registry of the installed plugins, built once per process.

    The command line's (plugins are imported on first use); call
    :func:`reset_registry_cache` when the plugins may have changed.
    """
    if not _CACHED:
        _CACHED.append(build_registry())
    return _CACHED[0]


def reset_registry_cache() -> None:
    """Forget the registry :func:`cached_registry` built."""
    _CACHED.clear()


def used_plugins(reg: Registry, *names: tuple[str, list[str]]) -> dict[str, str]:
    """Plugin -> version of the plugins that registered the given names.

    ``names`` are (table, registered names) pairs, the table one of
    ``"models"``, ``"estimators"``, ``"scenarios"``; names not registered are
    skipped.
    """
    out: dict[str, str] = {}
    for table, registered in names:
        entries = getattr(reg, table)
        for name in registered:
            if name in entries:
                plugin = entries[name].plugin
                out[plugin] = reg.versions.get(plugin, "")
    return dict(sorted(out.items()))


def _withdraw(reg: Registry, plugin: str, message: str) -> None:
    """Record ``plugin`` as broken and remove all it registered."""
    log.warning("plugin %r disabled: %s", plugin, message)
    reg.errors[plugin] = message
    tables = (reg.models, reg.estimators, reg.scenarios, reg.commands,
              reg.observations)  # fmt: skip
    for table in tables:
        for key in [k for k, e in table.items() if e.plugin == plugin]:
            del table[key]


def plugin_version(pm: pluggy.PluginManager, name: str) -> str:
    """Version of the distribution that provides plugin ``name``, or ``""``."""
    if name in _versions(pm):
        return _versions(pm)[name]
    plugin = pm.get_plugin(name)
    return plugin_version_of(plugin)
