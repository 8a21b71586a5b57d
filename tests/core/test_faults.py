"""Faults: misbehaving plugins, dead workers, bad folders, bad files.

Plugins that must reach worker processes are *installed* for real: a module
and a ``*.dist-info`` folder (with its ``entry_points.txt``) in a temporary
directory put on ``sys.path`` and ``PYTHONPATH``, so spawned workers and
subprocesses discover them through ``importlib.metadata`` exactly as they
would a pip-installed plugin.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
import pytest
from support.helpers import MODEL, STEPS, TRUTH, tiny

from idbench.cli.commands import main
from idbench.plan.config import ConfigError
from idbench.run.compare import compare

TINY = ["--truth-mesh", TRUTH, "--meshes", MODEL, "--steps", str(STEPS), "--seeds",
        "1"]  # fmt: skip


BAD_ESTIMATORS = '''
    """Estimators that misbehave in ways a sweep must survive."""
    import os
    import signal
    import sys
    import time
    from dataclasses import dataclass
    from pathlib import Path

    import numpy as np

    import idbench


    @dataclass
    class Base:
        at: int = 2
        marker: str = ""

        def start(self, model, prior):
            self.mean = np.asarray(prior.mean, dtype=float)

        def answer(self):
            return idbench.Estimate(self.mean, np.full_like(self.mean, 1.0),
                                    idbench.Cost())

        def update(self, k, observation):
            if k == self.at:
                if self.marker:  # written whole, then renamed: never read empty
                    part = Path(self.marker + ".part")
                    part.write_text(str(os.getpid()))
                    os.replace(part, self.marker)
                self.misbehave()
            return self.answer()


    @dataclass
    class Exits(Base):
        def misbehave(self):
            sys.exit(0)


    @dataclass
    class Dies(Base):
        def misbehave(self):
            os._exit(3)


    @dataclass
    class Interrupts(Base):
        def misbehave(self):
            raise KeyboardInterrupt


    @dataclass
    class HangsInC(Base):
        def misbehave(self):  # as a C library that masks signals while it waits
            signal.pthread_sigmask(signal.SIG_BLOCK, [signal.SIGALRM])
            time.sleep(600)


    @dataclass
    class Sleeps(Base):
        def misbehave(self):
            time.sleep(600)


    @dataclass
    class Matrix(Base):
        def answer(self):
            mean = self.mean.reshape(1, -1)  # (1, 1) instead of (1,)
            return idbench.Estimate(mean, np.ones_like(mean), idbench.Cost())

        def misbehave(self):
            pass


    @idbench.hookimpl
    def register_estimators(register):
        register("exits", Exits)
        register("dies", Dies)
        register("interrupts", Interrupts)
        register("hangs-in-c", HangsInC)
        register("sleeps", Sleeps)
        register("matrix", Matrix)
'''

TAKES_A_NAME = """
    from dataclasses import dataclass

    import idbench


    @dataclass
    class Fake:
        pass


    class NotADataclass:
        pass


    @idbench.hookimpl
    def register_estimators(register):
        register("ro-ukf", Fake)  # a built-in's name
