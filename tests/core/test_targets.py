"""Hidden targets: the TRE columns, the predicted target region, bodies' [targets]."""

from __future__ import annotations

import tomllib
from collections.abc import Callable
from typing import Any

import numpy as np
import pytest
from support.helpers import registry_with

import idbench
from idbench.plan.config import CompareConfig
from idbench.report.summary import summarise
from idbench.run.compare import compare, runs_of
from idbench.run.session import Session
from idbench.score import metrics, targets
from idbench.truth.simulate import simulate_path

TRUTH, MESH, STEPS = "20x3x3", "6x2x2", 4


def tiny(**kw: Any) -> CompareConfig:
    kw = {"truth_mesh": TRUTH, "meshes": (MESH,), "steps": STEPS, "seeds": 1, **kw}
    return CompareConfig(**kw)


def beam(mesh: str) -> Any:
    """The default model (the beam) of ``mesh``, built as a run builds it."""
    spec = runs_of(tiny(estimators=("rls",)))[0]
    return Session().model(spec, mesh, role="test")


def test_tre_equals_a_hand_computation_on_a_tiny_beam(tmp_path):
    runs, traces = compare(tiny(estimators=("batch-ls",)), tmp_path)
    assert list(runs.status) == ["ok"], runs.error.tolist()
    truth, model = beam(TRUTH), beam(MESH)
    true_states = simulate_path(truth, np.array([5000.0]))
    # batch-ls keeps no state: the harness steps the metrics model with each
    # step's estimate; do the same by hand
    u = model.reset()
    expected = []
    for k, E in enumerate(traces.sort_values("step")["E"], start=1):
        u = model.step(np.array([E]), k, u)
        d = model.targets(u)[0] - truth.targets(true_states[k - 1])[0]
        expected.append(1000.0 * float(np.sqrt(d @ d)))
    np.testing.assert_allclose(
        traces.sort_values("step")["tre_mm"], expected, rtol=1e-9
    )
    assert runs.tre_final_mm.iloc[0] == pytest.approx(expected[-1], rel=1e-12)
    assert expected[-1] > 0  # the coarse beam is not the truth
    assert runs.target_cov_method.iloc[0] == "jacobian"
    assert runs.tre_covered_final.iloc[0] in (0.0, 1.0)
    assert "tre_final_mm" in idbench.report.summary.summarise(runs).columns  # type: ignore[attr-defined]


def test_the_95_region_against_a_constructed_covariance():
    cov = np.diag([1.0, 4.0, 9.0])  # chi2_3(0.95) = 7.815
    assert metrics.ellipsoid_covers([1.0, 1.0, 1.0], cov) == 1.0  # 1.36
    assert metrics.ellipsoid_covers([3.0, 0.0, 0.0], cov) == 0.0  # 9
    assert metrics.ellipsoid_covers([0.0, 0.0, 8.3], cov) == 1.0  # 7.65
    assert metrics.ellipsoid_covers([0.0, 0.0, 8.5], cov) == 0.0  # 8.03
    rot = np.linalg.qr(np.arange(9.0).reshape(3, 3) + np.eye(3))[0]
    e = rot @ np.array([0.0, 0.0, 8.3])
    assert metrics.ellipsoid_covers(e, rot @ cov @ rot.T) == 1.0
    flat = np.diag([1.0, 0.0, 0.0])  # one parameter: a segment
    assert metrics.ellipsoid_covers([1.5, 0.0, 0.0], flat) == 1.0
    assert metrics.ellipsoid_covers([1.5, 1e-3, 0.0], flat) == 0.0
    assert np.isnan(metrics.ellipsoid_covers([np.nan, 0, 0], cov))


class Members:
    """An estimator that shows its ensemble (rows [u; xi])."""

    def __init__(self, rows: np.ndarray) -> None:
        self.ensemble = rows


def test_ensemble_covariance_is_the_members_target_covariance():
    model = beam(MESH)
    rng = np.random.default_rng(3)
    u = simulate_path(model, np.array([5000.0]))[-1]
    rows = u + 1e-4 * rng.standard_normal((8, u.size))
    est = Members(np.hstack([rows, np.ones((8, 1))]))  # a parameter column
    cov, how = targets.covariance(model, est, u.size, np.array([5000.0]), np.ones(1))
    moved = np.array([model.targets(r)[0] for r in rows])
    assert how == "ensemble"
    np.testing.assert_allclose(cov[0], np.cov(moved.T), rtol=1e-12)


