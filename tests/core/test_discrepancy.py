"""The approximation-error calibration and the corrected estimators."""

from __future__ import annotations

from dataclasses import replace
from typing import Any

import numpy as np
import pytest

from idbench import (
    ConfigError,
    DiscrepancyModel,
    ModelFailure,
    ModelSpec,
    Observation,
    Prior,
)
from idbench.calibrate.corrected import CorrectedModel
from idbench.calibrate.design import CalibrationSettings, scaling_holds
from idbench.calibrate.discrepancy import Discrepancy
from idbench.calibrate.fit import fit_discrepancy
from idbench.core.capabilities import present
from idbench.plan.config import CompareConfig
from idbench.registry.registry import build_registry
from idbench.registry.testing import check_model
from idbench.run.compare import compare
from idbench.truth.cache import cache_dir

REG = build_registry()
BEAM = REG.model("svk-beam")
PRIOR = Prior((2500.0,), (2500.0,))
SMALL = CalibrationSettings(scaled_steps=12)


def _spec(mesh: str = "6x2x2", scenario: str = "bend-y", steps: int = 4) -> ModelSpec:
    return ModelSpec(mesh=mesh, scenario=REG.scenario(scenario), n_steps=steps)


def _calibration(scenarios: tuple[str, ...] = ("bend-y",)) -> Discrepancy:
    sc = [REG.scenario(n) for n in scenarios]
    return fit_discrepancy(BEAM, _spec(), "9x2x2", sc, PRIOR, SMALL)


def test_load_scaling_detected_on_the_beam_and_refused_when_declared_false():
    model = BEAM(_spec())
    assert scaling_holds(model)
    model.load_scaling = False  # a model may declare it does not hold
    assert not scaling_holds(model)


def test_calibration_cost_and_cache_with_a_digest(caplog, tmp_path, monkeypatch):
    # a cache of its own: the session's may hold other tests' calibrations
    monkeypatch.setenv("IDBENCH_CACHE_DIR", str(tmp_path / "c"))
    first = _calibration()
    # one fine path of scaled_steps steps per scenario: 12 / K = 3 paths
    assert first.cost == pytest.approx(12 / 4)
    assert first.info["load_scaling"] is True
    files = sorted(cache_dir().glob("discrepancy-*.npz"))
    assert len(files) == 1
    again = _calibration()
    np.testing.assert_array_equal(again.w_obs, first.w_obs)
    # an altered entry is recomputed, not trusted
    data = dict(np.load(files[0], allow_pickle=False))
    data["w_obs"] = data["w_obs"] + 1.0
    np.savez(files[0], **data)
    with caplog.at_level("WARNING"):
        third = _calibration()
    assert "digest" in caplog.text
    np.testing.assert_allclose(third.w_obs, first.w_obs)


def test_the_correction_moves_the_coarse_observation_towards_the_fine_one():
    disc = _calibration()
    theta = np.array([3000.0])
    coarse, fine = BEAM(_spec()), BEAM(_spec("9x2x2"))
    u_c, u_f = coarse.reset(), fine.reset()
    for k in range(1, 5):
        u_c, u_f = coarse.step(theta, k, u_c), fine.step(theta, k, u_f)
    wrapped = CorrectedModel(coarse, disc)
    before = np.linalg.norm(coarse.observe(u_c) - fine.observe(u_f))
    after = np.linalg.norm(wrapped.observe(u_c) - fine.observe(u_f))
    assert after < 0.05 * before
    grid_before = np.linalg.norm(coarse.grid(u_c) - fine.grid(u_f))
    grid_after = np.linalg.norm(wrapped.grid(u_c) - fine.grid(u_f))
    assert grid_after < 0.2 * grid_before
    cov = wrapped.observation_cov(u_c)
    assert np.all(np.linalg.eigvalsh(cov) >= -1e-18)


def test_the_corrected_model_passes_the_model_checks():
    check_model(CorrectedModel(BEAM(_spec()), _calibration()), np.array([3000.0]))


def test_the_corrected_model_has_the_coarse_models_optional_members_only():
    coarse = BEAM(_spec())
    wrapped = CorrectedModel(coarse, _calibration())
    own = {"observation_cov", "grid_cov", "targets_cov", "extrapolated"}
    assert isinstance(wrapped, DiscrepancyModel)  # own: the DiscrepancyModel's
    assert present(wrapped).keys() == present(coarse).keys() | own
    assert present(wrapped)["surface"] == coarse.surface  # the coarse model's own
    assert present(wrapped)["sensitivity"] != coarse.sensitivity  # corrected
    assert not hasattr(wrapped, "settings")  # no proxy: the rest is wrapped.coarse's

    class Bare:  # the protocol and no optional member
        parameters, n_steps = coarse.parameters, coarse.n_steps
        reset, step, observe = coarse.reset, coarse.step, coarse.observe
        grid, cost, describe = coarse.grid, coarse.cost, coarse.describe

    assert present(CorrectedModel(Bare(), _calibration())).keys() == own


