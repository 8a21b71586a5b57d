"""The metrics of docs/design.md section 5: shape error, settling step, observations."""

from __future__ import annotations

import numpy as np
import pytest

from idbench.score import metrics


@pytest.fixture(autouse=True)
def _cache_dir(tmp_path, monkeypatch):
    monkeypatch.setenv("IDBENCH_CACHE_DIR", str(tmp_path / "cache"))


# --- shape_error --------------------------------------------------------------


def test_shape_error_sum_and_mean_of_norms():
    truth = np.array([[0.0, 0.0, 0.0], [1.0, 1.0, 1.0], [0.0, -2.0, 0.0]])
    # differences (3,4,0), (0,0,0), (1,2,2): norms 5, 0, 3
    model = truth + np.array([[3.0, 4.0, 0.0], [0.0, 0.0, 0.0], [1.0, 2.0, 2.0]])
    total, mean = metrics.shape_error(model, truth)
    assert total == pytest.approx(8.0)
    assert mean == pytest.approx(8.0 / 3.0)
    assert isinstance(total, float) and isinstance(mean, float)


def test_shape_error_is_symmetric_and_zero_for_equal_grids():
    rng = np.random.default_rng(0)
    a, b = rng.normal(size=(10, 3)), rng.normal(size=(10, 3))
    assert metrics.shape_error(a, b) == pytest.approx(metrics.shape_error(b, a))
    assert metrics.shape_error(a, a) == (0.0, 0.0)


def test_shape_error_accepts_lists():
    total, mean = metrics.shape_error([[0, 0, 1], [0, 2, 0]], [[0, 0, 0], [0, 0, 0]])
    assert (total, mean) == pytest.approx((3.0, 1.5))


@pytest.mark.parametrize(
    "shape_a, shape_b", [((4, 3), (5, 3)), ((4, 3), (4, 2)), ((4, 3), (12,))]
)
def test_shape_error_shape_mismatch_raises(shape_a, shape_b):
    with pytest.raises(ValueError, match="grid shapes differ"):
        metrics.shape_error(np.zeros(shape_a), np.zeros(shape_b))


# --- settling_step ------------------------------------------------------------


def test_settles_at_step_one():
    assert metrics.settling_step([10.2, 9.9, 10.0, 10.01], [10.0]) == 1


def test_settles_late():
    # steps 1 and 2 outside the 5 % band, step 3 (3 % off) and after inside
    assert metrics.settling_step([1.0, 2.0, 9.7, 10.2, 10.0], [10.0]) == 3


def test_settles_on_last_step():
    assert metrics.settling_step([1.0, 2.0, 3.0, 10.0], [10.0]) == 4


def test_leaving_the_band_again_moves_the_settling_step():
    # inside at steps 1-2, outside at 3, inside from 4 on
    assert metrics.settling_step([10.0, 10.0, 12.0, 10.1, 10.0], [10.0]) == 4


def test_never_settles():
    assert metrics.settling_step([1.0, 2.0, 3.0], [10.0]) is None


def test_settled_then_left_at_the_end_is_none():
    assert metrics.settling_step([10.0, 10.0, 10.0, 20.0], [10.0]) is None


def test_column_shape_equals_flat_shape():
    flat = [1.0, 2.0, 9.7, 10.2, 10.0]
    column = np.array(flat).reshape(-1, 1)
    assert metrics.settling_step(column, np.array([10.0])) == 3
    assert metrics.settling_step(flat, 10.0) == 3


def test_two_parameters_use_the_worst():
    ref = [10.0, 20.0]
    est = np.array(
        [
            [10.0, 20.0],  # both inside
            [10.0, 30.0],  # second 50 % off
            [10.2, 20.5],  # both inside
            [10.0, 20.0],
        ]
    )
    assert metrics.settling_step(est, ref) == 3
    # the first parameter alone would have settled at step 1
    assert metrics.settling_step(est[:, :1], ref[:1]) == 1
    # a late first parameter decides when the second is good throughout
    est2 = np.array([[5.0, 20.0], [9.0, 20.0], [10.4, 20.0], [10.0, 20.0]])
    assert metrics.settling_step(est2, ref) == 3


