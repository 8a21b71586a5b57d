"""A filter that is not consistent with its data says so.

Each run's NIS, summed over its observed steps, is tested against the
two-sided 95% chi-square band of its degrees of freedom (the observed
values). On a linear-Gaussian toy, where the sum is exactly chi-square for a
truth drawn from the prior, a consistent filter is inside the band in about
95% of the seeds and one whose noise is 10x too small is outside in all; on
a coarse beam fed data far more precise than its discretization error the
sequential filters are flagged ``inconsistent`` in the row and the summary.
"""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest
from support.toymodels import SensitiveLinearToy

from idbench import Observation, Prior
from idbench.plan.config import CompareConfig
from idbench.registry.registry import build_registry
from idbench.report.text import summary_text
from idbench.run.compare import compare
from idbench.score.metrics import inconsistency, nis, nis_band

REG = build_registry()
PRIOR_MEAN, PRIOR_STD, SIGMA, STEPS, M = 2.0, 1.0, 0.05, 6, 3


def summed_nis(name: str, seed: int, shrink: float = 1.0) -> tuple[float, int]:
    """The summed NIS of one run on the toy, its truth drawn from the prior."""
    rng = np.random.default_rng(seed)
    model = SensitiveLinearToy(p=1, m=M, n_steps=STEPS, seed=7)
    theta = np.array([rng.normal(PRIOR_MEAN, PRIOR_STD)])
    est = REG.estimator(name)(transform="identity")
    est.start(model, Prior((PRIOR_MEAN,), (PRIOR_STD,)))
    total, dof = 0.0, 0
    for k in range(1, STEPS + 1):
        y = model.jac(k) @ theta + SIGMA * rng.standard_normal(M)
        est.update(k, Observation(y, SIGMA / shrink, k))
        v, S = est.innovation
        total += nis(v, S)
        dof += v.size
    return total, dof


@pytest.mark.parametrize("name", ["rls", "ro-ukf", "ukf"])
def test_the_summed_nis_of_a_consistent_filter_is_in_its_band_95pct(name):
    seeds = 300
    inside = 0
    for seed in range(seeds):
        total, dof = summed_nis(name, seed)
        assert dof == STEPS * M
        lo, hi = nis_band(dof)
        inside += lo <= total <= hi
        assert inconsistency(total, dof) == ("" if lo <= total <= hi else
                                             inconsistency(total, dof))  # fmt: skip
    # binomial(300, 0.95): sd 1.3%; 0.90..0.99 is more than 3 sd either side
    assert 0.90 <= inside / seeds <= 0.99, inside / seeds


@pytest.mark.parametrize("name", ["rls", "ro-ukf", "ukf"])
def test_a_filter_with_a_10x_too_small_noise_is_outside(name):
    for seed in range(50):
        total, dof = summed_nis(name, seed, shrink=10.0)
        assert total > nis_band(dof)[1], (seed, total)
        assert "inconsistent: its NIS lies above" in inconsistency(total, dof)


def test_the_band_is_chi_square_and_the_flag_names_the_side():
    lo, hi = nis_band(18)
    assert lo == pytest.approx(8.2307, abs=1e-3) and hi == pytest.approx(31.526, 1e-3)
    assert inconsistency(20.0, 18) == ""
    assert "below" in inconsistency(2.0, 18) and "too large" in inconsistency(2.0, 18)
    assert inconsistency(float("nan"), float("nan")) == ""  # no innovation: no say


def test_coarse_filters_fed_precise_data_are_flagged(tmp_path):
    est = ("ro-ukf", "enkf", "rls", "batch-ls")
    config = CompareConfig(
        truth_mesh="12x3x3", meshes=("4x1x1",), steps=4, seeds=1, estimators=est,
        noise=(1e-6,), obs_points=(4,), obs_every=(2,),
    )  # fmt: skip
    runs, _ = compare(config, tmp_path / "out")
    runs = runs.set_index("estimator")
    assert (runs["status"] == "ok").all()
    for name in ("ro-ukf", "enkf", "rls"):  # the sequential filters
        row = runs.loc[name]
        assert row["nis_dof"] == 2 * 12, name  # 2 observed steps x 4 markers x 3
        assert row["nis"] > nis_band(row["nis_dof"])[1], name
        assert "inconsistent: its NIS lies above" in row["warning"], name
    assert np.isnan(runs.loc["batch-ls", "nis"])  # no innovation, no say
    text = summary_text(pd.read_parquet(tmp_path / "out" / "runs.parquet"))
    assert "ro-ukf (1 run(s)): inconsistent" in text, text


def runs_table(**over) -> pd.DataFrame:
    """Three estimators on one data set (two seeds): ro-ukf far from the others."""
    rows = []
    for seed in (1, 2):
        for est, mean, std in (("ro-ukf", 1500.0, 20.0), ("batch-ls", 4800.0, 60.0),
                               ("ukf", 4750.0, 50.0)):  # fmt: skip
            rows.append({
                "run_id": f"{est}-{seed}", "scenario": "bend-y", "estimator": est,
                "settings": "{}", "mesh": "6x2x2", "model_nodes": 63, "seed": seed,
                "noise": 1e-4, "steps": 4, "E_true": 5000.0, "status": "ok",
                "warning": "", "E_final": mean + seed, "E_std_final": std,
                "E_ref": 4800.0, **over,
            })  # fmt: skip
    return pd.DataFrame(rows)


def test_the_summary_names_estimators_that_disagree_on_the_same_data():
    text = summary_text(runs_table())
    (line,) = [x for x in text.splitlines() if x.startswith("disagree:")]
    assert "batch-ls and ro-ukf on bend-y 6x2x2 (2 of 2 data sets, up to 52 std" in line
    assert "ro-ukf and ukf on bend-y 6x2x2" in line
    assert "batch-ls and ukf" not in line  # within their intervals
    # other data (another noise) are never compared
    apart = runs_table()
    apart.loc[apart["estimator"] == "ro-ukf", "noise"] = 1e-3
    assert "disagree:" not in summary_text(apart)


def test_the_report_says_a_flagged_interval_is_not_to_be_believed(tmp_path):
    from idbench.report.write import write_report

    runs = runs_table(warning="inconsistent: its NIS lies above the band")
    runs.to_parquet(tmp_path / "runs.parquet")
    traces = pd.DataFrame(
        [{"run_id": r, "step": k} for r in runs["run_id"] for k in range(1, 5)
         if not (r == "ukf-2" and k > 2)]
    )  # fmt: skip
    traces.to_parquet(tmp_path / "traces.parquet")
    write_report(tmp_path)
    md = (tmp_path / "report.md").read_text()
    html = (tmp_path / "report.html").read_text()
    for text in (md, html):
        assert "Caveats" in text
        assert "its intervals and their coverage are not to be believed" in text
        assert "disagree: on the same data" in text
        assert "traces incomplete: 1 ok run(s)" in text
        assert "ukf bend-y 6x2x2 seed 2 (2 of 4 steps)" in text
    # the flagged runs are listed once in report.md (the summary's flags)
    assert md.count("bend-y 6x2x2 ro-ukf (2 run(s)): inconsistent") == 1, md