"""

NOT_A_DATACLASS = TAKES_A_NAME.replace(
    'register("ro-ukf", Fake)', 'register("mine", NotADataclass)'
)


# --- 1. threads: a Dask worker with two threads ------------------------------


@pytest.mark.dask
def test_dask_worker_with_two_threads_gives_the_serial_results(tmp_path):
    distributed = pytest.importorskip("distributed")
    cfg = tiny(meshes=("3x1x1", MODEL), seeds=3, estimators=("rls", "ro-ukf", "lms"))
    serial, _ = compare(cfg, tmp_path / "serial")
    with distributed.LocalCluster(
        n_workers=1, threads_per_worker=2, processes=True, host="127.0.0.1",
        dashboard_address=None, env={"OMP_NUM_THREADS": "1"},
    ) as cluster:  # fmt: skip
        runs, _ = compare(cfg, tmp_path / "dask", scheduler=cluster.scheduler_address)
    assert (runs["status"] == "ok").all(), runs[["estimator", "status", "error"]]
    a = runs.set_index("run_id").sort_index()
    b = serial.set_index("run_id").sort_index()
    np.testing.assert_allclose(a["E_final"], b["E_final"], rtol=1e-9)
    np.testing.assert_allclose(
        a["shape_error_final"], b["shape_error_final"], rtol=1e-9
    )


# --- 2, 3, 14: estimators that return nonsense, exit or interrupt ------------


@pytest.mark.parametrize("jobs,method", [(1, "fork"), (2, "fork"), (2, "spawn")])
def test_misbehaving_estimators_fail_their_run_only(
    install, tmp_path, monkeypatch, jobs, method
):
    monkeypatch.setenv("IDBENCH_START_METHOD", method)
    install("bad-ests", BAD_ESTIMATORS)
    cfg = tiny(estimators=("rls", "matrix", "exits", "interrupts"))
    out = tmp_path / "out"
    runs, _ = compare(cfg, out, jobs=jobs)
    by = runs.set_index("estimator")
    assert by.loc["rls", "status"] == "ok"
    assert by.loc["matrix", "status"] == "failed"
    assert "mean of shape (1, 1) at step 1; expected (1,)" in by.loc["matrix", "error"]
    assert by.loc["exits", "status"] == "failed"
    assert "called sys.exit(0) in update() at step 2" in by.loc["exits", "error"]
    assert by.loc["interrupts", "status"] == "failed"
    assert "KeyboardInterrupt in update() at step 2" in by.loc["interrupts", "error"]
    assert (out / "runs.parquet").exists() and (out / "traces.parquet").exists()
    again, _ = compare(cfg, out, jobs=jobs)  # the folder stays usable
    assert list(again["status"]) == list(runs["status"])


# --- 4: a plugin that takes a name or registers a non-dataclass --------------


@pytest.mark.parametrize("source", [TAKES_A_NAME, NOT_A_DATACLASS])
def test_a_broken_plugin_is_reported_and_the_rest_works(install, tmp_path, capsys,
                                                        source):  # fmt: skip
    install("broken", source)
    assert main(["plugins", "--json"]) == 0
    rows = {r["name"]: r for r in json.loads(capsys.readouterr().out)}
    assert rows["broken"]["error"]
    assert rows["broken"]["estimators"] == []
    assert "ro-ukf" in rows["filters"]["estimators"]
    assert main(["compare", *TINY, "--estimators", "ro-ukf,rls",
                 "--out", str(tmp_path / "o"), "-q"]) == 0  # fmt: skip
    capsys.readouterr()
    if source is NOT_A_DATACLASS:  # naming its entry: one line naming the plugin
        assert main(["compare", *TINY, "--estimators", "mine", "--dry-run"]) == 2
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and "unknown estimator 'mine'" in err
        assert "disabled plugins: broken" in err


# --- 5, 14: a dead worker is charged to its own run only ----------------------


@pytest.mark.parametrize("method", ["fork", "spawn"])
def test_a_worker_death_is_charged_to_its_own_run_only(
    install, tmp_path, monkeypatch, method
):
    monkeypatch.setenv("IDBENCH_START_METHOD", method)
    install("bad-ests", BAD_ESTIMATORS)
    cfg = tiny(estimators=("dies", "rls", "lms"), seeds=3)
    runs, _ = compare(cfg, tmp_path / "out", jobs=2)
    by_status = runs.groupby("estimator")["status"].agg(set)
    assert by_status["dies"] == {"failed"}
    assert by_status["rls"] == by_status["lms"] == {"ok"}
    errors = runs.loc[runs["estimator"] == "dies", "error"]
    assert errors.str.contains("worker process died (exit code 3)", regex=False).all()


# --- 6: a timeout stops a hang in compiled code --------------------------------


@pytest.mark.parametrize("method", ["fork", "spawn"])
def test_timeout_stops_a_hang_in_compiled_code(install, tmp_path, monkeypatch, method):
    monkeypatch.setenv("IDBENCH_START_METHOD", method)
    install("bad-ests", BAD_ESTIMATORS)
    cfg = tiny(estimators=("hangs-in-c", "rls"), timeout=3.0)
    start = time.monotonic()
    runs, _ = compare(cfg, tmp_path / "out")  # jobs=1: still in a worker
    assert time.monotonic() - start < 90
    by = runs.set_index("estimator")
    assert by.loc["rls", "status"] == "ok"
    assert by.loc["hangs-in-c", "status"] == "failed"
    assert "--timeout 3 s" in by.loc["hangs-in-c", "error"]
    assert "worker process was killed" in by.loc["hangs-in-c", "error"]


# --- 7, 8: sweep axes and sizes ------------------------------------------------


@pytest.mark.parametrize(
    "argv, words",
    [
        (["--noise", "0,0"], "noise (0.0, 0.0) has duplicates"),
        (["--obs-every", "2,2"], "obs_every (2, 2) has duplicates"),
        (["--seeds", "1000000000000"], "more than the limit of 100,000"),
        (["--meshes", "199x99x99"], "more than the limit of 300,000"),
        (["--timeout", "1e308"], "timeout 1e+308: must be a number in (0, "),
    ],
)
def test_bad_sweeps_are_refused_before_allocating(argv, words, capsys):
    start = time.monotonic()
    base = [a for a in TINY if a not in ("--seeds", "1")] if "--seeds" in argv else TINY
    assert main(["compare", *base, *argv, "--dry-run"]) == 2
    assert time.monotonic() - start < 30
    err = capsys.readouterr().err
    assert words in err and err.count("\n") == 1


# --- 9, 11, 14: the results folder ----------------------------------------------


def test_a_corrupt_part_is_quarantined_and_its_run_redone(tmp_path, caplog):
    cfg = tiny(estimators=("rls", "lms"))
    out = tmp_path / "out"
    runs, _ = compare(cfg, out)
    victim = runs["run_id"].iloc[0]
    (out / "parts" / f"{victim}.runs.parquet").write_bytes(b"not parquet")
    (out / "parts" / ".tmp-leftover.parquet").write_bytes(b"half a file")
    again, _ = compare(cfg, out)
    assert (out / "quarantine" / f"{victim}.runs.parquet").exists()
    assert "running it again" in caplog.text
    assert not list((out / "parts").glob(".tmp-*"))
    pd.testing.assert_series_equal(again["E_final"], runs["E_final"])


def test_changing_only_the_timeout_resumes(tmp_path):
    out = tmp_path / "out"
    compare(tiny(), out)
    runs, _ = compare(tiny(timeout=100.0), out)
    assert list(runs["status"]) == ["ok"]
    with pytest.raises(Exception, match="other settings"):
        compare(tiny(seeds=2), out)


def test_files_follow_the_umask(tmp_path):
    old = os.umask(0o022)
    try:
        compare(tiny(), tmp_path / "out")
    finally:
        os.umask(old)
    for path in [tmp_path / "out" / "runs.parquet", tmp_path / "out" / "manifest.json",
                 *(tmp_path / "out" / "parts").iterdir()]:  # fmt: skip
        assert path.stat().st_mode & 0o777 == 0o644, path


def test_ctrl_c_keeps_tables_of_finished_runs(tmp_path):
    def stop(done: int, total: int, row: dict[str, Any]) -> None:
        if done == 1:
            raise KeyboardInterrupt

    out = tmp_path / "out"
    with pytest.raises(KeyboardInterrupt):
        compare(tiny(estimators=("rls", "lms")), out, progress=stop)
    assert len(pd.read_parquet(out / "runs.parquet")) == 1


# --- 10, 14: one line and exit 2 instead of a traceback --------------------------


def _one_line(capsys, argv: list[str], code: int = 2) -> str:
    assert main(argv) == code
    captured = capsys.readouterr()
    assert "Traceback" not in captured.err + captured.out
    assert captured.err.count("\n") == 1, captured.err
    return captured.err


def test_unusable_output_folders_are_one_line(tmp_path, capsys):
    afile = tmp_path / "afile"
    afile.write_text("x")
    compare_ = ["compare", *TINY, "--estimators", "rls"]
    assert "need a directory" in _one_line(capsys, [*compare_, "--out", str(afile)])
    assert "cannot write" in _one_line(capsys, [*compare_, "--out", str(afile / "sub")])
    assert "need a path" in _one_line(capsys, [*compare_, "--out", ""])
    out = tmp_path / "out"
    assert main([*compare_, "--out", str(out), "-q"]) == 0
    capsys.readouterr()
    assert "other settings" in _one_line(
        capsys, [*compare_, "--out", str(out), "--steps", "4"]
    )
    for text in ("[1, 2]", "{not json"):
        (out / "manifest.json").write_text(text)
        assert "manifest" in _one_line(capsys, [*compare_, "--out", str(out)])


def test_readme_order_compare_then_quick_uses_two_folders(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    assert main(["compare", *TINY, "--estimators", "rls", "-q"]) == 0
    small = [a for a in TINY if a not in ("--seeds", "1")]  # --quick: one seed
    assert main(["compare", "--quick", *small, "--estimators", "rls", "-q"]) == 0
    assert (tmp_path / "idbench-out" / "runs.parquet").exists()
    assert (tmp_path / "idbench-out-quick" / "runs.parquet").exists()


@pytest.mark.parametrize(
    "toml, words",
    [
        ("[estimators]\nrls = 5\n", "[estimators] rls = 5"),
        ("model = 5\n", "model 5"),
        ("estimator_settings = 5\n", "unknown key 'estimator_settings'"),
        ("[model]\nsvk-beam = 5\n", "[model] svk-beam = 5"),
        ('[model.svk-beam]\ntrue_factors = "abc"\n', "true_factors 'abc'"),
        ("[model.svk-beam]\ncolour = 1\n", "has no setting 'colour'"),
        ("true = {F = 1.0}\n", "model 'svk-beam' has no such parameter"),
        ("compare = 5\n", "compare = 5"),
        ("prior = 5\n", "prior 5"),
    ],
)
def test_bad_toml_values_are_one_line(tmp_path, capsys, toml, words):
    cfg = tmp_path / "c.toml"
    cfg.write_text(toml)
    err = _one_line(capsys, ["compare", *TINY, "--config", str(cfg), "--dry-run",
                             "--out", str(tmp_path / "o")])  # fmt: skip
    assert words in err


def test_failed_truth_solves_are_one_line_without_warnings(tmp_path, capsys):
    out = str(tmp_path / "o")
    err = _one_line(capsys, ["compare", *TINY, "--E-true", "1e-300", "--out", out])
    assert "outside the parameter bounds" in err
    for opt in (["--E-true", "2"], ["--nu", "0.4999999"]):
        err = _one_line(capsys, ["compare", *TINY, *opt, "--out", out])
        assert "cannot be simulated" in err and "Warning" not in err
    assert main(["compare", *TINY, "--out", out, "-q"]) == 0  # the folder is free


def test_other_commands_bad_paths_and_garbage_are_one_line(tmp_path, capsys):
    afile = tmp_path / "afile"
    afile.write_text("x")
    assert ".xdmf" in _one_line(capsys, ["simulate", "--mesh", MODEL, "--scenario",
                                         "bend-y", "--out", str(tmp_path)])  # fmt: skip
    assert "is a file" in _one_line(capsys, ["calibrate", "--mesh", MODEL, "--out",
                                             str(afile)])  # fmt: skip
    (tmp_path / "g").mkdir()
    (tmp_path / "g" / "runs.parquet").write_text("garbage")
    err = _one_line(capsys, ["report", str(tmp_path / "g")])
    assert "readable idbench results" in err
    out = str(tmp_path / "s")
    err = _one_line(capsys, ["compare", *TINY, "--scheduler", "garbage", "--out", out])
    assert "scheduler 'garbage'" in err


def test_a_failed_write_is_one_line(tmp_path, capsys, monkeypatch):
    import idbench.store.results

    def full(*args: Any, **kwargs: Any) -> None:
        raise OSError(27, "File too large")

    monkeypatch.setattr(idbench.store.results, "atomic_write_parquet", full)
    err = _one_line(capsys, ["compare", *TINY, "--out", str(tmp_path / "o")])
    assert "File too large" in err


def test_broken_pipe_is_quiet(tmp_path):
    proc = subprocess.run(
        f"{sys.executable} -m idbench.cli plugins --json | head -1",
        shell=True, capture_output=True, text=True, timeout=120,
    )  # fmt: skip
    assert proc.stdout.strip() == "["
    assert "Traceback" not in proc.stderr and "BrokenPipe" not in proc.stderr


# --- 12: killing the main process ends its workers ------------------------------


@pytest.mark.parametrize("sig", [signal.SIGKILL, signal.SIGTERM])
def test_killing_the_main_process_ends_its_workers(install, tmp_path, sig):
    install("bad-ests", BAD_ESTIMATORS)
    marker = tmp_path / "asleep"
    cfg = tmp_path / "c.toml"
    cfg.write_text(f'[estimators.sleeps]\nmarker = "{marker}"\n')
    proc = subprocess.Popen(
        [sys.executable, "-m", "idbench.cli", "compare", *TINY, "--estimators",
         "sleeps,rls", "--jobs", "2", "--config", str(cfg), "--out",
         str(tmp_path / "o"), "-q"],
        stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
    )  # fmt: skip
    try:
        deadline = time.monotonic() + 120
        while not marker.exists():
            assert proc.poll() is None and time.monotonic() < deadline
            time.sleep(0.2)
        worker = int(marker.read_text())
        assert _alive(worker)
        proc.send_signal(sig)
        proc.wait(30)
        deadline = time.monotonic() + 20
        while _alive(worker) and time.monotonic() < deadline:
            time.sleep(0.2)
        assert not _alive(worker)
    finally:
        proc.kill()


def _alive(pid: int) -> bool:
    try:
        state = Path(f"/proc/{pid}/stat").read_text().split()[2]
    except OSError:
        return False
    return state != "Z"


# --- 13: the truth cache checks its content --------------------------------------


def test_truth_cache_rejects_altered_or_misshapen_entries(
    tmp_path, monkeypatch, caplog
):
    from idbench import ModelSpec, build_registry
    from idbench.truth.cache import cache_dir
    from idbench.truth.simulate import simulate_truth

    monkeypatch.setenv("IDBENCH_CACHE_DIR", str(tmp_path / "cache"))
    reg = build_registry()
    model = reg.model("svk-beam")(
        ModelSpec(mesh=MODEL, scenario=reg.scenario("bend-y"), n_steps=3)
    )
    theta = np.array([5000.0])
    first = simulate_truth(model, theta)
    (entry,) = cache_dir().glob("truth-*.npz")
    with np.load(entry) as data:
        fields = dict(data)
    for states in (fields["states"] * 1.01, fields["states"][:, :-3]):
        np.savez(entry, **{**fields, "states": states})
        again = simulate_truth(model, theta)
        np.testing.assert_array_equal(again.states, first.states)
    assert "digest mismatch" in caplog.text and "shape" in caplog.text


def test_unwritable_cache_runs_uncached_with_a_warning(tmp_path, monkeypatch, caplog):
    blocker = tmp_path / "file"
    blocker.write_text("x")
    monkeypatch.setenv("IDBENCH_CACHE_DIR", str(blocker / "cache"))
    runs, _ = compare(tiny(), tmp_path / "out")
    assert list(runs["status"]) == ["ok"]
    assert "going on without caching" in caplog.text


def test_config_errors_name_the_key_and_hide_private_fields():
    with pytest.raises(ConfigError, match="prior 5"):
        tiny(prior=5)
    with pytest.raises(ConfigError) as info:
        compare(tiny(estimator_settings={"ro-ukf": {"colour": 1}}))
    assert "_run" not in str(info.value) and "sigma_points" in str(info.value)


def test_timeout_counts_the_estimator_not_the_scoring(install, tmp_path):
    """A worker is killed only when the estimator's own work overruns."""
    install("bad-ests", BAD_ESTIMATORS)
    # lms is quick; the reference fit and transfer solves after it are not timed
    cfg = tiny(estimators=("lms",), timeout=1.0, steps=5, meshes=("6x2x2",))
    runs, _ = compare(cfg, tmp_path / "out")
    assert list(runs["status"]) == ["ok"], runs["error"].tolist()


def test_worker_lost_rows_have_every_column(install, tmp_path):
    install("bad-ests", BAD_ESTIMATORS)
    runs, _ = compare(tiny(estimators=("dies", "rls")), tmp_path / "out", jobs=2)
    lost = runs.set_index("estimator").loc["dies"]
    assert {"E_final", "E_ref", "wall_s"} <= set(lost.index)


def test_a_plugin_command_or_shorthand_that_clashes_is_reported(tmp_path, capsys,
                                                                 install):  # fmt: skip
    install(
        "clash",
        """
    import idbench


    def configure(parser):
        raise RuntimeError("cannot configure")


    @idbench.hookimpl
    def register_commands(register):
        register("plugins", idbench.Command("shadows", lambda p: None, lambda a: 0))
        register("broken-cmd", idbench.Command("breaks", configure, lambda a: 0))
    """,
    )
    assert main(["plugins", "--json"]) == 0
    rows = {r["name"]: r for r in json.loads(capsys.readouterr().out)}
    assert "one of idbench's own" in rows["clash"]["error"]
    assert "cannot configure" in rows["clash"]["error"]
    assert main(["compare", *TINY, "--estimators", "rls", "--dry-run"]) == 0
