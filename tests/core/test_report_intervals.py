"""How sure the comparison is: intervals over seeds, paired differences."""

from __future__ import annotations

import io

import numpy as np
import pandas as pd
import pytest
from scipy import stats
from support.helpers import compare_into

from idbench.cli.commands import main
from idbench.report.intervals import excludes_zero, interval, method, seeds_needed
from idbench.report.paired import paired_differences, paired_text
from idbench.report.summary import summarise
from idbench.report.text import summary_text

SAMPLES = [
    [3251.2, 3257.9, 3262.4],
    [0.1, 0.4, 0.35, 0.9, 0.2],
    [-2.0, 5.0],
    list(np.random.default_rng(7).normal(10.0, 3.0, 12)),
]


@pytest.mark.parametrize("x", SAMPLES)
def test_t_interval_is_scipys(x):
    mean, lo, hi = interval(x, "E_final")
    a = np.asarray(x)
    want = stats.t.interval(0.95, a.size - 1, loc=a.mean(), scale=stats.sem(a))
    assert mean == pytest.approx(a.mean(), rel=1e-15)
    assert (lo, hi) == pytest.approx(want, rel=1e-12)


def test_bootstrap_and_binomial_intervals():
    x = np.random.default_rng(3).poisson(6.0, 40).astype(float)
    mean, lo, hi = interval(x, "settling_step")
    assert method("settling_step") == "bootstrap"
    assert interval(x, "settling_step") == (mean, lo, hi)  # seeded: reproducible
    ref = stats.bootstrap(
        (x,), np.mean, method="percentile", n_resamples=4000,
        rng=np.random.default_rng(11),
    ).confidence_interval  # fmt: skip
    width = ref.high - ref.low
    assert lo == pytest.approx(ref.low, abs=0.1 * width)
    assert hi == pytest.approx(ref.high, abs=0.1 * width)
    cover = [1.0, 0.0, 1.0, 1.0]
    ci = stats.binomtest(3, 4).proportion_ci(0.95, "exact")
    assert interval(cover, "E_cover95_true") == pytest.approx((0.75, ci.low, ci.high))
    assert interval([0.0, 0.0, 0.0], "E_cover95_true")[2] > 0.5  # not [0, 0]
    # a paired difference of shares is not a share: bootstrapped
    assert interval([-1.0, 0.0, 1.0], "E_cover95_true", paired=True)[1] >= -1.0


def test_one_value_has_no_interval():
    mean, lo, hi = interval([3257.0, np.nan], "E_final")
    assert mean == 3257.0 and np.isnan(lo) and np.isnan(hi)
    assert all(np.isnan(interval([], "E_final")))


def test_seeds_needed_is_the_smallest_n_that_reaches_the_half_width():
    for s, h in ((10.0, 1.0), (4.0, 3.0), (1.0, 0.01)):
        n = seeds_needed(s, h)
        assert stats.t.ppf(0.975, n - 1) * s / np.sqrt(n) <= h
        if n > 2:
            assert stats.t.ppf(0.975, n - 2) * s / np.sqrt(n - 1) > h
    assert seeds_needed(0.0, 1.0) == 2


def runs_table(values: dict[str, list[float]], mesh: str = "m") -> pd.DataFrame:
    """A runs table: one run per estimator and seed, E_final as given."""
    rows = []
    for est, xs in values.items():
        for seed, x in enumerate(xs):
            rows.append({
                "run_id": f"{est}{mesh}{seed}", "scenario": "bend-y", "estimator": est,
                "settings": "{}", "mesh": mesh, "model_nodes": 90.0, "seed": seed,
                "noise": 1e-4, "E_true": 5000.0, "status": "ok", "error": "",
                "E_final": x, "E_ref": 3000.0 + seed,
            })  # fmt: skip
    return pd.DataFrame(rows)


def test_summary_columns_and_cells_carry_the_intervals():
    runs = runs_table({"rls": SAMPLES[0], "lms": [1.0, 2.0, 3.0]})
    s = summarise(runs).set_index("estimator")
    x = SAMPLES[0]
    want = stats.t.interval(0.95, 2, loc=np.mean(x), scale=stats.sem(x))
    assert (s.at["rls", "E_final_lo"], s.at["rls", "E_final_hi"]) == pytest.approx(want)
    csv = pd.read_csv(io.StringIO(summary_text(runs, "csv")))
    assert {"E_final_lo", "E_final_hi", "E_ratio_lo", "E_ref_hi"} <= set(csv)
    text = summary_text(runs)
    half = (want[1] - want[0]) / 2
    assert f"3257 +- {half:.2g}" in text
    assert "95% t interval" in text
    assert "seeds for a 95% interval of +-1% on E_final" in text


