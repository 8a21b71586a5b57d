"""Parallel executors: local process pool and a real Dask cluster.

Each executor must give the same tables as the serial path (apart from
timings), a worker killed mid-sweep must cost no finished run, and a scheduler
nobody listens on must fail fast with a :class:`ConfigError`.
"""

from __future__ import annotations

import logging
import os
import re
import signal
import socket
import time
from typing import Any

import numpy as np
import pandas as pd
import pytest

from idbench.plan.config import CompareConfig, ConfigError
from idbench.run.compare import compare
from idbench.run.executors import ClusterLost

distributed = pytest.importorskip("distributed")
pytestmark = pytest.mark.dask  # run last (tests/conftest.py)

TIMING = {"wall_s", "wall_s_step"}
LOOSE = {"E_ref": 1e-8, "nees_ref": 1e-3, "E_relerr_ref": 1e-4}
"""Columns compared more loosely. E_ref: the reference fit of a data set can
come out 1.2e-9 apart between a serial sweep and a fresh worker (seed 1 of
``tiny()``; a fresh Session in this process gives the worker's value), within
the Newton tolerance that docs/design.md allows. NEES against the reference squares
(E_final - E_ref) / std, a difference of two nearly equal values; so is
E_relerr_ref = E_final / E_ref - 1 (about 1e-4 here: E_ref's 1e-8 is 1e-4 of it)."""


def tiny(seeds: int = 2) -> CompareConfig:
    return CompareConfig(
        truth_mesh="20x3x3",
        meshes=("6x2x2",),
        steps=6,
        seeds=seeds,
        estimators=("ro-ukf", "rls"),
    )


@pytest.fixture
def cache(tmp_path, monkeypatch):
    """A truth cache shared by this process and every worker started after it."""
    path = tmp_path / "cache"
    path.mkdir()
    monkeypatch.setenv("IDBENCH_CACHE_DIR", str(path))
    return path


@pytest.fixture
def serial(cache, tmp_path):
    return compare(tiny(), tmp_path / "serial", jobs=1)


def assert_same(a: pd.DataFrame, b: pd.DataFrame, keys: list[str]) -> None:
    a = a.sort_values(keys).reset_index(drop=True)
    b = b.sort_values(keys).reset_index(drop=True)
    assert list(a.columns) == list(b.columns)
    assert len(a) == len(b)
    for col in a.columns:
        if col in TIMING:
            continue
        if pd.api.types.is_numeric_dtype(a[col]) and not pd.api.types.is_bool_dtype(
            a[col]
        ):
            np.testing.assert_allclose(
                a[col].to_numpy(float),
                b[col].to_numpy(float),
                rtol=LOOSE.get(col, 1e-9),
                atol=0,
                equal_nan=True,
                err_msg=col,
            )
        else:
            assert a[col].tolist() == b[col].tolist(), col


def assert_same_tables(got, want) -> None:
    runs, traces = got
    want_runs, want_traces = want
    assert (runs["status"] == "ok").all(), runs[["run_id", "status", "error"]]
    assert_same(runs, want_runs, ["run_id"])
    assert_same(traces, want_traces, ["run_id", "step"])


def test_process_pool_matches_serial(serial, tmp_path):
    assert_same_tables(compare(tiny(), tmp_path / "pool", jobs=2), serial)


@pytest.fixture
def cluster(cache):
    env = {"IDBENCH_CACHE_DIR": str(cache), "OMP_NUM_THREADS": "1"}
    with distributed.LocalCluster(
        n_workers=2,
        threads_per_worker=1,
        processes=True,
        host="127.0.0.1",
        dashboard_address=None,
        env=env,
    ) as cl:
        yield cl


def test_dask_cluster_matches_serial(serial, cluster, tmp_path):
    got = compare(tiny(), tmp_path / "dask", scheduler=cluster.scheduler_address)
    assert_same_tables(got, serial)


def test_killed_dask_worker_loses_no_run(cluster, tmp_path):
    config = tiny(seeds=4)
    out = tmp_path / "killed"
    with distributed.Client(cluster.scheduler_address) as client:
        pids = list(client.run(os.getpid).values())
    assert len(pids) == 2
    killed: list[int] = []

    def progress(done, total, row):
        if not killed:
            os.kill(pids[0], signal.SIGKILL)
            killed.append(pids[0])

    runs, _ = compare(
        config, out, scheduler=cluster.scheduler_address, progress=progress
    )
    assert killed
    n_runs = 2 * 4  # estimators x seeds
    assert len(runs) == n_runs
    assert runs["run_id"].is_unique
    assert set(runs["status"]) <= {"ok", "failed"}
    on_disk = pd.read_parquet(out / "runs.parquet")
    assert len(on_disk) == n_runs
    assert set(on_disk["run_id"]) == set(runs["run_id"])


def test_unreachable_scheduler_is_a_config_error(cache, tmp_path):
    address = "tcp://127.0.0.1:1"
    start = time.monotonic()
    with pytest.raises(ConfigError, match=re.escape(address)):
        compare(tiny(), tmp_path / "nobody", scheduler=address)
    assert time.monotonic() - start < 30
    assert not (tmp_path / "nobody" / "manifest.json").exists()


