"""The comparison harness, the result store and the ``idbench compare`` CLI.

Everything runs on tiny meshes (truth 20x3x3, models 6x2x2 and 10x2x2) with a
few load steps; the truth cache lives in a per-session temporary folder.
"""

from __future__ import annotations

import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
import pytest

import idbench
import idbench.run.compare
from idbench.cli.commands import main
from idbench.core.capabilities import by_default
from idbench.plan.config import CompareConfig, ConfigError
from idbench.run.compare import compare
from idbench.run.compare import runs_of as expand
from idbench.store.results import ResultsError

TRUTH = "20x3x3"
COARSE, FINE = "6x2x2", "10x2x2"
STEPS = 8

RUN_COLUMNS = [
    "run_id", "scenario", "estimator", "model_nodes", "truth_nodes", "seed",
    "obs_every", "obs_points", "noise", "E_true", "E_final", "E_std_final", "E_ref",
    "settling_step", "shape_error_final", "shape_error_direct", "transfer_error",
    "n_solves", "wall_s", "status", "error",
]  # fmt: skip
TRACE_COLUMNS = [
    "run_id", "step", "load", "observed", "E", "E_std", "shape_error", "n_solves",
    "wall_s", "newton_its", "tip_x", "tip_y", "tip_z", "shape_error_mean",
]  # fmt: skip
WALL = ["wall_s", "wall_s_step"]
CLI_ARGV = [
    "compare", "--truth-mesh", TRUTH, "--meshes", f"{COARSE},{FINE}",
    "--steps", str(STEPS), "--seeds", "1", "--estimators", "ro-ukf,rls,batch-ls",
]  # fmt: skip


@pytest.fixture(scope="session")
def cache_dir(tmp_path_factory):
    return tmp_path_factory.mktemp("idbench-cache")


@pytest.fixture(autouse=True)
def _cache_env(cache_dir, monkeypatch):
    monkeypatch.setenv("IDBENCH_CACHE_DIR", str(cache_dir))


def tiny(**overrides: Any) -> CompareConfig:
    base: dict[str, Any] = {
        "truth_mesh": TRUTH,
        "meshes": (COARSE,),
        "estimators": ("rls", "batch-ls"),
        "steps": 6,
        "seeds": 1,
    }
    return CompareConfig(**{**base, **overrides})


def tiny_args(*extra: str) -> list[str]:
    return [
        "compare", "--truth-mesh", TRUTH, "--meshes", COARSE, "--steps", "6",
        "--seeds", "1", "--estimators", "rls", *extra,
    ]  # fmt: skip


def drop_wall(df: pd.DataFrame) -> pd.DataFrame:
    return df.drop(columns=[c for c in WALL if c in df.columns])


# --- CLI end to end -----------------------------------------------------------


@pytest.fixture(scope="module")
def cli_run(tmp_path_factory, cache_dir):
    out = tmp_path_factory.mktemp("cli") / "out"
    with pytest.MonkeyPatch.context() as mp:
        mp.setenv("IDBENCH_CACHE_DIR", str(cache_dir))
        rc = main([*CLI_ARGV, "--out", str(out)])
    assert rc == 0
    runs = pd.read_parquet(out / "runs.parquet")
    traces = pd.read_parquet(out / "traces.parquet")
    return out, runs, traces


def test_cli_writes_documented_columns(cli_run):
    out, runs, traces = cli_run
    assert (out / "manifest.json").is_file()
    assert set(RUN_COLUMNS) <= set(runs.columns), set(RUN_COLUMNS) - set(runs.columns)
    assert set(TRACE_COLUMNS) <= set(traces.columns), set(TRACE_COLUMNS) - set(
        traces.columns
    )
    assert len(runs) == 6
    assert runs["run_id"].is_unique
    assert list(runs["estimator"]) == ["ro-ukf", "rls", "batch-ls"] * 2
    assert list(runs["mesh"]) == [COARSE] * 3 + [FINE] * 3
    assert (runs["status"] == "ok").all(), runs[["estimator", "mesh", "error"]]
    assert (runs["error"] == "").all()
    assert (runs["scenario"] == "bend-y").all()
    assert (runs["seed"] == 0).all()
    assert (runs["E_true"] == 5000.0).all()
    assert runs["truth_nodes"].nunique() == 1
    nodes = runs.groupby("mesh")["model_nodes"].first()
    assert nodes[COARSE] < nodes[FINE] < runs["truth_nodes"].iloc[0]