def test_jacobian_covariance_follows_the_parameter_std():
    model = beam(MESH)
    theta = np.array([5000.0])
    c1, how = targets.covariance(
        model, object(), model.n_state, theta, np.array([10.0])
    )
    c2, _ = targets.covariance(model, object(), model.n_state, theta, np.array([20.0]))
    assert how == "jacobian"
    np.testing.assert_allclose(c2, 4 * c1, rtol=1e-9)
    assert np.linalg.matrix_rank(c1[0], tol=1e-12 * np.abs(c1).max()) == 1
    nan, _ = targets.covariance(
        model, object(), model.n_state, theta, np.full(1, np.nan)
    )
    assert np.isnan(nan).all()


class Spring:
    """A model without targets (a linear chain)."""

    def __init__(self, n_steps: int) -> None:
        self.n_steps = n_steps
        self.parameters = idbench.ParameterSpec(("E",), (1.0,), (1e4,), (300.0,))

    def reset(self) -> np.ndarray:
        return np.zeros(3)

    def step(self, theta, k, state, *, substeps=1):  # type: ignore[no-untyped-def]
        return (k / self.n_steps) * np.array([1.0, 2.0, 3.0]) / float(theta[0])

    def observe(self, state: np.ndarray) -> np.ndarray:
        return state.copy()

    def grid(self, state: np.ndarray) -> np.ndarray:
        return state.reshape(1, 3)

    def cost(self) -> idbench.Cost:
        return idbench.Cost()

    def describe(self) -> dict[str, Any]:
        return {"model": "spring"}


class SpringPlugin:
    @idbench.hookimpl
    def register_models(self, register: Callable[..., None]) -> None:
        register("spring", lambda spec: Spring(spec.n_steps))


def test_a_model_without_targets_gives_no_tre_columns(tmp_path):
    registry = registry_with({"spring": SpringPlugin()})
    config = CompareConfig(
        model="spring", truth_mesh="t", meshes=("m",), scenarios=("bend-y",),
        estimators=("rls", "enkf"), steps=4, seeds=1, prior=(200.0, 100.0),
    )  # fmt: skip
    runs, traces = compare(config, tmp_path, registry=registry)
    assert set(runs.status) == {"ok"}, runs.error.tolist()
    assert not [c for c in runs.columns if "tre" in c or "target" in c]
    assert "tre_mm" not in traces.columns
    summary = summarise(runs)
    assert "tre_final_mm" not in summary.columns


def test_body_targets_parse_a_point_and_a_list_and_refuse_a_bad_one():
    from idbench_fem.bodies.description import parse_body

    base = tomllib.loads((idbench_examples() / "kidney" / "body.toml").read_text())
    body = parse_body(base, "kidney.toml")
    assert dict(body.targets)["tumour"] == (0.02, 0.003, 0.0)
    base["targets"] = {"a": [0.0, 0.0, 0.0], "v": [[1.0, 2.0, 3.0], [4.0, 5.0, 6.0]]}
    names = [n for n, _ in parse_body(base, "b.toml").targets]
    assert names == ["a", "v[0]", "v[1]"]
    base["targets"] = {"a": [0.0, 0.0]}
    with pytest.raises(ValueError, match=r"\[targets\] a = \[0.0, 0.0\]: need three"):
        parse_body(base, "b.toml")


def idbench_examples() -> Any:
    from pathlib import Path

    return Path(__file__).resolve().parents[2] / "examples"


def inside(ellipsoid: Any, p: np.ndarray) -> float:
    """The ellipsoid's level at p: < 1 inside."""
    centre, axes = ellipsoid
    return float(np.sum(((p - np.array(centre)) / np.array(axes)) ** 2))


def test_example_targets_lie_well_inside_their_bodies():
    """Kidney: inside the bean, out of the hilum notch; liver: inside a lobe."""
    from idbench_fem.bodies import geometry as g
    from idbench_fem.bodies.catalog import get_body

    kidney = get_body(str(idbench_examples() / "kidney" / "body.toml"))
    for _, p in kidney.targets:
        assert inside(g.KIDNEY_ELLIPSOID, np.array(p)) < 0.8
        assert inside(g.KIDNEY_NOTCH, np.array(p)) > 1.2
    centre, _ = g.KIDNEY_INCLUSION
    assert dict(kidney.targets)["tumour"] == tuple(centre)
    liver = get_body(str(idbench_examples() / "liver" / "body.toml"))
    assert len(liver.targets) >= 3
    for _, p in liver.targets:
        assert min(inside(e, np.array(p)) for e in g.LIVER_ELLIPSOIDS) < 0.8
