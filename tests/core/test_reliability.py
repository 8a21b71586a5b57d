"""Reliability: bad mesh files, numerical faults and crashing plugins.

Every fault here is provoked in a real comparison (truth 12x3x3, model 4x1x1,
5 load steps) or a real mesh read, and must end as a clean one-line error
(bad input) or a row with the right status and a message naming the culprit
and the step (faults inside a run), while the other runs of the sweep are ok.
"""

from __future__ import annotations

import importlib.metadata
import json
import math
import subprocess
import sys
import time
import types
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import meshio
import numpy as np
import pandas as pd
import pytest
from support.helpers import MODEL, STEPS, TRUTH, registry_with, tiny

import idbench
from idbench.cli.commands import main
from idbench.core.capabilities import by_default
from idbench.plan.config import ConfigError
from idbench.registry.registry import AUTOLOAD_ENV
from idbench.run.compare import compare
from idbench_fem.bodies import box as meshes

BUILTIN_ESTIMATORS = {"ro-ukf", "ukf", "enkf", "etkf", "rls", "lms", "batch-ls",
                      "map-laplace", "local-enkf", "local-etkf"}  # fmt: skip


def by_estimator(runs: pd.DataFrame) -> pd.DataFrame:
    assert runs["estimator"].is_unique
    return runs.set_index("estimator")


def diverged_at(
    runs: pd.DataFrame, traces: pd.DataFrame, estimator: str, step: int, why: str
) -> pd.DataFrame:
    """Assert ``estimator``'s run diverged at ``step`` for ``why``; its traces.

    The run is ``diverged`` with ``failed_step`` and an error "step N: ...why...",
    and its traces hold the steps before, not the failed one.
    """
    row = by_estimator(runs).loc[estimator]
    assert row["status"] == "diverged", row["error"]
    assert row["failed_step"] == step
    assert row["error"].startswith(f"step {step}: ") and why in row["error"]
    steps = traces.loc[traces["run_id"] == row["run_id"]]
    assert sorted(steps["step"]) == list(range(1, step))
    return steps


# --- bad mesh files ------------------------------------------------------------

GOOD = meshes.parse("4x2x2")  # has interior nodes (y = z = W/2)


def _write(path: Path, points: np.ndarray, cells: list[tuple[str, Any]]) -> None:
    meshio.write(path, meshio.Mesh(points, cells))


def _garbage(path: Path) -> Path:
    path = path.with_suffix(".msh")
    path.write_text("not a mesh\n")
    return path


def _empty(path: Path) -> Path:
    path.write_bytes(b"")
    return path


def _truncated(path: Path) -> Path:
    _write(path, GOOD.points, [("tetra", GOOD.tets)])
    path.write_bytes(path.read_bytes()[:300])
    return path


def _unknown_format(path: Path) -> Path:
    path = path.with_suffix(".beam")
    path.write_text("0 0 0\n")
    return path


def _hexahedra(path: Path) -> Path:
    from skfem import MeshHex

    h = MeshHex.init_tensor(*(np.linspace(0, s, 3) for s in (0.2, 0.03, 0.03)))
    _write(path, h.p.T, [("hexahedron", h.t.T)])
    return path


def _triangles(path: Path) -> Path:
    _write(path, GOOD.points, [("triangle", GOOD.tets[:, :3])])
    return path


def _quadratic(path: Path) -> Path:
    pts = np.vstack([GOOD.points, np.zeros((6, 3))])
    _write(path, pts, [("tetra10", np.arange(10)[None, :])])
    return path


def _tets_and_hexes(path: Path) -> Path:
    _write(
        path, GOOD.points, [("tetra", GOOD.tets), ("hexahedron", np.arange(8)[None])]
    )
    return path


def _interior_node() -> int:
    p = GOOD.points
    on = np.isclose(p[:, 0], 0.05) & np.isclose(p[:, 1], 0.015)
    return int(np.flatnonzero(on & np.isclose(p[:, 2], 0.015))[0])


def _inverted(path: Path) -> Path:
    # push an interior node past its neighbours along x: its elements fold over
    pts = GOOD.points.copy()
    pts[_interior_node(), 0] += 0.06
    _write(path, pts, [("tetra", GOOD.tets)])
    return path


