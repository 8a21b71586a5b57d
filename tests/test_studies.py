"""Each study runs in --quick mode and shows its claim on one number."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import numpy as np
import pytest

STUDIES = Path(__file__).resolve().parent.parent / "studies"


def load(name: str):
    spec = importlib.util.spec_from_file_location(name, STUDIES / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


@pytest.fixture(autouse=True)
def _cache(tmp_path_factory, monkeypatch):
    monkeypatch.setenv("IDBENCH_CACHE_DIR", str(tmp_path_factory.getbasetemp() / "c"))


def test_fig2_identified_E_rises_with_resolution_and_stays_below_truth(tmp_path):
    table = load("fig2_stiffness_vs_resolution").compute(quick=True, out=tmp_path)
    ro = table[table["estimator"] == "ro-ukf"].sort_values("model_nodes")
    assert len(ro) == 3
    assert np.all(np.diff(ro["E"].to_numpy()) > 0)  # approaches E_true from below
    assert np.all(ro["ratio"] < 1.0)
