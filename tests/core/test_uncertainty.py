"""Uncertainty wiring: paired noise draws, run seeds, coverage/NEES/NIS columns.

Runs on the spring chain of ``test_report_models`` (k, one parameter, fast).
"""

from __future__ import annotations

import numpy as np
import pytest
from support.helpers import registry_with
from support.springs import SpringPlugin

from idbench.plan.config import CompareConfig
from idbench.run.compare import compare, runs_of
from idbench.run.session import Session


@pytest.fixture
def registry():
    return registry_with({"springs": SpringPlugin()})


def chain(**kw) -> CompareConfig:
    base = {
        "model": "spring-chain",
        "meshes": ("5",),
        "truth_mesh": "40",
        "estimators": ("rls",),
        "seeds": 1,
        "steps": 6,
        "obs_every": (1,),
        "noise": (1e-4,),
    }
    return CompareConfig(**{**base, **kw})


# --- common random numbers ----------------------------------------------------


def test_noise_draws_are_shared_across_noise_levels_spacing_meshes(registry):
    config = chain(
        noise=(1e-4, 1e-3), obs_every=(1, 2), meshes=("5", "20"),
        estimators=("rls", "ro-ukf"), seeds=2,
    )  # fmt: skip
    session = Session(registry)
    specs = runs_of(config, registry)
    truth = session.truth(specs[0]).observations

    def noise(spec):
        return [
            None if o is None else o.values - truth[k]
            for k, o in enumerate(session.observations(spec))
        ]

    by = {(s.mesh, s.estimator, s.noise, s.obs_every, s.seed): s for s in specs}
    base = noise(by[("5", "rls", 1e-4, 1, 0)])
    assert all(n is not None for n in base)
    # ten times the sigma: exactly ten times the noise, same draws
    tenfold = noise(by[("5", "rls", 1e-3, 1, 0)])
    for a, b in zip(base, tenfold, strict=True):
        np.testing.assert_allclose(b, 10 * a, rtol=1e-9, atol=0)
    # every second step: the same values at the shared steps, None between
    sparse = noise(by[("5", "rls", 1e-4, 2, 0)])
    for k, (a, b) in enumerate(zip(base, sparse, strict=True), start=1):
        if k % 2 == 0:
            np.testing.assert_array_equal(a, b)
        else:
            assert b is None
    # other estimators and meshes: the same stream
    for key in (("20", "rls", 1e-4, 1, 0), ("5", "ro-ukf", 1e-4, 1, 0)):
        for a, b in zip(base, noise(by[key]), strict=True):
            np.testing.assert_array_equal(a, b)
    # another seed: other draws
    other = noise(by[("5", "rls", 1e-4, 1, 1)])
    assert not np.allclose(base[0], other[0])


# --- run seeds reach estimators with a seed setting -----------------------------


def test_run_seed_reaches_the_ensemble_filter(registry, tmp_path):
    # noise 0: the seeds' data are identical, only the ensemble draws differ
    config = chain(estimators=("enkf",), seeds=2, noise=(0.0,))
    runs, _ = compare(config, tmp_path / "a", registry=registry)
    assert (runs["status"] == "ok").all(), runs["error"].tolist()
    k0, k1 = runs.sort_values("seed")["k_final"]
    assert k0 != k1  # the two seeds draw different ensembles
    again, _ = compare(config, tmp_path / "b", registry=registry)
    np.testing.assert_array_equal(
        again.sort_values("seed")["k_final"], runs.sort_values("seed")["k_final"]
    )
    # a seed the user sets wins over the run's
    fixed = chain(
        estimators=("enkf",), seeds=2, noise=(0.0,),
        estimator_settings={"enkf": {"seed": 7}},
    )  # fmt: skip
    same, _ = compare(fixed, tmp_path / "c", registry=registry)
    assert same["k_final"].nunique() == 1


# --- uncertainty columns --------------------------------------------------------


@pytest.fixture(scope="module")
def scored(tmp_path_factory):
    reg = registry_with({"springs": SpringPlugin()})
    config = chain(
        meshes=("5", "40"), estimators=("rls", "ro-ukf", "etkf", "batch-ls"),
        seeds=2, obs_every=(2,), noise=(1e-3,), posterior=True,
        posterior_settings={"points": 61},
    )  # fmt: skip
    runs, traces = compare(config, tmp_path_factory.mktemp("u"), registry=reg)
    assert (runs["status"] == "ok").all(), runs["error"].tolist()
    return runs, traces


def test_coverage_nees_crps_columns_follow_the_final_estimate(scored):
    runs, _ = scored
    z_true = (runs["k_final"] - runs["k_true"]) / runs["k_std_final"]
    z_ref = (runs["k_final"] - runs["k_ref"]) / runs["k_std_final"]
    np.testing.assert_allclose(runs["nees_true"], z_true**2, rtol=1e-12)
    np.testing.assert_allclose(runs["nees_ref"], z_ref**2, rtol=1e-12, atol=1e-12)
    for level, z in ((68, 0.994458), (95, 1.959964)):
        np.testing.assert_array_equal(
            runs[f"k_cover{level}_true"], (z_true.abs() <= z).astype(float)
        )
        np.testing.assert_array_equal(
            runs[f"k_cover{level}_ref"], (z_ref.abs() <= z).astype(float)
        )
    # the 5-node chain is stiffer: confidently wrong about k_true, right about
    # its own best constant; the truth's own chain covers k_true
    coarse, same = runs[runs["mesh"] == "5"], runs[runs["mesh"] == "40"]
    assert (coarse["k_cover95_true"] == 0).all()
    assert (coarse["k_cover95_ref"] == 1).all()
    assert same["k_cover95_true"].mean() >= 0.75  # 7 of 8 (one z = 2.0x)
    assert (runs["k_crps"] > 0).all()
    assert (coarse["k_crps"] > 5 * same["k_crps"].max()).all()