def _zero(disc: Discrepancy) -> Discrepancy:
    zero = np.zeros_like
    return replace(disc, w_obs=zero(disc.w_obs), w_grid=zero(disc.w_grid),
                   cov_unit=zero(disc.cov_unit))  # fmt: skip


@pytest.mark.parametrize("name", ["ro-ukf", "etkf", "rls", "batch-ls", "enkf", "ukf"])
def test_a_zero_correction_gives_the_uncorrected_estimate(name):
    """The matrix path (R + Sigma) with Sigma = 0, mu = 0 is the scalar one."""
    cls = REG.estimator(name)
    model = BEAM(_spec())
    theta = np.array([4000.0])
    u, obs = model.reset(), []
    for k in range(1, 5):
        u = model.step(theta, k, u)
        obs.append(Observation(model.observe(u), 1e-4, k))
    out = []
    for est, m in ((cls(), model),
                   (cls(correction="approximation-error"),
                    CorrectedModel(model, _zero(_calibration())))):  # fmt: skip
        est.start(m, PRIOR)
        for k, o in enumerate(obs, start=1):
            e = est.update(k, o)
        out.append((e.mean, e.std))
    np.testing.assert_allclose(out[1][0], out[0][0], rtol=1e-7)
    np.testing.assert_allclose(out[1][1], out[0][1], rtol=1e-5)


def test_bad_settings_are_one_line():
    with pytest.raises(ValueError, match="correction = 'yes' is not allowed"):
        REG.estimator("ro-ukf")(correction="yes")
    est = REG.estimator("rls")(correction="approximation-error")
    with pytest.raises(ValueError, match="needs a corrected model"):
        est.start(BEAM(_spec()), PRIOR)
    with pytest.raises(ValueError, match="features = 'cubic'"):
        CalibrationSettings(features="cubic")
    config = CompareConfig(
        scenarios=("bend-y",), meshes=("6x2x2",), truth_mesh="9x2x2",
        estimators=("rls",), seeds=1, steps=4,
        estimator_settings={"rls": {"correction": "approximation-error"}},
        calibration={"draws": 0},
    )  # fmt: skip
    with pytest.raises(ConfigError, match="calibration: draws = 0: need an integer"):
        compare(config, None)  # refused before any run
    unknown = replace(config, calibration={"scenarios": ["bend-q"]})
    with pytest.raises(ConfigError, match="bend-q"):
        compare(unknown, None)
    with pytest.raises(ConfigError, match="calibration"):
        CompareConfig(calibration=["mesh"])  # type: ignore[arg-type]


def test_compare_with_the_correction_covers_the_true_value():
    """Uncorrected: confidently wrong about E_true; corrected: it holds it."""
    est = ("ro-ukf", "batch-ls")
    common = dict(scenarios=("bend-y",), meshes=("6x2x2",), truth_mesh="9x2x2",
                  estimators=est, seeds=2, steps=4)  # fmt: skip
    plain, _ = compare(CompareConfig(**common), None)
    fixed, _ = compare(CompareConfig(
        **common, calibration={"scaled_steps": 12},
        estimator_settings={e: {"correction": "approximation-error"} for e in est},
    ), None)  # fmt: skip
    assert (plain["status"] == "ok").all() and (fixed["status"] == "ok").all()
    assert plain["E_cover95_true"].mean() == 0
    assert fixed["E_cover95_true"].mean() > plain["E_cover95_true"].mean()
    # (two observations: the RO-UKF is still 5% off, batch LS within 1%)
    assert fixed["E_relerr_true"].abs().max() < 0.06
    assert plain["E_relerr_true"].abs().min() > 0.09
    # the effective value is still the uncorrected fit, the mesh's answer
    np.testing.assert_allclose(fixed["E_ref"], plain["E_ref"])
    assert (fixed["calibration_cost"] == 3.0).all()
    assert set(fixed["run_id"]).isdisjoint(plain["run_id"])


def test_a_fine_path_that_fails_at_high_load_keeps_the_states_it_reached(caplog):
    """Beyond what the fine mesh bears, the calibration uses what it reached."""
    calls = {"fine": 0}

    def factory(spec: ModelSpec):
        model = BEAM(spec)
        if spec.mesh != "9x2x2":
            return model
        step = model.step

        def failing(theta, k, state, *, substeps=1):
            calls["fine"] += 1
            if k > 8:
                raise ModelFailure("inverted element", step=k)
            return step(theta, k, state, substeps=substeps)

        model.step = failing
        return model

    sc = [REG.scenario("bend-y")]
    settings = replace(SMALL, quantile=0.1)  # a path no other test cached whole
    with caplog.at_level("WARNING"):
        disc = fit_discrepancy(
            factory, _spec(), "9x2x2", sc, PRIOR, settings, cache=False
        )
    assert "up to step 8 of 12" in caplog.text
    assert disc.info["samples"] == 8
    assert disc.cost == pytest.approx(8 / 4)
    assert len(list(cache_dir().glob("reached-*.npz"))) == 1
    before = calls["fine"]
    fit_discrepancy(factory, _spec(), "9x2x2", sc, PRIOR, settings, cache=False)
    assert calls["fine"] == before  # the reached states came from the cache


