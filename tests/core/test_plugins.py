"""The plugin system: manager, registry, CLI listing, packaging, docs."""

from __future__ import annotations

import importlib.metadata
import inspect
import json
import os
import subprocess
import sys
import textwrap
import types
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pluggy
import pytest
from support.helpers import run_fresh_python

import idbench
from idbench.registry import hookspecs
from idbench.registry.registry import AUTOLOAD_ENV

ROOT = Path(__file__).resolve().parents[2]

BUILTIN_MODELS = {"svk-beam"}
BUILTIN_ESTIMATORS = {"ro-ukf", "ukf", "rls", "lms", "batch-ls"}
BUILTIN_SCENARIOS = {"bend-y", "bend-z", "stretch-x", "mixed-30", "mixed-60"}


@dataclass
class TinyEstimator:
    """A do-nothing estimator, enough for the registry's dataclass check."""

    gain: float = 1.0

    def start(self, model: Any, prior: idbench.Prior) -> None:
        self._mean = np.asarray(prior.mean, dtype=float)

    def update(self, k: int, observation: Any) -> idbench.Estimate:
        return idbench.Estimate(
            self._mean, np.full_like(self._mean, np.nan), idbench.Cost()
        )


def _estimator_plugin(name: str, cls: type = TinyEstimator) -> types.SimpleNamespace:
    @idbench.hookimpl
    def register_estimators(register: Callable[[str, type], None]) -> None:
        register(name, cls)

    return types.SimpleNamespace(register_estimators=register_estimators)


@pytest.fixture
def pm() -> pluggy.PluginManager:
    """A fresh manager with the built-ins only (no third-party autoload)."""
    return idbench.get_plugin_manager(autoload=False)


@pytest.fixture
def add_plugin(
    pm: pluggy.PluginManager,
) -> Iterator[Callable[[object, str], object]]:
    """Register plugins on ``pm`` by name; unregister them afterwards."""
    added: list[object] = []

    def add(plugin: object, name: str) -> object:
        pm.register(plugin, name=name)
        added.append(plugin)
        return plugin

    yield add
    for plugin in added:
        if pm.is_registered(plugin):
            pm.unregister(plugin)


# --- built-ins -----------------------------------------------------------


def test_builtin_plugins_registered_without_autoload(pm: pluggy.PluginManager) -> None:
    names = {pm.get_name(p) for p in pm.get_plugins()}
    assert {"fem", "filters"} <= names


def test_builtin_registry_contents(pm: pluggy.PluginManager) -> None:
    reg = idbench.build_registry(pm)
    assert reg.errors == {}
    assert BUILTIN_MODELS <= set(reg.models)
    assert BUILTIN_ESTIMATORS <= set(reg.estimators)
    assert BUILTIN_SCENARIOS <= set(reg.scenarios)
    assert reg.models["svk-beam"].plugin == "fem"
    for name in BUILTIN_ESTIMATORS:
        assert reg.estimators[name].plugin == "filters"
    for name in BUILTIN_SCENARIOS:
        assert reg.scenarios[name].plugin == "fem"
        scenario = reg.scenario(name)
        assert isinstance(scenario, idbench.Scenario)
        assert scenario.name == name
    assert callable(reg.model("svk-beam"))
    assert isinstance(reg.estimator("ukf"), type)


# --- lookup ----------------------------------------------------------------


@pytest.mark.parametrize(
    ("method", "table", "kind"),
    [
        ("model", "models", "model"),
        ("estimator", "estimators", "estimator"),
        ("scenario", "scenarios", "scenario"),
    ],
)
def test_unknown_name_lists_allowed(
    pm: pluggy.PluginManager, method: str, table: str, kind: str
) -> None:
    reg = idbench.build_registry(pm)
    with pytest.raises(KeyError) as info:
        getattr(reg, method)("no-such-thing")
    message = str(info.value)
    assert "no-such-thing" in message
    assert kind in message
    allowed = getattr(reg, table)
    assert allowed, "built-ins should have registered something"
    for name in allowed:
        assert name in message


def test_unknown_name_in_empty_registry() -> None:
    with pytest.raises(KeyError, match="none registered"):
        idbench.Registry().estimator("x")