def test_reference_posterior_columns(scored):
    runs, _ = scored
    assert runs["posterior_converged"].all()
    # linear-Gaussian in 1/k: the posterior is close to the batch fit, N(k_ref, std)
    ls = runs[runs["estimator"] == "batch-ls"]
    np.testing.assert_allclose(ls["k_post_mean"], ls["k_ref"], rtol=2e-3)
    np.testing.assert_allclose(ls["k_post_std"], ls["k_std_final"], rtol=0.05)
    # one posterior per data set and mesh, shared by every estimator
    per = runs.groupby(["mesh", "seed"])["k_post_mean"].nunique()
    assert (per == 1).all()
    w1 = runs["w1_posterior"]
    assert np.isfinite(w1).all()
    assert (w1 >= 0.99 * (runs["k_final"] - runs["k_post_mean"]).abs()).all()
    assert (ls["w1_posterior"] < 0.1 * ls["k_post_std"]).all()


def test_nis_on_observed_steps_of_filters_that_expose_an_innovation(scored):
    runs, traces = scored
    est = traces["run_id"].map(runs.set_index("run_id")["estimator"])
    filt = traces[est.isin(["ro-ukf", "etkf", "rls"])]
    assert np.isfinite(filt.loc[filt["observed"], "nis"]).all()
    assert filt.loc[~filt["observed"], "nis"].isna().all()
    assert traces.loc[est.isin(["batch-ls"]), "nis"].isna().all()
    # consistent on the truth's own chain: mean NIS near m = 2 (2 markers x 1)
    same = filt[filt["run_id"].isin(runs.loc[runs["mesh"] == "40", "run_id"])]
    assert 0.3 < same.loc[same["observed"], "nis"].mean() < 6


def test_a_posterior_that_did_not_converge_gives_no_distance(registry, monkeypatch):
    import dataclasses

    import idbench.run.session

    real = idbench.run.session.reference_posterior

    def unconverged(*args, **kw):
        return dataclasses.replace(real(*args, **kw), converged=False)

    monkeypatch.setattr(idbench.run.session, "reference_posterior", unconverged)
    config = chain(posterior=True, posterior_settings={"points": 31})
    runs, _ = compare(config, registry=registry)
    assert runs["status"].tolist() == ["ok"]
    assert not runs["posterior_converged"].iloc[0]
    assert runs["w1_posterior"].isna().all()
    assert np.isfinite(runs["k_post_mean"]).all()


def test_without_posterior_no_posterior_columns(registry):
    runs, _ = compare(chain(), registry=registry)
    assert "posterior_converged" not in runs and "k_post_mean" not in runs
    assert {"k_cover68_true", "k_cover95_ref", "nees_true", "k_crps"} <= set(runs)


# --- bad input ------------------------------------------------------------------

BEAM = [
    "compare", "--truth-mesh", "20x3x3", "--meshes", "6x2x2", "--steps", "6",
    "--seeds", "1", "--dry-run",
]  # fmt: skip


@pytest.mark.parametrize(
    ("toml", "expected"),
    [
        ("[estimators.enkf]\nmembers = 1\n", "members = 1"),
        ("[estimators.etkf]\ninflation = 0.5\n", "inflation = 0.5"),
        (
            "posterior = true\n[posterior_settings]\nmax_solves = 100\n",
            "max_solves = 100",
        ),
        ("[posterior_settings]\npoints = 5\n", "points = 5"),
        ("[posterior_settings]\npoint = 51\n", "did you mean 'points'"),
    ],
)
def test_bad_uncertainty_settings_exit_2_with_one_line(
    toml, expected, tmp_path, capsys
):
    from idbench.cli.commands import main

    path = tmp_path / "x.toml"
    path.write_text(toml)
    assert main([*BEAM, "--estimators", "enkf,etkf", "--config", str(path)]) == 2
    captured = capsys.readouterr()
    err = captured.err.strip()
    assert "Traceback" not in captured.err + captured.out
    assert len(err.splitlines()) == 1 and err.startswith("idbench: error:"), err
    assert expected in err, err


def test_summary_shows_coverage_as_a_fraction_over_seeds_and_mean_nees(scored):
    from idbench.report.summary import summarise
    from idbench.report.text import summary_text

    runs, _ = scored
    summary = summarise(runs).set_index(["mesh", "estimator"])
    by = runs.groupby(["mesh", "estimator"])
    for col in ("k_cover68_true", "k_cover95_true", "k_cover95_ref", "nees_true"):
        np.testing.assert_allclose(summary[col], by[col].mean()[summary.index])
    assert set(summary["k_cover68_true"]) <= {0.0, 0.5, 1.0}  # two seeds
    text = summary_text(runs)
    assert "k 95% covers true" in text and "NEES vs true (mean)" in text


def test_results_of_an_older_version_without_posterior_settings_resume(tmp_path):
    from idbench.store.results import ResultsError, ResultStore

    old = {"seeds": 3, "noise": [1e-4]}  # a manifest of an older idbench
    ResultStore(tmp_path, old, {})
    ResultStore(tmp_path, {**old, "posterior": False, "posterior_settings": {}}, {})
    with pytest.raises(ResultsError, match="other settings"):
        ResultStore(tmp_path, {**old, "posterior": True, "posterior_settings": {}}, {})