def test_a_correction_with_another_observation_model_is_planned(tmp_path, capsys):
    """A cloud's correction is taken on each run's frames (see test_offsets.py)."""
    from idbench.cli.commands import main

    toml = tmp_path / "c.toml"
    toml.write_text('[estimators.ro-ukf]\ncorrection = "approximation-error"\n')
    argv = ["compare", "--truth-mesh", "12x3x3", "--meshes", "4x1x1", "--steps", "3",
            "--seeds", "1", "--estimators", "ro-ukf", "--observe", "cloud",
            "--config", str(toml), "--dry-run"]  # fmt: skip
    assert main(argv) == 0, capsys.readouterr().err


LIVER_DESIGN = ("cal-grasp-a", "cal-grasp-b", "cal-grasp-c")


def _liver_compare(design: tuple[str, ...] | None) -> Any:
    """RO-UKF on a tiny liver (150 nodes against 600), grasp-lift, 6 steps."""
    from pathlib import Path

    from idbench import Scenario

    body = str(Path(__file__).resolve().parents[2] / "examples/liver/calibration.toml")
    reg = REG.with_scenarios(
        [Scenario(n, {"body": body, "manipulation": n}) for n in LIVER_DESIGN],
        "test",
    )
    on = {"correction": "approximation-error"}
    settings = {} if design is None else {"ro-ukf": on}
    config = CompareConfig(
        scenarios=("grasp-lift",), meshes=("150",), truth_mesh="600",
        estimators=("ro-ukf",), seeds=1, steps=6, obs_points=(8,), obs_every=(2,),
        noise=(1e-4,), prior=(2000.0, 2000.0), model="solid",
        model_settings={"solid": {"body": "liver", "reference": "600"}},
        estimator_settings=settings,
        calibration={"quantile": 0.25, "scaled_steps": 12,
                     "scenarios": list(design or ())},
    )  # fmt: skip
    runs, _ = compare(config, None, registry=reg)
    return runs


def test_on_the_liver_a_design_of_other_grasps_gives_the_tissue_e():
    """Calibrated on grasps in three other directions (not grasp-lift's)."""
    plain = _liver_compare(None)
    fixed = _liver_compare(LIVER_DESIGN)
    assert (plain["status"] == "ok").all() and (fixed["status"] == "ok").all()
    assert plain["E_cover95_true"].mean() == 0
    assert fixed["E_cover95_true"].mean() == 1
    assert fixed["E_relerr_true"].abs().max() < 0.1
    assert plain["E_relerr_true"].abs().min() > 0.1
    assert (fixed["calibration_cost"] == 3 * 12 / 6).all()
    # the predictive uncertainty of the grid and of the hidden targets
    row = fixed.iloc[0]
    assert row["grid_std_final_mm"] > row["grid_disc_std_final_mm"] > 0
    assert 0 <= fixed["grid_covered_final"].iloc[0] <= 1
    assert "grid_covered_final" not in plain
    assert fixed["tre_final_mm"].iloc[0] < plain["tre_final_mm"].iloc[0]


def test_the_corrected_grid_and_targets_carry_the_discrepancy_and_its_covariance():
    """The targets' and grid's mean discrepancy and covariance at a load state."""
    from pathlib import Path

    from idbench import Scenario
    from idbench.truth.simulate import simulate_truth

    solid = REG.model("solid")
    body = str(Path(__file__).resolve().parents[2] / "examples/liver/calibration.toml")
    grasp = Scenario("cal-grasp-a", {"body": body, "manipulation": "cal-grasp-a"})
    coarse = ModelSpec(mesh="150", scenario=grasp, n_steps=4,
                       settings={"body": "liver", "reference": "600"})  # fmt: skip
    settings = CalibrationSettings(quantile=0.25, scaled_steps=8)
    prior = Prior((2000.0,), (2000.0,))
    disc = fit_discrepancy(solid, coarse, "600", [grasp], prior, settings)
    model = solid(coarse)
    fixed = CorrectedModel(model, disc)
    fine = simulate_truth(solid(replace(coarse, mesh="600")), np.array([3000.0]))
    state = model.reset()
    for k in range(1, 5):
        state = model.step(np.array([3000.0]), k, state)
    true_t, true_g = fine.targets[-1], fine.grid[-1]
    err = lambda a, b: float(np.linalg.norm(np.asarray(a) - b))  # noqa: E731
    assert err(fixed.targets(state), true_t) < 0.5 * err(model.targets(state), true_t)
    assert err(fixed.grid(state), true_g) < 0.5 * err(model.grid(state), true_g)
    tc, gc = fixed.targets_cov(state), fixed.grid_cov(state)
    assert tc.shape == (len(true_t), 3, 3) and gc.shape == (len(true_g), 3, 3)
    for c in (tc, gc):
        assert np.all(np.linalg.eigvalsh(c) >= -1e-18)
        assert np.all(np.trace(c, axis1=1, axis2=2) > 0)
