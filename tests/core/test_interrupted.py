"""A sweep killed at random points keeps every finished run and resumes exactly."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time

import numpy as np
import pandas as pd
import pytest

ARGS = ["compare", "--truth-mesh", "12x3x3", "--meshes", "4x1x1,6x2x2", "--steps",
        "5", "--seeds", "2", "--estimators", "rls,lms,ro-ukf", "-q"]  # fmt: skip
WALL = ["wall_s", "wall_s_step"]


def run_cli(out, env, kill_at=None, jitter=0.0, sig=signal.SIGKILL):
    """Run a sweep; with ``kill_at``, signal it once that many runs are on disk.

    Killing on a count of finished runs (plus a random delay) rather than after
    a fixed time makes every attempt land mid-sweep on fast and slow machines.
    """
    cmd = [sys.executable, "-m", "idbench.cli", *ARGS, "--out", str(out)]
    proc = subprocess.Popen(cmd, env=env, stdout=subprocess.DEVNULL,
                            stderr=subprocess.PIPE, text=True)  # fmt: skip
    if kill_at is None:
        _, err = proc.communicate(timeout=300)
        assert proc.returncode == 0, err
        return True
    deadline = time.monotonic() + 300
    while proc.poll() is None and len(parts(out)) < kill_at:
        assert time.monotonic() < deadline, "sweep made no progress"
        time.sleep(0.02)
    time.sleep(jitter)
    finished = proc.poll() is not None
    if not finished:
        proc.send_signal(sig)
    proc.communicate(timeout=60)
    return finished


def parts(out):
    return {p.name.split(".")[0] for p in (out / "parts").glob("*.runs.parquet")}


@pytest.mark.slow
def test_random_kills_lose_nothing_and_resume_to_the_same_tables(tmp_path):
    env = {**os.environ, "IDBENCH_CACHE_DIR": str(tmp_path / "cache")}
    reference = tmp_path / "reference"
    run_cli(reference, env)  # also warms the truth cache
    ref_runs = pd.read_parquet(reference / "runs.parquet")

    rng = np.random.default_rng(7)
    out = tmp_path / "killed"
    seen: set[str] = set()
    kills = 0
    partial = 0
    for attempt in range(6):
        sig = signal.SIGKILL if attempt % 2 == 0 else signal.SIGINT
        kill_at = len(seen) + int(rng.integers(1, 3))
        jitter = float(rng.uniform(0.0, 0.1))
        finished = run_cli(out, env, kill_at=kill_at, jitter=jitter, sig=sig)
        now = parts(out)
        assert seen <= now, "a finished run was lost"
        for run_id in now:  # every part on disk is readable
            pd.read_parquet(out / "parts" / f"{run_id}.runs.parquet")
            pd.read_parquet(out / "parts" / f"{run_id}.traces.parquet")
        seen = now
        partial += 0 < len(now) < 12
        kills += not finished
        if finished:
            break
    assert kills >= 1 and partial >= 1  # killed while some, not all, runs were done
    run_cli(out, env)
    runs = pd.read_parquet(out / "runs.parquet")
    traces = pd.read_parquet(out / "traces.parquet")
    assert len(runs) == len(ref_runs) == 12
    pd.testing.assert_frame_equal(runs.drop(columns=WALL), ref_runs.drop(columns=WALL))
    ref_traces = pd.read_parquet(reference / "traces.parquet")
    pd.testing.assert_frame_equal(
        traces.drop(columns=["wall_s"]), ref_traces.drop(columns=["wall_s"])
    )