def _degenerate(path: Path) -> Path:
    flat = np.flatnonzero(GOOD.points[:, 0] == 0)[:4]  # on the face x = 0: flat
    _write(path, GOOD.points, [("tetra", np.vstack([GOOD.tets, flat]))])
    return path


def _flat_2d(path: Path) -> Path:
    _write(path, GOOD.points[:, :2], [("tetra", GOOD.tets)])  # meshio adds z = 0
    return path


def _no_clamped_face(path: Path) -> Path:
    c, s = math.cos(math.pi / 4), math.sin(math.pi / 4)
    turn = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    _write(path, GOOD.points @ turn.T, [("tetra", GOOD.tets)])  # min x: an edge
    return path


def _no_loaded_face(path: Path) -> Path:
    pts = GOOD.points.copy()
    pts[:, 0] *= 1 + 0.5 * pts[:, 1] / 0.03  # far end slanted, x = 0 stays flat
    _write(path, pts, [("tetra", GOOD.tets)])
    return path


def _bad_node_number(path: Path) -> Path:
    _write(path, GOOD.points, [("tetra", np.vstack([GOOD.tets, [0, 1, 2, 999]]))])
    return path


def _nan_coordinate(path: Path) -> Path:
    pts = GOOD.points.copy()
    pts[_interior_node()] = np.nan
    _write(path, pts, [("tetra", GOOD.tets)])
    return path


BAD_MESHES: dict[str, tuple[Callable[[Path], Path], str]] = {
    "garbage": (_garbage, "meshio cannot read it"),
    "empty": (_empty, "meshio cannot read it"),
    "truncated": (_truncated, "meshio cannot read it"),
    "unknown-format": (_unknown_format, "meshio cannot read it"),
    "hexahedra": (_hexahedra, "no 'tetra' cells (found ['hexahedron'])"),
    "triangles": (_triangles, "no 'tetra' cells (found ['triangle'])"),
    "quadratic-tets": (_quadratic, "no 'tetra' cells (found ['tetra10'])"),
    "tets-and-hexes": (_tets_and_hexes, "mixes tetrahedra with ['hexahedron']"),
    "inverted": (_inverted, "inverted tetrahedra"),
    "degenerate": (_degenerate, "1 degenerate (zero-volume) tetrahedra"),
    "flat-2d": (_flat_2d, "degenerate (zero-volume) tetrahedra"),
    "no-clamped-face": (_no_clamped_face, "no clamped face x = min x"),
    "no-loaded-face": (_no_loaded_face, "no loaded face x = max x"),
    "bad-node-number": (_bad_node_number, "refers to node 999"),
    "nan-coordinate": (_nan_coordinate, "non-finite node coordinates"),
}


@pytest.fixture(params=sorted(BAD_MESHES))
def bad_mesh(request, tmp_path) -> tuple[Path, str]:
    make, problem = BAD_MESHES[request.param]
    return make(tmp_path / f"bad-{request.param}.vtu"), problem


def test_model_constructor_rejects_bad_mesh_file(bad_mesh):
    path, problem = bad_mesh
    reg = idbench.build_registry(idbench.get_plugin_manager(autoload=False))
    spec = idbench.ModelSpec(mesh=str(path), scenario=reg.scenario("bend-y"))
    with pytest.raises(ValueError) as info:
        reg.model("svk-beam")(spec)
    message = str(info.value)
    assert str(path) in message and problem in message, message
    assert "\n" not in message


def test_cli_rejects_bad_mesh_file(bad_mesh, capsys, tmp_path):
    path, problem = bad_mesh
    out = tmp_path / "out"
    argv = ["compare", "--truth-mesh", TRUTH, "--meshes", str(path), "--steps",
            str(STEPS), "--seeds", "1", "--estimators", "rls",
            "--out", str(out)]  # fmt: skip
    for extra in (["--dry-run"], ["-q"]):
        assert main([*argv, *extra]) == 2
        captured = capsys.readouterr()
        assert "Traceback" not in captured.err + captured.out
        lines = captured.err.strip().splitlines()
        assert len(lines) == 1 and lines[0].startswith("idbench: error: "), lines
        assert str(path) in lines[0] and problem in lines[0], lines[0]
        assert not out.exists()  # rejected before anything is written


