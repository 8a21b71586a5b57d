"""Every benchmark script runs (in its smallest mode) and prints its figures.

No timing is asserted (machines are noisy): this only keeps the scripts that
carry the speed targets working as the code under them changes.
"""

from __future__ import annotations

import importlib.util
import os
import subprocess
import sys
from pathlib import Path

import pytest

BENCH = Path(__file__).resolve().parents[2] / "benchmarks"
FELUPE = importlib.util.find_spec("felupe") is not None
GMSH = importlib.util.find_spec("gmsh")

CASES = [
    (["filters.py", "--quick", "--repeat", "1"], "x solve"),
    (["kernel.py", "--sizes", "100"], "tangent_data"),
    (["startup.py", "--repeat", "1"], "ms"),
    (["sweep.py", "--quick", "--repeat", "1"], "speedup / bound"),
    (["observe.py", "--quick", "--repeat", "1"], "ms per sigma point"),
    (["correction.py", "--quick", "--repeat", "1"], "corrected / uncorrected"),
    pytest.param(
        ["organs.py", "--quick", "--repeat", "1", "--only", "liver"],
        "fact/step",
        marks=pytest.mark.skipif(GMSH is None, reason="the organs' meshes need gmsh"),
    ),
    pytest.param(
        ["forward.py", "--sizes", "100"],
        "ratio",
        marks=pytest.mark.skipif(not FELUPE, reason="needs the bench extra (FElupe)"),
    ),
    pytest.param(
        ["solid.py", "--sizes", "100"],
        "solid",
        marks=pytest.mark.skipif(not FELUPE, reason="needs the bench extra (FElupe)"),
    ),
]


@pytest.mark.parametrize(("argv", "expect"), CASES)
def test_benchmark_runs(argv, expect, tmp_path):
    env = {**os.environ, "IDBENCH_CACHE_DIR": str(tmp_path / "cache")}
    env["MPLBACKEND"] = "Agg"
    done = subprocess.run(
        [sys.executable, str(BENCH / argv[0]), *argv[1:]],
        capture_output=True,
        text=True,
        env=env,
        timeout=300,
    )
    assert done.returncode == 0, done.stderr[-2000:]
    assert expect in done.stdout, done.stdout[-2000:]