def test_cli_one_trace_row_per_step_per_run(cli_run):
    _, runs, traces = cli_run
    assert len(traces) == STEPS * len(runs)
    # traces follow the runs table's order, steps ascending within a run
    assert list(traces["run_id"].unique()) == list(runs["run_id"])
    assert traces.groupby("run_id", sort=False)["step"].is_monotonic_increasing.all()
    assert set(traces["run_id"]) == set(runs["run_id"])
    for _, t in traces.groupby("run_id"):
        assert sorted(t["step"]) == list(range(1, STEPS + 1))
        t = t.sort_values("step")
        assert np.allclose(t["load"], np.arange(1, STEPS + 1) / STEPS)
        # default obs_every=2: even steps observed
        assert list(t["observed"]) == [k % 2 == 0 for k in range(1, STEPS + 1)]
    # the final trace row is what the run row reports
    for _, r in runs.iterrows():
        last = traces[(traces["run_id"] == r["run_id"]) & (traces["step"] == STEPS)]
        assert last["E"].iloc[0] == pytest.approx(r["E_final"])
        assert last["shape_error"].iloc[0] == pytest.approx(r["shape_error_final"])
        per_run = traces[traces["run_id"] == r["run_id"]]
        assert per_run["n_solves"].sum() == r["n_solves"]


def test_cli_physics(cli_run):
    _, runs, _ = cli_run
    by = runs.set_index(["estimator", "mesh"])
    # coarse meshes are stiffer: the identified E is below the truth's
    assert by.loc[("ro-ukf", COARSE), "E_final"] < 5000.0
    assert by.loc[("ro-ukf", COARSE), "E_final"] < by.loc[("ro-ukf", FINE), "E_final"]
    # identification beats running the coarse mesh with the true E
    assert (runs["shape_error_final"] < runs["shape_error_direct"]).all()
    # ro-ukf: two forward solves per step
    assert (runs.loc[runs["estimator"] == "ro-ukf", "n_solves"] == 2 * STEPS).all()
    # E_ref is the batch-ls fit on the run's data, the same for all estimators
    for mesh in (COARSE, FINE):
        ref = by.loc[("batch-ls", mesh), "E_final"]
        sub = runs[runs["mesh"] == mesh]
        assert np.allclose(sub["E_ref"], ref, rtol=1e-6)
        assert by.loc[("ro-ukf", mesh), "E_final"] == pytest.approx(ref, rel=0.05)
    assert runs["settling_step"].between(1, STEPS).all()
    assert (runs["E_std_final"].dropna() >= 0).all()
    assert runs["transfer_error"].notna().all()


def test_cli_prints_summary(cli_run, capsys, tmp_path):
    # rerunning into the finished DIR executes nothing and prints the summary
    out, runs, _ = cli_run
    assert main([*CLI_ARGV, "--out", str(out)]) == 0
    text = capsys.readouterr().out
    assert "runs.parquet" in text and "traces.parquet" in text
    again = pd.read_parquet(out / "runs.parquet")
    pd.testing.assert_frame_equal(again, runs)


def test_quick_dry_run_prints_run_count(capsys):
    assert main(["compare", "--quick", "--dry-run"]) == 0
    out = capsys.readouterr().out
    registered = idbench.build_registry().estimators.values()
    # quick: 2 meshes, 1 seed; the estimators a comparison runs unnamed
    n = 2 * sum(by_default(e.obj) for e in registered)
    assert out.startswith(f"{n} runs;"), out
    assert "forward solves" in out


def test_dry_run_runs_nothing(capsys, tmp_path):
    out = tmp_path / "out"
    assert main([*tiny_args("--dry-run", "--out", str(out))]) == 0
    assert capsys.readouterr().out.startswith("1 runs;")
    assert not out.exists()


# --- resume ---------------------------------------------------------------------


class Stop:
    """A progress callback that interrupts after ``after`` finished runs."""

    def __init__(self, after: int) -> None:
        self.after = after
        self.seen: list[str] = []

    def __call__(self, done: int, total: int, row: dict[str, Any]) -> None:
        self.seen.append(row["run_id"])
        if done >= self.after:
            raise KeyboardInterrupt