@pytest.mark.parametrize("case", ["inverted", "no-clamped-face"])
def test_bad_mesh_file_in_a_real_process(case, tmp_path):
    path = BAD_MESHES[case][0](tmp_path / f"{case}.vtu")
    proc = subprocess.run(
        [sys.executable, "-m", "idbench.cli", "compare", "--meshes", str(path),
         "--truth-mesh", TRUTH, "--steps", str(STEPS), "--seeds", "1",
         "--estimators", "rls", "--out", str(tmp_path / "out")],
        capture_output=True, text=True, timeout=120,
    )  # fmt: skip
    assert proc.returncode == 2
    assert "Traceback" not in proc.stderr
    (line,) = proc.stderr.strip().splitlines()
    assert str(path) in line and BAD_MESHES[case][1] in line


def test_good_mesh_files_are_accepted_and_run(tmp_path):
    """Negative controls: reversed vertex order is re-oriented, not "inverted";
    an irregular (jittered) mesh passes the fold check and runs."""
    reversed_ = tmp_path / "reversed.vtu"
    _write(reversed_, GOOD.points, [("tetra", GOOD.tets[:, [0, 1, 3, 2]])])
    back = meshes.parse(str(reversed_))
    np.testing.assert_array_equal(back.tets, GOOD.tets)

    rng = np.random.default_rng(3)
    pts = GOOD.points.copy()
    inside = np.all((pts > GOOD.lower + 1e-9) & (pts < GOOD.upper - 1e-9), axis=1)
    pts[inside] += rng.uniform(-0.004, 0.004, size=(int(inside.sum()), 3))
    jittered = tmp_path / "jittered.vtu"
    _write(jittered, pts, [("tetra", GOOD.tets)])
    runs, _ = compare(tiny(meshes=(str(jittered),)), tmp_path / "out")
    assert list(runs["status"]) == ["ok"]
    assert runs["model_nodes"].iloc[0] == len(GOOD.points)


# --- plugin estimators that misbehave ------------------------------------------


@dataclass
class FixedE:
    """Steps the real model with a fixed modulus: a soft one breaks Newton."""

    E: float = 5000.0

    def start(self, model: Any, prior: idbench.Prior) -> None:
        self.model, self.cost0 = model, model.cost()
        self.state = model.reset()

    def update(self, k: int, observation: Any) -> idbench.Estimate:
        theta = np.full(self.model.parameters.p, self.E)
        self.state = self.model.step(theta, k, self.state)  # ModelFailure escapes
        return idbench.Estimate(
            theta, np.full_like(theta, np.nan), self.model.cost() - self.cost0,
            state=self.state,
        )  # fmt: skip


@dataclass
class BadValueAt:
    """Keeps the prior mean, then reports ``value`` from step ``at`` on."""

    at: int = 4
    value: float = math.nan

    def start(self, model: Any, prior: idbench.Prior) -> None:
        self.mean = np.asarray(prior.mean, dtype=float)

    def update(self, k: int, observation: Any) -> idbench.Estimate:
        mean = np.full_like(self.mean, self.value) if k >= self.at else self.mean
        return idbench.Estimate(mean, np.full_like(mean, np.nan), idbench.Cost())


class _PluginCrash(RuntimeError):
    pass


@dataclass
class CrashAtStart(BadValueAt):
    def start(self, model: Any, prior: idbench.Prior) -> None:
        raise _PluginCrash("cannot start today")


@dataclass
class CrashInUpdate(BadValueAt):
    at: int = 3

    def update(self, k: int, observation: Any) -> idbench.Estimate:
        if k == self.at:
            raise _PluginCrash(f"lost my marbles at step {k}")
        return super().update(k, observation)


@dataclass
class CrashInConstructor(BadValueAt):
    def __post_init__(self) -> None:
        raise _PluginCrash("refuse to exist")


class FaultyPlugin:
    """A third-party plugin whose estimators fail in every way."""

    @idbench.hookimpl
    def register_estimators(self, register: Callable[[str, type], None]) -> None:
        register("fixed-e", FixedE)
        register("nan-at", BadValueAt)
        register("crash-start", CrashAtStart)
        register("crash-update", CrashInUpdate)
        register("crash-init", CrashInConstructor)


@pytest.fixture
def registry() -> idbench.Registry:
    """Built-ins plus the faulty plugin, registered on a fresh manager."""
    reg = registry_with({"faulty-plug": FaultyPlugin()})
    assert reg.errors == {}
    return reg