# --- duplicates and bad registrations ---------------------------------------


def test_duplicate_name_names_both_plugins(
    pm: pluggy.PluginManager, add_plugin: Callable[[object, str], object]
) -> None:
    add_plugin(_estimator_plugin("dup"), "first-plug")
    add_plugin(_estimator_plugin("dup"), "second-plug")
    reg = idbench.build_registry(pm)  # reported, not raised: the rest works
    message = reg.errors["second-plug"]
    assert "'dup'" in message
    assert "first-plug" in message
    assert "second-plug" in message
    assert reg.estimators["dup"].plugin == "first-plug"
    assert BUILTIN_ESTIMATORS <= set(reg.estimators)


def test_duplicate_of_builtin_name_rejected(
    pm: pluggy.PluginManager, add_plugin: Callable[[object, str], object]
) -> None:
    add_plugin(_estimator_plugin("ukf"), "shadow-plug")
    reg = idbench.build_registry(pm)
    assert "filters" in reg.errors["shadow-plug"]
    assert reg.estimators["ukf"].plugin == "filters"  # the built-in keeps it


def test_unique_third_party_name_accepted(
    pm: pluggy.PluginManager, add_plugin: Callable[[object, str], object]
) -> None:
    add_plugin(_estimator_plugin("tiny"), "tiny-plug")
    reg = idbench.build_registry(pm)
    assert reg.estimator("tiny") is TinyEstimator
    assert reg.estimators["tiny"].plugin == "tiny-plug"
    assert BUILTIN_ESTIMATORS <= set(reg.estimators)


def test_non_dataclass_estimator_rejected(
    pm: pluggy.PluginManager, add_plugin: Callable[[object, str], object]
) -> None:
    class NotADataclass:
        pass

    add_plugin(_estimator_plugin("bad", NotADataclass), "bad-plug")
    reg = idbench.build_registry(pm)
    assert "must be a dataclass" in reg.errors["bad-plug"]
    assert "bad" not in reg.estimators
    assert BUILTIN_ESTIMATORS <= set(reg.estimators)


def test_fixture_unregisters(pm: pluggy.PluginManager) -> None:
    # A fresh manager never carries plugins from earlier tests.
    names = {pm.get_name(p) for p in pm.get_plugins()}
    assert names == {"fem", "filters"}


# --- a plugin that raises while registering ---------------------------------


class _Boom(RuntimeError):
    pass


class RaisingPlugin:
    """Registers one estimator and one scenario-less model, then blows up."""

    @idbench.hookimpl
    def register_models(self, register: Callable[..., None]) -> None:
        register("half-model", lambda spec: None)

    @idbench.hookimpl
    def register_estimators(self, register: Callable[..., None]) -> None:
        register("half-registered", TinyEstimator)
        raise _Boom("kaboom in estimators")


def test_raising_plugin_recorded_and_builtins_survive(
    pm: pluggy.PluginManager, add_plugin: Callable[[object, str], object]
) -> None:
    add_plugin(RaisingPlugin(), "raiser")
    reg = idbench.build_registry(pm)
    assert "raiser" in reg.errors
    assert "kaboom in estimators" in reg.errors["raiser"]
    assert set(reg.errors) == {"raiser"}
    # Nothing from the failing plugin stays behind, whatever hook ran first.
    assert "half-registered" not in reg.estimators
    assert "half-model" not in reg.models
    assert all(e.plugin != "raiser" for e in reg.models.values())
    assert BUILTIN_MODELS <= set(reg.models)
    assert BUILTIN_ESTIMATORS <= set(reg.estimators)
    assert BUILTIN_SCENARIOS <= set(reg.scenarios)


def test_plugin_raising_in_scenarios_hook(
    pm: pluggy.PluginManager, add_plugin: Callable[[object, str], object]
) -> None:
    @idbench.hookimpl
    def register_scenarios(register: Callable[[Any], None]) -> None:
        raise ValueError("no scenarios today")

    add_plugin(types.SimpleNamespace(register_scenarios=register_scenarios), "sc")
    reg = idbench.build_registry(pm)
    assert "no scenarios today" in reg.errors["sc"]
    assert BUILTIN_SCENARIOS <= set(reg.scenarios)