def test_interrupted_sweep_resumes(tmp_path, counted):
    cfg = tiny(meshes=(COARSE, FINE))  # 2 meshes x 2 estimators = 4 runs
    ids = [r.run_id for r in expand(cfg)]
    assert len(ids) == 4
    out = tmp_path / "resumed"

    stop = Stop(after=2)
    with pytest.raises(KeyboardInterrupt):
        compare(cfg, out, progress=stop)
    first = list(counted)  # the reference estimator's runs go first
    assert stop.seen == first and len(first) == 2 and set(first) <= set(ids)
    parts = out / "parts"
    assert sorted(p.name for p in parts.glob("*.runs.parquet")) == sorted(
        f"{i}.runs.parquet" for i in first
    )
    assert sorted(p.name for p in parts.glob("*.traces.parquet")) == sorted(
        f"{i}.traces.parquet" for i in first
    )
    assert not list(parts.glob(".tmp-*"))

    counted.clear()
    calls: list[tuple[int, int]] = []
    runs, traces = compare(cfg, out, progress=lambda d, t, r: calls.append((d, t)))
    assert sorted(counted) == sorted(set(ids) - set(first))
    assert calls == [(3, 4), (4, 4)]
    assert list(runs["run_id"]) == ids
    assert (runs["status"] == "ok").all()

    counted.clear()
    fresh_runs, fresh_traces = compare(cfg, tmp_path / "fresh")
    assert sorted(counted) == sorted(ids)
    pd.testing.assert_frame_equal(drop_wall(runs), drop_wall(fresh_runs))
    pd.testing.assert_frame_equal(drop_wall(traces), drop_wall(fresh_traces))
    on_disk = pd.read_parquet(out / "runs.parquet")
    pd.testing.assert_frame_equal(on_disk, runs)

    # a third call finds everything done
    counted.clear()
    compare(cfg, out)
    assert counted == []


def test_reopening_dir_with_other_settings_raises(tmp_path, counted):
    out = tmp_path / "out"
    compare(tiny(estimators=("rls",)), out)
    with pytest.raises(ResultsError, match="other settings"):
        compare(tiny(estimators=("rls",), steps=7), out)
    with pytest.raises(ResultsError):
        compare(tiny(estimators=("rls",), noise=(2e-4,)), out)
    assert len(counted) == 1
    # the same settings still open it
    compare(tiny(estimators=("rls",)), out)
    assert len(counted) == 1


# --- determinism ------------------------------------------------------------------


def test_same_config_gives_identical_estimates(tmp_path):
    cfg = tiny(estimators=("ro-ukf", "rls"))
    runs_a, traces_a = compare(cfg, tmp_path / "a")
    runs_b, traces_b = compare(cfg, tmp_path / "b")
    assert list(runs_a["run_id"]) == list(runs_b["run_id"])
    for col in ("E_final", "E_std_final", "E_ref", "shape_error_final", "n_solves"):
        np.testing.assert_array_equal(runs_a[col], runs_b[col])
    for col in ("E", "E_std", "shape_error"):
        np.testing.assert_array_equal(traces_a[col], traces_b[col])
    pd.testing.assert_frame_equal(drop_wall(runs_a), drop_wall(runs_b))


def test_run_id_is_deterministic():
    a = [r.run_id for r in expand(tiny(meshes=(COARSE, FINE)))]
    b = [r.run_id for r in expand(tiny(meshes=(COARSE, FINE)))]
    assert a == b
    assert len(set(a)) == len(a)
    # not changed by the timeout, changed by anything the result depends on
    assert [r.run_id for r in expand(tiny(meshes=(COARSE, FINE), timeout=9.0))] == a
    assert expand(tiny(steps=7))[0].run_id not in a
    assert expand(tiny(noise=(2e-4,)))[0].run_id not in a
    # and the same in another interpreter (no hash randomisation)
    code = (
        "from idbench.plan.config import CompareConfig;"
        "from idbench.run.compare import runs_of as expand;"
        f"print(' '.join(r.run_id for r in expand(CompareConfig(truth_mesh={TRUTH!r},"
        f"meshes=({COARSE!r},{FINE!r}),estimators=('rls','batch-ls'),steps=6,"
        "seeds=1))))"
    )
    out = subprocess.run(
        [sys.executable, "-c", code],
        capture_output=True,
        text=True,
        check=True,
        env={**_env(), "PYTHONHASHSEED": "12345"},
    ).stdout.split()
    assert out == a


