"""Loading MKL without pypardiso's import-time search of site-packages."""

from __future__ import annotations

import os
import subprocess
import sys

import pytest

from idbench_fem.fem import solver


def test_mkl_runtime_is_found_without_importing_pypardiso():
    pytest.importorskip("pypardiso")
    code = (
        "import sys; from idbench_fem.fem.solver import _mkl, _mkl_rt_path; "
        "lib = _mkl(); print(_mkl_rt_path()); "
        "assert 'pypardiso' not in sys.modules, 'pypardiso was imported'"
    )
    env = dict(os.environ)
    env.pop("PYPARDISO_MKL_RT", None)
    out = subprocess.run(
        [sys.executable, "-c", code], env=env, capture_output=True, text=True
    )
    assert out.returncode == 0, out.stderr
    assert "mkl_rt" in out.stdout


def test_environment_variable_wins(monkeypatch):
    monkeypatch.setenv("PYPARDISO_MKL_RT", "/some/where/libmkl_rt.so")
    assert solver._mkl_rt_path() == "/some/where/libmkl_rt.so"
