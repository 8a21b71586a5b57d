"""A model's load against the truth's: stored per run, flagged in the summary.

A spring chain whose end load is "captured" less on a coarse chain (as a
selector captures less area on a coarse mesh of a curved body) reports its
load figures; each run stores the ratios to the truth model's, and the
summary lists the rows off by more than 2%.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest
from support.helpers import registry_with
from support.springs import SpringChain, SpringPlugin

import idbench
from idbench.plan.config import CompareConfig
from idbench.registry.testing import check_optional_members
from idbench.report.text import LOAD_TOLERANCE, load_lines, summary_text
from idbench.run.compare import compare


class LoadedChain(SpringChain):
    """A spring chain that captures 1 - 1/n of its load and knows it."""

    def load_figures(self) -> dict[str, float]:
        return {"resultant": self.load * (1.0 - 1.0 / self.n_nodes), "volume": 1.0}

    def describe(self) -> dict[str, Any]:
        return {**super().describe(), "model": "loaded-chain"}


class LoadedPlugin:
    @idbench.hookimpl
    def register_models(self, register):
        register("loaded-chain", LoadedChain, defaults=idbench.ModelDefaults(
            truth_mesh="200", meshes=("5", "100"), scenarios=("pull",),
            prior=(30.0, 20.0)))  # fmt: skip


@pytest.fixture
def registry():
    return registry_with({"springs": SpringPlugin(), "loaded": LoadedPlugin()})


def config(model: str) -> CompareConfig:
    return CompareConfig(
        model=model, meshes=("5", "100"), truth_mesh="200", estimators=("rls",),
        seeds=2, steps=4, obs_every=(1,), noise=(1e-4,),
    )  # fmt: skip


def test_each_run_stores_its_load_against_the_truths(registry, tmp_path):
    runs, _ = compare(config("loaded-chain"), tmp_path / "out", registry=registry)
    assert len(runs) == 4
    truth = 1.0 - 1.0 / 200
    for mesh, n in (("5", 5), ("100", 100)):
        rows = runs[runs["mesh"] == mesh]
        expected = (1.0 - 1.0 / n) / truth
        assert np.allclose(rows["load_resultant_ratio"], expected, rtol=1e-12)
        assert (rows["load_volume_ratio"] == 1.0).all()
    text = summary_text(runs)
    lines = text[text.index("load: ") :].splitlines()
    assert lines[0].startswith("load: 1 row(s) whose model's load differs from")
    assert "more than 2%" in lines[0]
    assert lines[1] == "  pull 5: resultant 0.804"  # volume 1: not shown
    assert len(lines) == 2  # mesh 100 is within 2% (0.995)
    assert "load: 1 row(s)" in summary_text(runs, "markdown")
    from idbench.report.write import write_report

    write_report(tmp_path / "out")
    report = (tmp_path / "out" / "report.md").read_text()
    assert "\n- pull 5: resultant 0.804\n" in report


def test_a_model_without_load_figures_has_no_load_columns(registry, tmp_path):
    runs, _ = compare(config("spring-chain"), tmp_path / "out", registry=registry)
    assert not [c for c in runs.columns if c.startswith("load_")]
    assert "load:" not in summary_text(runs)


def test_the_flag_is_beyond_two_percent_either_way():
    import pandas as pd

    runs = pd.DataFrame({
        "scenario": ["a", "a", "b", "c"], "mesh": ["1", "1", "2", "3"],
        "load_area_ratio": [1.03, 1.03, 0.985, np.nan],
        "load_mass_ratio": [1.0, 1.0, 0.97, 1.0],
    })  # fmt: skip
    assert LOAD_TOLERANCE == 0.02
    lines = load_lines(runs)
    assert lines[1:] == ["  a 1: area 1.03", "  b 2: mass 0.97"]


def test_check_model_checks_the_load_figures():
    model = LoadedChain(
        idbench.ModelSpec("5", idbench.Scenario("pull", {"force": 1.0}), n_steps=2)
    )
    state = model.step(np.array([30.0]), 1, model.reset())
    check_optional_members(model, state)
    model.load_figures = lambda: {"resultant": -1.0}  # type: ignore[method-assign]
    with pytest.raises(AssertionError, match="finite number >= 0"):
        check_optional_members(model, state)
    model.load_figures = lambda: {"a b": 1.0}  # type: ignore[method-assign]
    with pytest.raises(AssertionError, match="identifier"):
        check_optional_members(model, state)