def _env() -> dict[str, str]:
    import os

    return dict(os.environ)


# --- bad options ----------------------------------------------------------------


def error_line(capsys) -> str:
    captured = capsys.readouterr()
    err = captured.err.strip()
    assert "Traceback" not in captured.err + captured.out
    assert len(err.splitlines()) == 1, err
    assert err.startswith("idbench: error:"), err
    return err


@pytest.mark.parametrize(
    "extra, expected",
    [
        (["--estimators", "ro-ukf,rlss"], ["'rlss'", "did you mean 'rls'"]),
        (["--scenarios", "bend-q"], ["unknown scenario", "'bend-q'"]),
        (["--noise=-1"], ["noise", "-1", ">= 0"]),
        (["--steps", "0"], ["steps 0"]),
        (["--steps", "two"], ["--steps 'two'"]),
        (["--nu", "0.5"], ["nu 0.5", "(-1, 0.5)"]),
        (["--meshes", "/nonexistent.msh"], ["/nonexistent.msh"]),
        (["--prior", "1,2,3"], ["--prior", "MEAN,STD"]),
        (["--seeds", "0"], ["seeds 0"]),
        (["--obs-every", "2,x"], ["--obs-every '2,x'"]),
        (["--config", "/nonexistent.toml"], ["/nonexistent.toml", "does not exist"]),
    ],
)
def test_bad_option_exits_2(extra, expected, capsys, tmp_path):
    rc = main([*tiny_args(*extra), "--out", str(tmp_path / "out")])
    err = error_line(capsys)
    assert rc == 2
    for text in expected:
        assert text in err, err
    assert not (tmp_path / "out").exists()


def test_bad_option_exit_status_in_a_real_process(tmp_path):
    proc = subprocess.run(
        [sys.executable, "-m", "idbench.cli", *tiny_args("--steps", "0", "--dry-run")],
        capture_output=True,
        text=True,
        env=_env(),
        cwd=tmp_path,
    )
    assert proc.returncode == 2
    assert "Traceback" not in proc.stderr
    assert proc.stderr.strip().splitlines() == [
        "idbench: error: steps 0: must be a whole number >= 1"
    ]


def test_garbage_mesh_file_exits_2(tmp_path, capsys):
    bad = tmp_path / "bad.msh"
    bad.write_text("not a mesh\n")
    rc = main([*tiny_args("--dry-run"), "--meshes", str(bad)])
    assert rc == 2
    assert str(bad) in error_line(capsys)


def write_toml(tmp_path: Path, text: str) -> Path:
    path = tmp_path / "cfg.toml"
    path.write_text(text)
    return path


def test_unknown_toml_key_suggests(tmp_path, capsys):
    path = write_toml(tmp_path, "nosie = 1\n")
    assert main([*tiny_args("--dry-run"), "--config", str(path)]) == 2
    err = error_line(capsys)
    assert "'nosie'" in err and "did you mean 'noise'" in err


def test_unknown_estimator_setting_in_toml(tmp_path, capsys):
    path = write_toml(tmp_path, '[estimators.ro-ukf]\nsigma_point = "star"\n')
    argv = [*tiny_args("--dry-run"), "--estimators", "ro-ukf", "--config", str(path)]
    assert main(argv) == 2
    err = error_line(capsys)
    assert "'ro-ukf'" in err and "'sigma_point'" in err
    assert "did you mean 'sigma_points'" in err


def test_bad_estimator_setting_value_in_toml(tmp_path, capsys):
    path = write_toml(tmp_path, '[estimators.ro-ukf]\nsigma_points = "moon"\n')
    argv = [*tiny_args("--dry-run"), "--estimators", "ro-ukf", "--config", str(path)]
    assert main(argv) == 2
    assert "'moon'" in error_line(capsys)


def test_invalid_toml(tmp_path, capsys):
    path = write_toml(tmp_path, "seeds = = 2\n")
    assert main([*tiny_args("--dry-run"), "--config", str(path)]) == 2
    assert "not valid TOML" in error_line(capsys)