def test_one_seed_rows_say_there_is_no_interval():
    runs = runs_table({"rls": [1.0, 2.0, 3.0], "lms": [4.0]})
    text = summary_text(runs)
    lms = next(line for line in text.splitlines() if " lms " in line)
    rls = next(line for line in text.splitlines() if " rls " in line)
    assert "(1 ok run: no interval)" in lms and "+-" not in lms
    assert "no interval" not in rls and "+-" in rls
    csv = pd.read_csv(io.StringIO(summary_text(runs, "csv"))).set_index("estimator")
    assert csv.loc["lms", ["E_final_lo", "E_final_hi"]].isna().all()
    assert "(1 ok run: no interval)" in summary_text(runs, "markdown")
    alone = summary_text(runs_table({"rls": [1.0], "lms": [4.0]}))
    assert "one ok run per row: no interval" in alone and "+-" not in alone


def test_pairing_by_seed_sees_a_difference_hidden_in_the_spread():
    """Per-seed offsets of +-300 shared by both estimators; b is a + 2 (+-0.5)."""
    rng = np.random.default_rng(5)
    offset = rng.normal(0.0, 300.0, 5)
    a = 3000.0 + offset
    b = a + 2.0 + rng.normal(0.0, 0.5, 5)
    runs = runs_table({"a": list(a), "b": list(b)})
    # unpaired: the two means' intervals overlap, Welch's interval holds 0
    s = summarise(runs).set_index("estimator")
    assert s.at["b", "E_final_lo"] < s.at["a", "E_final_hi"]
    welch = stats.ttest_ind(b, a, equal_var=False).confidence_interval(0.95)
    assert welch.low < 0 < welch.high
    # paired on the seed: the difference is 2 +- ~0.6, excluding 0
    p = paired_differences(runs, "a")
    row = p.table.set_index("other").loc["b"]
    assert row["pairs"] == 5
    assert row["E_final"] == pytest.approx(np.mean(b - a))
    want = stats.t.interval(0.95, 4, loc=np.mean(b - a), scale=stats.sem(b - a))
    assert (row["E_final_lo"], row["E_final_hi"]) == pytest.approx(want)
    assert excludes_zero(row["E_final_lo"], row["E_final_hi"])
    assert "E_ref" in p.identical  # the same batch fit for both: left out
    line = next(x for x in paired_text(p).splitlines() if x.startswith("bend-y"))
    assert line.rstrip().endswith("*")


def test_pairs_need_the_same_seed_and_every_other_axis():
    runs = pd.concat([
        runs_table({"a": [1.0, 2.0, 3.0], "b": [2.0, 3.0, 4.5]}, mesh="m"),
        runs_table({"a": [10.0, 20.0]}, mesh="n"),  # b did not run on n
    ])  # fmt: skip
    runs.loc[(runs["estimator"] == "b") & (runs["seed"] == 2), "status"] = "failed"
    p = paired_differences(runs, "a")
    assert p.table["pairs"].tolist() == [2]  # seed 2 failed for b; mesh n unpaired
    assert p.table["E_final"].tolist() == [1.0]
    by_mesh = paired_differences(runs, "m", by="mesh")
    assert by_mesh.table.set_index("other").at["n", "E_final"] == pytest.approx(13.5)
    with pytest.raises(ValueError, match="'c' did not run; ran: a, b"):
        paired_differences(runs, "c")


@pytest.fixture(scope="module")
def small(tmp_path_factory):
    return compare_into(
        tmp_path_factory.mktemp("versus"), "--truth-mesh", "12x3x3", "--meshes",
        "4x1x1,6x2x2", "--steps", "4", "--seeds", "3", "--estimators", "ro-ukf,rls",
    )  # fmt: skip


def test_report_versus_prints_and_writes_the_paired_table(small, capsys):
    assert main(["report", str(small), "--versus", "ro-ukf", "--versus-mesh",
                 "6x2x2"]) == 0  # fmt: skip
    out = capsys.readouterr().out
    assert "paired differences: each estimator minus ro-ukf" in out
    assert "paired differences: each mesh minus 6x2x2" in out
    by_est, by_mesh = (
        [line for line in part.splitlines() if line.startswith("bend-y")]
        for part in out.split("each mesh minus")
    )
    assert len(by_est) == 2 and all(" rls " in r for r in by_est)  # one a mesh
    assert len(by_mesh) == 2 and all(" 4x1x1 " in r for r in by_mesh)  # one a est.
    assert all(" 3 " in r for r in by_est + by_mesh)  # three seeds paired
    md = (small / "report.md").read_text()
    assert "## Paired differences against ro-ukf (estimator)" in md
    assert "## Paired differences against 6x2x2 (mesh)" in md
    assert "+-" in md.split("## Summary")[1]
    html = (small / "report.html").read_text()
    assert "Paired differences against ro-ukf" in html and " +- " in html


def test_report_versus_an_estimator_that_did_not_run(small, capsys):
    assert main(["report", str(small), "--versus", "ukf"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("idbench: error:") and "'ukf' did not run" in err
    assert "ro-ukf" in err and len(err.splitlines()) == 1


def test_seeds_help_says_how_many_seeds_a_precision_needs(capsys):
    with pytest.raises(SystemExit):
        main(["compare", "--help"])
    text = " ".join(capsys.readouterr().out.split())
    assert "n ~ (t s / h)^2" in text and "(default: 3; --quick: 1)" in text