# --- numerical faults ----------------------------------------------------------


def test_newton_failure_is_a_diverged_run_at_its_step(registry, tmp_path):
    # E = 40 Pa: the 4x1x1 beam inverts an element in load step 3, a genuine
    # failure of the SVK Newton solve (it converges at steps 1 and 2).
    cfg = tiny(
        estimators=("rls", "fixed-e", "batch-ls"),
        estimator_settings={"fixed-e": {"E": 40.0}},
    )
    runs, traces = compare(cfg, tmp_path / "out", registry=registry)
    diverged_at(runs, traces, "fixed-e", 3, "inverted element")
    by = by_estimator(runs)
    for ok in ("rls", "batch-ls"):
        assert by.loc[ok, "status"] == "ok" and by.loc[ok, "error"] == ""
        assert np.isfinite(by.loc[ok, "E_final"])


def test_sigma_point_in_the_tail_diverges_after_substep_retry(tmp_path):
    # An absurd prior std (1e9 Pa on 2500 Pa) puts sigma points at a few Pa:
    # the filters retry the solve in 4 load sub-steps, then report divergence
    # at that step. The gradient filter on the same data is unaffected.
    cfg = tiny(estimators=("ro-ukf", "ukf", "rls"), prior=(2500.0, 1e9))
    runs, _ = compare(cfg, tmp_path / "out")
    by = by_estimator(runs)
    for name in ("ro-ukf", "ukf"):
        row = by.loc[name]
        assert row["status"] == "diverged", row["error"]
        step = int(row["failed_step"])
        assert 1 <= step <= STEPS
        assert row["error"].startswith(f"step {step}: forward solve failed")
        assert "retry with 4 sub-steps failed too" in row["error"]
        assert "at the parameter theta=" in row["error"]  # not the updated state
        assert np.isnan(row["E_final"])
    assert by.loc["rls", "status"] == "ok"
    assert np.isfinite(by.loc["rls", "E_final"])


@pytest.mark.parametrize("value", [math.nan, math.inf, -math.inf])
def test_non_finite_estimate_is_caught_at_its_step(registry, tmp_path, value):
    cfg = tiny(
        estimators=("nan-at", "rls"),
        estimator_settings={"nan-at": {"at": 4, "value": value}},
    )
    runs, traces = compare(cfg, tmp_path / "out", registry=registry)
    steps = diverged_at(runs, traces, "nan-at", 4, "non-finite")
    assert np.isfinite(steps["E"]).all()  # nothing non-finite was recorded
    assert by_estimator(runs).loc["rls", "status"] == "ok"


# --- crashing plugins ----------------------------------------------------------

CRASHES = ("crash-start", "crash-update", "crash-init")


def check_crash_rows(runs: pd.DataFrame, traces: pd.DataFrame) -> None:
    by = by_estimator(runs)
    assert len(runs) == 2 + len(CRASHES)
    for name in CRASHES:
        row = by.loc[name]
        assert row["status"] == "failed"
        assert f"estimator {name!r} (plugin 'faulty-plug')" in row["error"]
        assert "_PluginCrash" in row["error"]
        assert "_PluginCrash" in row["traceback"]
    start = by.loc["crash-start"]
    assert "raised in start(): " in start["error"]
    assert "cannot start today" in start["error"]
    assert np.isnan(start["failed_step"])
    assert "raised in its constructor" in by.loc["crash-init", "error"]
    update = by.loc["crash-update"]
    assert "raised in update() at step 3: " in update["error"]
    assert "lost my marbles at step 3" in update["error"]
    assert update["failed_step"] == 3
    kept = traces.loc[traces["run_id"] == update["run_id"], "step"]
    assert sorted(kept) == [1, 2]  # the steps before the crash are kept
    for name in ("rls", "batch-ls"):
        assert by.loc[name, "status"] == "ok" and by.loc[name, "error"] == ""
        assert np.isfinite(by.loc[name, "E_final"])