def test_bad_python_api_values_raise_config_error(tmp_path):
    with pytest.raises(ConfigError, match="did you mean 'rls'"):
        compare(tiny(estimators=("rlss",)), tmp_path / "x")
    with pytest.raises(ConfigError, match="jobs 0"):
        compare(tiny(), tmp_path / "x", jobs=0)
    with pytest.raises(ConfigError, match="noise"):
        tiny(noise=(-1.0,))
    assert not (tmp_path / "x").exists()


# --- TOML config ----------------------------------------------------------------

# TOML cannot hold both ``estimators = [...]`` and ``[estimators.NAME]`` at the
# top level, so the list goes in the [compare] table.
TOML = f"""
[compare]
truth-mesh = "{TRUTH}"
meshes = ["{COARSE}", "{FINE}"]
estimators = ["rls", "batch-ls", "lms"]
steps = 6
seeds = 2
noise = [1e-4, 2e-4]

[estimators.ro-ukf]
sigma_points = "star"
"""


def run_count(capsys) -> int:
    out = capsys.readouterr().out
    return int(out.split(" runs;")[0])


def test_toml_values_are_used(tmp_path, capsys):
    path = write_toml(tmp_path, TOML)
    assert main(["compare", "--config", str(path), "--dry-run"]) == 0
    # 2 meshes x 2 noise levels x 3 estimators x 2 seeds
    out = capsys.readouterr().out
    assert out.startswith("24 runs;"), out
    assert f"{COARSE}:" in out and f"{TRUTH}:" in out


def test_toml_compare_table_keeps_estimators_next_to_settings(tmp_path):
    from idbench.plan.config import load_toml

    fields = load_toml(write_toml(tmp_path, TOML))
    assert fields["estimators"] == ("rls", "batch-ls", "lms")
    assert fields["estimator_settings"] == {"ro-ukf": {"sigma_points": "star"}}
    assert fields["truth_mesh"] == TRUTH and fields["noise"] == (1e-4, 2e-4)


def test_cli_wins_over_toml(tmp_path, capsys):
    path = write_toml(tmp_path, TOML)
    base = ["compare", "--config", str(path), "--dry-run"]
    assert main([*base, "--seeds", "1"]) == 0
    assert run_count(capsys) == 12
    assert main([*base, "--seeds", "1", "--meshes", COARSE]) == 0
    assert run_count(capsys) == 6
    assert main([*base, "--noise", "0", "--estimators", "rls"]) == 0
    assert run_count(capsys) == 4


def test_toml_compare_table(tmp_path, capsys):
    path = write_toml(
        tmp_path,
        f'[compare]\ntruth_mesh = "{TRUTH}"\nmeshes = "{COARSE}"\n'
        'estimators = ["rls"]\nseeds = 3\nsteps = 6\n',
    )
    assert main(["compare", "--config", str(path), "--dry-run"]) == 0
    assert run_count(capsys) == 3


def test_toml_settings_reach_the_runs(tmp_path, cache_dir):
    path = write_toml(
        tmp_path,
        f'truth_mesh = "{TRUTH}"\nmeshes = ["{COARSE}"]\n'
        'steps = 6\nseeds = 1\n[estimators.ro-ukf]\nsigma_points = "star"\n',
    )
    out = tmp_path / "out"
    argv = ["compare", "--config", str(path), "--estimators", "ro-ukf"]
    assert main([*argv, "--out", str(out), "-q"]) == 0
    runs = pd.read_parquet(out / "runs.parquet")
    assert list(runs["settings"]) == ['{"sigma_points": "star"}']
    assert list(runs["status"]) == ["ok"]


# --- failure isolation ----------------------------------------------------------


@dataclass
class Boom:
    """An estimator that keeps the prior and raises at ``fail_at``."""

    fail_at: int = 3

    def start(self, model: Any, prior: idbench.Prior) -> None:
        self.prior = prior

    def update(self, k: int, observation: Any) -> idbench.Estimate:
        if k == self.fail_at:
            raise RuntimeError(f"boom at step {k}")
        mean = np.asarray(self.prior.mean, dtype=float)
        return idbench.Estimate(mean, np.full(mean.shape, np.nan), idbench.Cost())


