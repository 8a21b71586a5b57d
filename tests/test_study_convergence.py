"""The convergence study runs in --quick mode and measures what it claims to."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import numpy as np
import pytest

STUDIES = Path(__file__).resolve().parent.parent / "studies"
STUDY = STUDIES / "convergence_sparse_data.py"


def load():
    spec = importlib.util.spec_from_file_location("convergence_sparse_data", STUDY)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


@pytest.fixture(autouse=True)
def _cache(tmp_path_factory, monkeypatch):
    monkeypatch.setenv("IDBENCH_CACHE_DIR", str(tmp_path_factory.getbasetemp() / "c"))


def test_convergence_quick_settles_with_consistent_intervals(tmp_path):
    study = load()
    table = study.compute(quick=True, out=tmp_path)
    steps = study.QUICK["steps"]

    # every level of every axis has the four estimators on the main mesh
    for axis, levels in study.QUICK["axes"].items():
        for level in levels:
            here = table[(table["axis"] == axis) & np.isclose(table["level"], level)]
            assert set(study.ESTIMATORS) <= set(here["method"])
    # censored settling steps: 1..K+1, the bootstrap interval brackets the mean
    assert table["settle"].between(1, steps + 1).all()
    assert (table["settle_lo"] <= table["settle"] + 1e-12).all()
    assert (table["settle"] <= table["settle_hi"] + 1e-12).all()
    assert table["never"].between(0, 1).all()

    dense = table[(table["axis"] == "obs_every") & (table["level"] == 1)]
    settle = dense.set_index("method")["settle"]
    obs = dense.set_index("method")["settle_obs"]
    # batch LS refitted at every observation agrees with E_ref from the first one
    assert obs["batch-ls"] == 1
    # with data at every step the RO-UKF settles no later than LMS
    assert settle["ro-ukf"] <= settle["lms"]

    verdicts = study.verdict(table)
    assert len(verdicts) == sum(len(v) for v in study.QUICK["axes"].values())
