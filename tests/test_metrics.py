"""The metrics of DESIGN.md section 5: shape error, settling step, observations."""

from __future__ import annotations

import numpy as np
import pytest

from idbench import metrics


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