def test_crashing_plugin_estimators_are_named_and_isolated(registry, tmp_path):
    cfg = tiny(estimators=("rls", *CRASHES, "batch-ls"))
    runs, traces = compare(cfg, tmp_path / "out", registry=registry)
    check_crash_rows(runs, traces)
    parts = tmp_path / "out" / "parts"
    stamps = {r: (parts / f"{r}.runs.parquet").stat().st_mtime_ns for r in runs.run_id}
    again, _ = compare(cfg, tmp_path / "out", registry=registry)
    assert list(again["status"]) == list(runs["status"])  # they crash again
    for run_id, status in zip(runs["run_id"], runs["status"], strict=True):
        redone = (parts / f"{run_id}.runs.parquet").stat().st_mtime_ns != stamps[run_id]
        assert redone == (status == "failed")  # failed runs retried, results kept


@pytest.fixture
def installed(monkeypatch) -> Callable[[str, types.ModuleType | None], None]:
    """Install a third-party entry point backed by a module (None: import fails)."""
    real = importlib.metadata.entry_points
    extra: list[importlib.metadata.EntryPoint] = []

    def entry_points(**kw: Any) -> Any:
        eps = list(real(**kw))
        return eps + extra if kw.get("group") == "idbench" else eps

    monkeypatch.setattr(importlib.metadata, "entry_points", entry_points)
    monkeypatch.delenv(AUTOLOAD_ENV, raising=False)

    def add(name: str, module: types.ModuleType | None) -> None:
        modname = "_idbench_reliability_missing_module"
        if module is not None:
            modname = f"_idbench_reliability_{name.replace('-', '_')}"
            monkeypatch.setitem(sys.modules, modname, module)
        extra.append(importlib.metadata.EntryPoint(name, modname, "idbench"))

    return add


def _module_of(plugin: object) -> types.ModuleType:
    mod = types.ModuleType("fake")
    mod.register_estimators = plugin.register_estimators  # type: ignore[attr-defined]
    return mod


def test_cli_sweep_with_crashing_plugin_completes_and_exits_0(
    installed, tmp_path, capsys
):
    """``idbench compare`` exits 0 once the sweep completes, whatever the run
    statuses: failures are rows (status, error, traceback), not an exit code."""
    installed("faulty-plug", _module_of(FaultyPlugin()))
    out = tmp_path / "out"
    names = ",".join(("rls", *CRASHES, "batch-ls"))
    rc = main(["compare", "--truth-mesh", TRUTH, "--meshes", MODEL, "--steps",
               str(STEPS), "--seeds", "1", "--estimators", names,
               "--out", str(out), "-q"])  # fmt: skip
    captured = capsys.readouterr()
    assert rc == 0
    assert "Traceback" not in captured.err + captured.out
    check_crash_rows(
        pd.read_parquet(out / "runs.parquet"), pd.read_parquet(out / "traces.parquet")
    )


class RaisesWhileRegistering:
    @idbench.hookimpl
    def register_estimators(self, register: Callable[[str, type], None]) -> None:
        register("half-way", BadValueAt)
        raise _PluginCrash("registration exploded")


def test_plugins_lists_builtins_when_third_party_plugins_fail(installed, capsys):
    installed("explodes", _module_of(RaisesWhileRegistering()))
    installed("missing", None)
    assert main(["plugins", "--json"]) == 0
    rows = {r["name"]: r for r in json.loads(capsys.readouterr().out)}
    assert set(rows["filters"]["estimators"]) == BUILTIN_ESTIMATORS
    assert rows["fem"]["models"] == ["solid", "svk-beam"]
    assert rows["filters"]["error"] == rows["fem"]["error"] == ""
    assert "registration exploded" in rows["explodes"]["error"]
    assert rows["explodes"]["estimators"] == []  # nothing half-registered
    assert "failed to load" in rows["missing"]["error"]
    # ... and a sweep of the built-ins still validates and plans
    argv = ["compare", "--dry-run", "--truth-mesh", TRUTH, "--meshes", MODEL,
            "--steps", str(STEPS), "--seeds", "1"]  # fmt: skip
    assert main(argv) == 0
    registered = idbench.build_registry().estimators.values()
    n = sum(by_default(e.obj) for e in registered)  # those unnamed, one mesh, seed
    assert capsys.readouterr().out.startswith(f"{n} runs;")


