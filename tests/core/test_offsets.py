"""The approximation error of a run's own frames, linear in ln theta."""

from __future__ import annotations

import numpy as np
import pytest
from support.toymodels import SensitiveLinearToy

from idbench.calibrate.prior_mean import linear_offsets
from idbench.observe import kinds
from idbench.observe.observed_model import ObservedModel
from idbench.observe.offsets import Offsets

K, M = 3, 4
B = np.random.default_rng(0).normal(size=(K, M))  # delta's slope per step


class _Seen:
    """A seen model whose step k prediction is a known function of theta."""

    n_steps = K

    def __init__(self, delta) -> None:  # type: ignore[no-untyped-def]
        self.delta = delta

    def reset(self) -> np.ndarray:
        return np.zeros(2)

    def step(self, theta, k, state):  # type: ignore[no-untyped-def]
        return np.array([float(k), float(theta[0])])

    def observe(self, state):  # type: ignore[no-untyped-def]
        k, theta = int(state[0]), state[1]
        return 3.0 * theta * k + self.delta(k, np.log(theta))


def test_a_linear_discrepancy_is_held_exactly_and_leaves_nothing():
    fine = _Seen(lambda k, x: B[k - 1] * x + k)
    coarse = _Seen(lambda k, x: np.zeros(M))
    found = linear_offsets(fine, coarse, np.array([2000.0]), np.array([0.4]))
    for k in range(1, K + 1):
        np.testing.assert_allclose(found.mean[k - 1], B[k - 1] * np.log(2000.0) + k)
        np.testing.assert_allclose(found.slopes[k - 1][:, 0], B[k - 1], atol=1e-9)
        np.testing.assert_allclose(found.covs[k - 1], 0.0, atol=1e-18)
        theta = np.array([3100.0])  # anywhere on the line: the discrepancy itself
        np.testing.assert_allclose(
            found.at(k, theta), B[k - 1] * np.log(3100.0) + k, rtol=1e-9
        )


def test_what_the_line_leaves_is_its_covariance():
    s, x0 = 0.3, np.log(1000.0)
    fine = _Seen(lambda k, x: B[k - 1] * (x - x0) ** 2)  # curved: zero slope at x0
    coarse = _Seen(lambda k, x: np.zeros(M))
    found = linear_offsets(fine, coarse, np.array([1000.0]), np.array([s]))
    for k in range(1, K + 1):
        np.testing.assert_allclose(found.slopes[k - 1], 0.0, atol=1e-9)
        left = s**2 * B[k - 1]  # (delta+ + delta- - 2 delta0) / 2
        np.testing.assert_allclose(found.covs[k - 1], np.outer(left, left), rtol=1e-9)


def test_a_seen_model_carries_theta_for_a_linear_offset():
    model = SensitiveLinearToy(p=2, n_steps=K)
    frames = [kinds.Frame(k, {"markers": np.zeros(3)}) for k in range(1, K + 1)]
    seen = ObservedModel(model, kinds.Markers(), frames)
    n = model.reset().size
    rng = np.random.default_rng(1)
    mean = [rng.normal(size=3) for _ in range(K)]
    slopes = [rng.normal(size=(3, 2)) for _ in range(K)]
    covs = [np.eye(3) * k for k in range(1, K + 1)]
    xi0 = np.log([2.0, 3.0])
    seen.offsets = Offsets(mean, slopes, xi0, covs)
    assert seen.n_state == n + 2 + 1 and seen.reset().size == seen.n_state
    theta = np.array([2.5, 1.5])
    u = seen.step(theta, 2, seen.reset())
    expected = model.observe(u[:n]) + mean[1] + slopes[1] @ (np.log(theta) - xi0)
    np.testing.assert_allclose(seen.observe(u), expected)
    np.testing.assert_allclose(seen.observation_cov(u), covs[1])
    many = seen.step_many(np.stack([theta, 2 * theta]), 2, np.stack([seen.reset()] * 2))
    np.testing.assert_allclose(many[0], u)
    seen.offsets = Offsets(mean)  # constant: nothing carried, no covariance
    assert seen.n_state == n + 1
    assert not hasattr(seen, "observation_cov")
    with pytest.raises(ValueError, match="go together"):
        Offsets(mean, slopes)


def test_the_correction_of_a_cloud_moves_a_coarse_mesh_towards_the_tissue():
    from idbench import CompareConfig, compare

    def final(correction: str) -> float:
        config = CompareConfig(
            meshes=("6x2x2",), truth_mesh="12x3x3", steps=4, seeds=1,
            obs_every=(1,), estimators=("ro-ukf",), observe=("cloud",),
            observe_settings={"cloud": {"points": 60}},
            estimator_settings={"ro-ukf": {"correction": correction}},
            calibration={"mesh": "12x3x3"} if correction != "none" else {},
        )  # fmt: skip
        row = compare(config, None)[0].iloc[0]
        assert row["status"] == "ok", row["error"]
        return float(row["E_final"] / row["E_true"])

    plain, corrected = final("none"), final("approximation-error")
    assert plain < 0.75  # the coarse mesh's effective E
    assert abs(np.log(corrected)) < 0.5 * abs(np.log(plain))