def test_band_is_exactly_five_percent_inclusive():
    assert metrics.SETTLING_TOLERANCE == 0.05
    assert metrics.settling_step([105.0, 95.0, 105.0], [100.0]) == 1
    assert metrics.settling_step([106.0, 105.0], [100.0]) == 2
    assert metrics.settling_step([100.0, 105.1], [100.0]) is None
    assert metrics.settling_step([100.0, 94.9], [100.0]) is None


def test_custom_tolerance():
    assert metrics.settling_step([8.0, 9.0, 10.0], [10.0], tol=0.1) == 2
    assert metrics.settling_step([8.0, 9.0, 10.0], [10.0], tol=0.2) == 1


def test_non_finite_estimates_or_reference():
    assert metrics.settling_step([np.nan, 10.0], [10.0]) == 2
    assert metrics.settling_step([10.0, np.nan], [10.0]) is None
    assert metrics.settling_step([10.0, 10.0], [np.nan]) is None
    assert metrics.settling_step([10.0, 10.0], [0.0]) is None


def test_settling_returns_python_int():
    step = metrics.settling_step(np.array([1.0, 10.0]), np.array([10.0]))
    assert step == 2 and type(step) is int


# --- observations_used --------------------------------------------------------


@pytest.mark.parametrize(
    "step, every, expected",
    [
        (None, 1, None),
        (None, 3, None),
        (1, 1, 1),
        (8, 1, 8),
        (7, 2, 3),
        (8, 2, 4),
        (2, 3, 0),
        (6, 3, 2),
    ],
)
def test_observations_used(step, every, expected):
    assert metrics.observations_used(step, every) == expected


# --- uncertainty: coverage, NEES, CRPS, Wasserstein-1, NIS -----------------------


@pytest.mark.parametrize("level", [0.68, 0.95])
def test_coverage_matches_monte_carlo(level):
    """Truths drawn from the estimate's own Gaussian are covered at ``level``."""
    rng = np.random.default_rng(7)
    n = 40_000
    mean, std = np.array([3.0, -2.0]), np.array([0.5, 2.0])
    truths = mean + std * rng.standard_normal((n, 2))
    hits = np.array([metrics.coverage(mean, std, t, level) for t in truths[:4000]])
    frac = hits.mean(axis=0)
    se = np.sqrt(level * (1 - level) / 4000)
    np.testing.assert_allclose(frac, level, atol=4 * se)
    # the same with a broadcast over many truths at once (vectorised call)
    frac = metrics.coverage(mean[0], std[0], truths[:, 0], level).mean()
    assert abs(frac - level) < 4 * np.sqrt(level * (1 - level) / n)


def test_coverage_edges_and_bad_input():
    assert metrics.coverage([1.0], [1.0], [1.0 + 1.959], 0.95)[0] == 1.0
    assert metrics.coverage([1.0], [1.0], [1.0 + 1.961], 0.95)[0] == 0.0
    assert metrics.coverage([1.0], [1.0], [1.995], 0.68)[0] == 0.0  # z = 0.9945
    out = metrics.coverage([1.0, 2.0, 3.0], [np.nan, 1.0, 0.0], [1.0, 2.0, 3.0], 0.68)
    assert np.isnan(out[0]) and out[1] == 1.0 and out[2] == 1.0
    for bad in (0.0, 1.0, 68):
        with pytest.raises(ValueError, match=f"level = {bad!r}"):
            metrics.coverage([1.0], [1.0], [1.0], bad)


def test_nees_is_squared_z_and_chi_squared_on_average():
    assert metrics.nees([5.0], [2.0], [1.0]) == pytest.approx(4.0)
    assert metrics.nees([5.0, 0.0], [2.0, 0.5], [1.0, 1.0]) == pytest.approx(8.0)
    assert metrics.nees([1.0], [0.0], [1.0]) == 0.0
    assert metrics.nees([1.5], [0.0], [1.0]) == np.inf
    assert np.isnan(metrics.nees([1.0], [np.nan], [1.0]))
    rng = np.random.default_rng(3)
    std = np.array([1.0, 10.0, 0.1])
    vals = [
        metrics.nees(std * rng.standard_normal(3), std, np.zeros(3))
        for _ in range(5000)
    ]
    assert np.mean(vals) == pytest.approx(3.0, abs=4 * np.sqrt(6 / 5000))