def closed_port() -> str:
    """The address of a local TCP port nobody listens on (bound, then closed)."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    return f"tcp://127.0.0.1:{port}"


def test_failed_connection_leaves_the_folder_usable(cache, tmp_path, monkeypatch):
    """Nothing stored: no manifest, so other settings may use the folder; runs
    stored before: kept, with their manifest."""
    monkeypatch.setattr("idbench.run.executors.dask.CONNECT_TIMEOUT_S", 1)
    out = tmp_path / "out"
    with pytest.raises(ConfigError, match="cannot connect"):
        compare(tiny(), out, scheduler=closed_port())
    assert not (out / "manifest.json").exists()
    runs, _ = compare(tiny(seeds=1), out)  # other settings: the folder is free
    assert (runs["status"] == "ok").all()
    first = sorted(runs["run_id"])[0]
    for part in (out / "parts").glob(f"{first}.*"):
        part.unlink()  # one run left to do
    with pytest.raises(ConfigError, match="cannot connect"):
        compare(tiny(seeds=1), out, scheduler=closed_port())
    assert (out / "manifest.json").exists()
    assert len(list((out / "parts").glob("*.runs.parquet"))) == len(runs) - 1


def in_process_cluster() -> Any:
    """A one-worker, one-thread Dask cluster in this process, over TCP."""
    return distributed.LocalCluster(
        n_workers=1,
        threads_per_worker=1,
        processes=False,
        protocol="tcp",
        host="127.0.0.1",
        dashboard_address=None,
    )


@pytest.fixture
def threads_cluster(cache):
    """A cluster in this process (worker threads), which a test may close."""
    cl = in_process_cluster()
    try:
        yield cl
    finally:
        cl.close()


def stored(out) -> pd.DataFrame:
    parts = sorted((out / "parts").glob("*.runs.parquet"))
    return pd.concat([pd.read_parquet(p) for p in parts]) if parts else pd.DataFrame()


@pytest.mark.parametrize("after", [0, 2])
def test_lost_scheduler_stops_and_resumes(
    after, threads_cluster, cache, tmp_path, monkeypatch
):
    """The scheduler closed after ``after`` stored runs (0: before any came
    back): one error naming it and the count, no run recorded as failed for
    it, no manifest when nothing is stored, and a rerun completes the sweep."""
    import idbench.run.compare

    config = tiny(seeds=3)
    out = tmp_path / "lost"
    address = threads_cluster.scheduler_address
    if after == 0:
        prepare = idbench.run.compare.prepare

        def prepare_then_close(runs, session):
            prepare(runs, session)
            threads_cluster.close()

        monkeypatch.setattr(idbench.run.compare, "prepare", prepare_then_close)

    def progress(done, total, row):
        if done == after:
            threads_cluster.close()

    with pytest.raises(ClusterLost) as lost:
        compare(config, out, scheduler=address, progress=progress)
    message = str(lost.value)
    assert message.startswith(f"lost the Dask scheduler at {address}: "), message
    assert "\n" not in message
    count = int(re.search(r": (\d+) of 6 runs stored; rerun", message).group(1))
    rows = stored(out)
    assert count == len(rows) >= after
    if after == 0:
        assert count == 0
        assert not (out / "manifest.json").exists()
    else:
        assert (rows["status"] == "ok").all(), rows[["status", "error"]]
        assert len(pd.read_parquet(out / "runs.parquet")) == count
    monkeypatch.undo()
    with in_process_cluster() as again:
        runs, _ = compare(config, out, scheduler=again.scheduler_address)
    assert len(runs) == 6 and runs["run_id"].is_unique
    assert (runs["status"] == "ok").all(), runs[["status", "error"]]


@pytest.fixture
def dask_log_levels():
    """Restore the loggers' levels that the CLI lowers."""
    names = [n for n in logging.root.manager.loggerDict if n.startswith("distributed")]
    levels = {n: logging.getLogger(n).level for n in names}
    yield
    for name, level in levels.items():
        logging.getLogger(name).setLevel(level)


def test_cli_says_a_lost_scheduler_in_one_line(
    threads_cluster, cache, tmp_path, monkeypatch, capfd, dask_log_levels
):
    from idbench.cli.commands import main
    from idbench.store.results import ResultStore

    write = ResultStore.write
    writes: list[str] = []

    def write_then_close(self, run, traces):
        write(self, run, traces)
        writes.append(run["run_id"])
        if len(writes) == 2:
            threads_cluster.close()

    monkeypatch.setattr(ResultStore, "write", write_then_close)
    out = tmp_path / "cli"
    address = threads_cluster.scheduler_address
    argv = ["compare", "--scheduler", address, "--out", str(out), "-q"]
    argv += ["--truth-mesh", "20x3x3", "--meshes", "6x2x2", "--steps", "6"]
    argv += ["--seeds", "3", "--estimators", "ro-ukf,rls"]
    capfd.readouterr()
    code = main(argv)
    captured = capfd.readouterr()
    assert code == 3
    lines = [line for line in captured.err.splitlines() if line.strip()]
    assert lines == [
        f"idbench: error: lost the Dask scheduler at {address}: 2 of 6 runs "
        "stored; rerun the same command to resume"
    ], captured.err
    assert set(stored(out)["status"]) == {"ok"}