# --- third-party entry points, in-process -----------------------------------


@pytest.fixture
def fake_entry_points(
    monkeypatch: pytest.MonkeyPatch,
) -> Callable[[str, types.ModuleType | None], None]:
    """Add a third-party entry point (no distribution) backed by a module.

    ``module=None`` makes the entry point's import fail.
    """
    real = importlib.metadata.entry_points
    extra: list[importlib.metadata.EntryPoint] = []

    def entry_points(**kw: Any) -> Any:
        eps = list(real(**kw))
        if kw.get("group") == "idbench":
            eps += extra
        return eps

    monkeypatch.setattr(importlib.metadata, "entry_points", entry_points)

    def add(name: str, module: types.ModuleType | None) -> None:
        modname = f"_idbench_test_plugin_{name.replace('-', '_')}"
        if module is not None:
            monkeypatch.setitem(sys.modules, modname, module)
        else:
            modname = "_idbench_test_plugin_that_does_not_exist"
        extra.append(importlib.metadata.EntryPoint(name, modname, "idbench"))

    return add


def _module(**attrs: Any) -> types.ModuleType:
    mod = types.ModuleType("fake")
    for k, v in attrs.items():
        setattr(mod, k, v)
    return mod


def test_autoload_flag_in_process(
    fake_entry_points: Callable[[str, types.ModuleType | None], None],
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    plug = _estimator_plugin("ep-est")
    fake_entry_points("ep-plug", _module(**vars(plug)))
    monkeypatch.delenv(AUTOLOAD_ENV, raising=False)
    reg = idbench.build_registry(idbench.get_plugin_manager())
    assert reg.estimators["ep-est"].plugin == "ep-plug"
    reg = idbench.build_registry(idbench.get_plugin_manager(autoload=False))
    assert "ep-est" not in reg.estimators
    monkeypatch.setenv(AUTOLOAD_ENV, "1")
    pm = idbench.get_plugin_manager()
    assert pm.get_plugin("ep-plug") is None
    assert {"fem", "filters"} <= {pm.get_name(p) for p in pm.get_plugins()}
    # an explicit argument beats the environment
    assert idbench.get_plugin_manager(autoload=True).get_plugin("ep-plug") is not None


def test_plugin_that_fails_to_import_is_recorded(
    fake_entry_points: Callable[[str, types.ModuleType | None], None],
) -> None:
    fake_entry_points("broken", None)
    pm = idbench.get_plugin_manager(autoload=True)
    reg = idbench.build_registry(pm)
    assert "failed to load" in reg.errors["broken"]
    assert BUILTIN_ESTIMATORS <= set(reg.estimators)
    assert BUILTIN_SCENARIOS <= set(reg.scenarios)


def test_third_party_cannot_take_a_builtin_plugin_name(
    fake_entry_points: Callable[[str, types.ModuleType | None], None],
) -> None:
    fake_entry_points("filters", _module(**vars(_estimator_plugin("impostor"))))
    reg = idbench.build_registry(idbench.get_plugin_manager(autoload=True))
    assert "impostor" not in reg.estimators
    assert BUILTIN_ESTIMATORS <= set(reg.estimators)


def test_plugin_with_misspelt_hook_does_not_take_down_the_rest(
    fake_entry_points: Callable[[str, types.ModuleType | None], None],
) -> None:
    @idbench.hookimpl
    def register_estimator(register: Any) -> None:  # typo: no such hook
        pass

    fake_entry_points("typo", _module(register_estimator=register_estimator))
    reg = idbench.build_registry(idbench.get_plugin_manager(autoload=True))
    assert "typo" in reg.errors
    assert BUILTIN_ESTIMATORS <= set(reg.estimators)


# --- hook specs and README ---------------------------------------------------


def _hookspec_names() -> set[str]:
    return {
        name
        for name, fn in inspect.getmembers(hookspecs, inspect.isfunction)
        if getattr(fn, "idbench_spec", None) is not None
    }


def test_hookspec_names() -> None:
    assert _hookspec_names() == {
        "register_models",
        "register_estimators",
        "register_scenarios",
        "register_commands",
        "register_observations",
        "register_versions",
    }


def test_the_docs_document_every_hookspec() -> None:
    page = ROOT / "docs" / "reference" / "hooks.md"
    text = page.read_text(encoding="utf-8")
    missing = sorted(n for n in _hookspec_names() if f"`{n}(register)`" not in text)
    assert not missing, f"{page} does not document hook spec(s): {missing}"


# --- import hygiene ----------------------------------------------------------


def test_import_idbench_loads_no_plugin() -> None:
    code = (
        "import sys, idbench, idbench.registry.registry, idbench.cli.commands\n"
        "plugins = ('idbench_fem', 'idbench_filters')\n"
        "bad = [m for m in plugins if m in sys.modules]\n"
        "assert not bad, bad\n"
    )
    run_fresh_python(code, timeout=60)


# --- a real third-party distribution -----------------------------------------

MYPLUG_PYPROJECT = """\
[build-system]
requires = ["setuptools>=61"]
build-backend = "setuptools.build_meta"

[project]
name = "idbench-myplug-testonly"
version = "0.0.7"

[project.entry-points.idbench]
myplug = "myplug"

[tool.setuptools]
py-modules = ["myplug"]
"""

MYPLUG_MODULE = '''\
"""A throwaway idbench plugin used by the test suite."""

from dataclasses import dataclass

import numpy as np

import idbench


@dataclass
class MyEst:
    gain: float = 0.5

    def start(self, model, prior):
        self._mean = np.asarray(prior.mean, dtype=float)

    def update(self, k, observation):
        return idbench.Estimate(
            self._mean, np.full_like(self._mean, np.nan), idbench.Cost()
        )


@idbench.hookimpl
def register_estimators(register):
    register("my-est", MyEst)
'''


def _plugins_json(env: dict[str, str]) -> list[dict[str, Any]]:
    proc = subprocess.run(
        [sys.executable, "-m", "idbench.cli", "plugins", "--json"],
        capture_output=True,
        text=True,
        env=env,
        timeout=120,
    )
    assert proc.returncode == 0, proc.stderr
    rows: list[dict[str, Any]] = json.loads(proc.stdout)
    return rows


# setuptools can build a wheel offline if it has bdist_wheel: built in from
# setuptools 70.1, else provided by the ``wheel`` package.
_OFFLINE_BUILD_CHECK = """
import setuptools
try:
    import setuptools.command.bdist_wheel
except ImportError:
    import wheel.bdist_wheel
"""

_NETWORK_ERRORS = (
    "No matching distribution",
    "Could not find a version",
    "NewConnectionError",
    "Temporary failure in name resolution",
    "Network is unreachable",
)


def _can_build_offline() -> bool:
    proc = subprocess.run(
        [sys.executable, "-c", _OFFLINE_BUILD_CHECK], capture_output=True
    )
    return proc.returncode == 0


@pytest.mark.slow
def test_third_party_plugin_via_entry_point(tmp_path: Path) -> None:
    pkg = tmp_path / "myplug-dist"
    pkg.mkdir()
    (pkg / "pyproject.toml").write_text(MYPLUG_PYPROJECT)
    (pkg / "myplug.py").write_text(textwrap.dedent(MYPLUG_MODULE))
    pip = [sys.executable, "-m", "pip"]
    quiet = {"capture_output": True, "text": True, "timeout": 180}
    env = {k: v for k, v in os.environ.items() if k != AUTOLOAD_ENV}
    try:
        install = [*pip, "install", "--no-deps", "--disable-pip-version-check"]
        if _can_build_offline():
            install += ["--no-build-isolation", "--no-index"]
        # else: pip fetches setuptools into an isolated build env (needs network)
        proc = subprocess.run(
            [*install, str(pkg)],
            **quiet,  # type: ignore[call-overload]
        )
        output = proc.stdout + proc.stderr
        if proc.returncode != 0 and any(e in output for e in _NETWORK_ERRORS):
            pytest.skip(f"cannot fetch a build backend offline:\n{output[-2000:]}")
        assert proc.returncode == 0, output

        rows = {r["name"]: r for r in _plugins_json(env)}
        assert "myplug" in rows, sorted(rows)
        assert rows["myplug"]["estimators"] == ["my-est"]
        assert rows["myplug"]["version"] == "0.0.7"
        assert rows["myplug"]["error"] == ""
        assert {"fem", "filters"} <= set(rows)
        assert "my-est" not in rows["filters"]["estimators"]

        # The autoload switch: third-party plugins off, built-ins stay.
        off = {r["name"]: r for r in _plugins_json({**env, AUTOLOAD_ENV: "1"})}
        assert "myplug" not in off
        assert all("my-est" not in r["estimators"] for r in off.values())
        assert {"fem", "filters"} <= set(off)
        assert set(off["filters"]["estimators"]) >= BUILTIN_ESTIMATORS
        assert set(off["fem"]["scenarios"]) >= BUILTIN_SCENARIOS

        # "0" means "not disabled".
        zero = {r["name"]: r for r in _plugins_json({**env, AUTOLOAD_ENV: "0"})}
        assert "myplug" in zero
    finally:
        subprocess.run(
            [*pip, "uninstall", "-y", "idbench-myplug-testonly"],
            **quiet,  # type: ignore[call-overload]
        )
    rows_after = {r["name"] for r in _plugins_json(env)}
    assert "myplug" not in rows_after


def test_the_registry_cache_lives_in_plugins_and_the_cli_uses_it() -> None:
    """One registry a process until reset; the command line reads that one."""
    from idbench.cli import commands, parser
    from idbench.registry import registry

    registry.reset_registry_cache()
    first = registry.cached_registry()
    assert registry.cached_registry() is first
    assert parser.registry is registry.cached_registry
    assert commands.registry is registry.cached_registry
    registry.reset_registry_cache()
    again = registry.cached_registry()
    assert again is not first and set(again.models) == set(first.models)


# --- idbench plugins lists observation models ------------------------------------

OBSERVES_DEPTH = """
from dataclasses import dataclass
import numpy as np
import idbench


@dataclass(frozen=True)
class Depth:
    requires: tuple = ("observe",)

    def sense(self, model, theta, k, state):
        return {"depth": np.asarray(model.observe(state))}

    def measure(self, clean, rng, noise):
        return [dict(c) for c in clean]

    def values(self, frame):
        return frame.data["depth"]

    def noise_std(self, frame, noise):
        return noise

    def predict(self, model, frame, theta, k, state):
        return np.asarray(model.observe(state))

    def identity(self):
        return ["depth"]


@idbench.hookimpl
def register_observations(register):
    register("depth-probe", Depth)
"""


def test_plugins_lists_the_core_and_the_plugins_observation_models(
    install: Any, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    from idbench.cli.commands import CORE, main

    install("depthplug", OBSERVES_DEPTH)
    assert main(["plugins", "--json"]) == 0
    rows = {r["name"]: r for r in json.loads(capsys.readouterr().out)}
    assert rows[CORE]["observations"] == ["cloud", "force", "markers"]
    assert rows["depthplug"]["observations"] == ["depth-probe"]
    assert rows["depthplug"]["error"] == ""
    assert rows["filters"]["observations"] == []
    monkeypatch.setenv("COLUMNS", "200")  # rich: one line a row
    assert main(["plugins"]) == 0  # the table has the column and the names
    table = capsys.readouterr().out
    assert "observations" in table
    assert "depth-probe" in table and "cloud, force, markers" in table


def test_an_observation_model_is_checked_against_the_protocol(
    pm: pluggy.PluginManager, add_plugin: Callable[[object, str], object]
) -> None:
    from idbench.observe.kinds import Markers

    @dataclass(frozen=True)
    class NoPrediction:
        requires: tuple[str, ...] = ("observe",)

        def sense(self, model: Any, theta: Any, k: int, state: Any) -> Any:
            return {}

    class Plugin:
        @idbench.hookimpl
        def register_observations(self, register: Any) -> None:
            register("half", NoPrediction)

    add_plugin(Plugin(), "half-plug")
    reg = idbench.build_registry(pm)
    message = reg.errors["half-plug"]
    assert message == (
        "plugin 'half-plug': observation model 'half' is no "
        "idbench.ObservationModel: it lacks measure, values, noise_std, predict, "
        "identity"
    )
    assert "half" not in reg.observations
    assert isinstance(Markers(), idbench.ObservationModel)
    assert "ObservationModel" in idbench.__all__