def test_plugin_constructor_crash_on_given_settings_is_one_clean_line(
    installed, tmp_path, capsys
):
    installed("faulty-plug", _module_of(FaultyPlugin()))
    cfg = tmp_path / "cfg.toml"
    cfg.write_text("[estimators.crash-init]\nat = 2\n")
    rc = main(["compare", "--truth-mesh", TRUTH, "--meshes", MODEL, "--steps",
               str(STEPS), "--seeds", "1", "--estimators", "rls,crash-init",
               "--config", str(cfg), "--out", str(tmp_path / "out")])  # fmt: skip
    captured = capsys.readouterr()
    assert rc == 2
    assert "Traceback" not in captured.err + captured.out
    (line,) = captured.err.strip().splitlines()
    assert "'crash-init' (plugin 'faulty-plug')" in line
    assert "refuse to exist" in line
    assert not (tmp_path / "out").exists()


class BrokenModelPlugin:
    """A model plugin whose factory has a bug (not a bad-input error)."""

    @idbench.hookimpl
    def register_models(self, register: Callable[[str, Any], None]) -> None:
        def factory(spec: idbench.ModelSpec) -> Any:
            raise TypeError("unsupported operand type(s)")

        register("broken-model", factory)


def test_a_model_plugin_bug_is_one_clean_line_naming_the_plugin(tmp_path):
    reg = registry_with({"broken-plug": BrokenModelPlugin()})
    with pytest.raises(ConfigError) as info:
        cfg = tiny(model="broken-model", scenarios=("bend-y",), prior=(1e3, 1e3))
        compare(cfg, tmp_path, registry=reg)
    text = str(info.value)
    assert "'broken-model' (plugin 'broken-plug') raised TypeError" in text
    assert "\n" not in text


@dataclass
class HangsAt(BadValueAt):
    """Hangs in update() at step ``at``, swallowing ordinary exceptions."""

    def update(self, k: int, observation: Any) -> idbench.Estimate:
        while k >= self.at:
            try:
                time.sleep(0.05)
            except Exception:  # a careless plugin: the timeout must still win
                pass
        return super().update(k, observation)


class HangingPlugin:
    @idbench.hookimpl
    def register_estimators(self, register: Callable[[str, type], None]) -> None:
        register("hangs", HangsAt)


def test_a_hanging_estimator_is_stopped_by_the_timeout_mid_step(tmp_path):
    reg = registry_with({"hang-plug": HangingPlugin()})
    cfg = tiny(estimators=("hangs", "rls"), timeout=1.5)
    start = time.perf_counter()
    runs, _ = compare(cfg, tmp_path, registry=reg)
    assert time.perf_counter() - start < 60
    rows = by_estimator(runs)
    assert rows.loc["hangs", "status"] == "failed"
    assert "exceeded --timeout 1.5 s" in rows.loc["hangs", "error"]
    assert rows.loc["hangs", "wall_s"] < 5
    assert rows.loc["rls", "status"] == "ok"


@dataclass
class Flaky(BadValueAt):
    """Crashes at start while ``Flaky.broken`` (e.g. a licence server is down)."""

    broken = True
    value: float = 4000.0

    def start(self, model: Any, prior: idbench.Prior) -> None:
        if Flaky.broken:
            raise _PluginCrash("server unavailable")
        super().start(model, prior)


class FlakyPlugin:
    @idbench.hookimpl
    def register_estimators(self, register: Callable[[str, type], None]) -> None:
        register("flaky", Flaky)


def test_resume_retries_failed_runs_and_keeps_the_others(tmp_path, monkeypatch):
    reg = registry_with({"flaky-plug": FlakyPlugin()})
    cfg = tiny(estimators=("flaky", "rls"))
    monkeypatch.setattr(Flaky, "broken", True)
    first, _ = compare(cfg, tmp_path, registry=reg)
    assert by_estimator(first).loc["flaky", "status"] == "failed"
    rls_id = by_estimator(first).loc["rls", "run_id"]
    rls_part = tmp_path / "parts" / f"{rls_id}.runs.parquet"
    stamp = rls_part.stat().st_mtime_ns
    monkeypatch.setattr(Flaky, "broken", False)
    second, _ = compare(cfg, tmp_path, registry=reg)
    rows = by_estimator(second)
    assert rows.loc["flaky", "status"] == "ok"
    assert rows.loc["flaky", "E_final"] == 4000.0
    assert rls_part.stat().st_mtime_ns == stamp  # a finished run is not redone