@pytest.mark.parametrize(
    ("mean", "std", "value"), [(0.0, 1.0, 0.3), (10.0, 3.0, 2.0), (-1.0, 0.01, -1.0)]
)
def test_crps_gaussian_matches_numerical_integration(mean, std, value):
    from scipy import integrate, stats

    F = stats.norm(mean, std).cdf
    lo, hi = mean - 12 * std, mean + 12 * std
    left, _ = integrate.quad(lambda x: F(x) ** 2, min(lo, value - 1), value, limit=200)
    right, _ = integrate.quad(
        lambda x: (1 - F(x)) ** 2, value, max(hi, value + 1), limit=200
    )
    got = metrics.crps_gaussian([mean], [std], [value])
    np.testing.assert_allclose(got, [left + right], rtol=1e-7)


def test_crps_gaussian_limits():
    # a point estimate scores its absolute error; a perfect centre scores
    # sigma (sqrt 2 - 1) / sqrt(pi)
    np.testing.assert_allclose(metrics.crps_gaussian([2.0], [0.0], [5.0]), [3.0])
    np.testing.assert_allclose(
        metrics.crps_gaussian([0.0], [2.0], [0.0]),
        [2 * (np.sqrt(2) - 1) / np.sqrt(np.pi)],
    )
    assert np.isnan(metrics.crps_gaussian([0.0], [-1.0], [0.0])[0])


def test_wasserstein_between_shifted_gaussians_is_the_shift():
    from scipy import stats

    x = np.linspace(-10, 14, 4001)
    density = stats.norm(2.0, 1.5).pdf(x)
    assert metrics.wasserstein_to_grid(0.5, 1.5, x, density) == pytest.approx(
        1.5, rel=1e-5
    )
    # unnormalised density, and a Gaussian mostly outside the grid (closed-form tails)
    assert metrics.wasserstein_to_grid(-20.0, 1.5, x, 7 * density) == pytest.approx(
        22.0, rel=1e-5
    )
    assert metrics.wasserstein_to_grid(2.0, 1.5, x, density) == pytest.approx(
        0.0, abs=1e-5
    )


def test_wasserstein_matches_scipy_on_samples():
    """A skewed gridded density against a narrow Gaussian, vs samples of both."""
    from scipy import stats

    rng = np.random.default_rng(11)
    post = stats.lognorm(s=0.3, scale=5.0)
    x = np.linspace(0.5, 25.0, 3001)
    got = metrics.wasserstein_to_grid(4.0, 0.2, x, post.pdf(x))
    n = 200_000
    a = post.rvs(size=n, random_state=rng)
    b = 4.0 + 0.2 * rng.standard_normal(n)
    want = stats.wasserstein_distance(a, b)
    assert got == pytest.approx(want, rel=0.02)
    # a point estimate
    got0 = metrics.wasserstein_to_grid(4.0, 0.0, x, post.pdf(x))
    assert got0 == pytest.approx(np.mean(np.abs(a - 4.0)), rel=0.02)
    assert metrics.wasserstein_to_grid(30.0, 0.0, x, post.pdf(x)) == pytest.approx(
        np.mean(30.0 - a), rel=0.01
    )


def test_wasserstein_bad_grid():
    with pytest.raises(ValueError, match="grid must increase"):
        metrics.wasserstein_to_grid(0.0, 1.0, [0.0, 0.0, 1.0], [1.0, 1.0, 1.0])
    with pytest.raises(ValueError, match="equal length"):
        metrics.wasserstein_to_grid(0.0, 1.0, [0.0, 1.0], [1.0])
    assert np.isnan(metrics.wasserstein_to_grid(np.nan, 1.0, [0.0, 1.0], [1.0, 1.0]))


def test_nis_is_chi_squared_on_average():
    rng = np.random.default_rng(5)
    B = rng.normal(size=(4, 4))
    S = B @ B.T + 0.1 * np.eye(4)
    C = np.linalg.cholesky(S)
    vals = [metrics.nis(C @ rng.standard_normal(4), S) for _ in range(5000)]
    assert np.mean(vals) == pytest.approx(4.0, abs=4 * np.sqrt(8 / 5000))
    assert metrics.nis([2.0], [[4.0]]) == pytest.approx(1.0)
    assert metrics.nis([2.0, 1.0], [4.0, 1.0]) == pytest.approx(2.0)
    assert np.isnan(metrics.nis([1.0, 1.0], np.zeros((2, 2))))
    with pytest.raises(ValueError, match="differ"):
        metrics.nis([1.0, 1.0], np.eye(3))