def test_failing_estimator_is_isolated(tmp_path):
    reg = idbench.build_registry()
    reg.estimators["boom"] = idbench.registry.registry.Entry("boom", Boom, "test")
    cfg = tiny(estimators=("rls", "boom", "batch-ls"))
    runs, traces = compare(cfg, tmp_path / "out", registry=reg)
    by = runs.set_index("estimator")
    assert by.loc["boom", "status"] == "failed"
    assert "RuntimeError" in by.loc["boom", "error"]
    assert "boom at step 3" in by.loc["boom", "error"]
    assert "boom at step 3" in by.loc["boom", "traceback"]
    assert by.loc["rls", "status"] == "ok" and by.loc["rls", "error"] == ""
    assert by.loc["batch-ls", "status"] == "ok"
    assert np.isfinite(by.loc["rls", "E_final"])
    # the failed run's finished steps are kept
    boom_id = by.loc["boom", "run_id"]
    assert sorted(traces.loc[traces["run_id"] == boom_id, "step"]) == [1, 2]
    # a failed run counts as finished: a rerun does not repeat it
    again, _ = compare(cfg, tmp_path / "out", registry=reg)
    assert list(again["status"]) == list(runs["status"])


def test_failure_at_the_first_step(tmp_path):
    reg = idbench.build_registry()
    reg.estimators["boom"] = idbench.registry.registry.Entry("boom", Boom, "test")
    cfg = tiny(estimators=("boom",), estimator_settings={"boom": {"fail_at": 1}})
    runs, traces = compare(cfg, tmp_path / "out", registry=reg)
    assert list(runs["status"]) == ["failed"]
    assert "boom at step 1" in runs["error"].iloc[0]
    assert traces.empty


def test_interleave_puts_runs_on_different_data_first():
    from idbench.run.compare import interleave
    from idbench.run.compare import runs_of as expand

    cfg = CompareConfig(meshes=("4x1x1",), seeds=3, estimators=("rls", "lms", "ro-ukf"))
    runs = expand(cfg)
    order = interleave(runs)
    assert sorted(r.run_id for r in order) == sorted(r.run_id for r in runs)
    keys = [r.reference_key() for r in order]
    assert len(set(keys[:3])) == 3  # one run per data first
    assert keys[3:6] == keys[:3]


def test_a_worker_uses_the_reference_another_worker_fitted(tmp_path):
    from idbench.run.compare import runs_of as expand
    from idbench.run.harness import execute
    from idbench.run.session import Session

    spec = expand(CompareConfig(truth_mesh="8x2x2", meshes=("4x1x1",), steps=4,
                                seeds=1, estimators=("rls",)))[0]  # fmt: skip
    first = Session()
    row, _ = execute(spec, first)
    fitted = first.known_reference(spec)
    assert fitted is not None and fitted[0] == pytest.approx(row["E_ref"])
    fresh = Session()  # another worker, told the answer
    fresh.remember_reference(spec, np.array([1234.5]))
    row, _ = execute(spec, fresh)
    assert row["E_ref"] == 1234.5  # not refitted
    assert fresh.known_reference(spec)[0] == 1234.5


def test_the_reference_estimators_own_run_is_its_datas_reference_fit(
    tmp_path, monkeypatch
):
    """Each data set's reference value is fitted once: by the reference
    estimator's own run (scheduled first), not again for the other runs."""
    from idbench_filters.batch_ls import BatchLs

    fits = []
    begin = BatchLs.begin

    def counted(self, model, prior):
        fits.append(1)
        return begin(self, model, prior)

    monkeypatch.setattr(BatchLs, "begin", counted)
    cfg = tiny(estimators=("rls", "batch-ls"), seeds=2)
    runs, _ = compare(cfg, tmp_path / "out")
    assert (runs["status"] == "ok").all()
    assert len(fits) == 2  # one per seed: the batch-ls runs themselves
    by = runs.set_index(["estimator", "seed"])
    for seed in (0, 1):
        fitted = by.loc[("batch-ls", seed), "E_final"]
        assert by.loc[("batch-ls", seed), "E_ref"] == fitted
        assert by.loc[("rls", seed), "E_ref"] == fitted


def test_a_sweep_over_marker_counts_observes_each_count(tmp_path):
    """The truth is probed per marker count (the states are shared)."""
    runs, _ = compare(tiny(obs_points=(1, 2), estimators=("rls",)), tmp_path)
    assert (runs["status"] == "ok").all(), runs[["obs_points", "error"]]
    assert sorted(runs["obs_points"]) == [1, 2]
    assert runs["E_final"].nunique() == 2  # different data, different estimates
