"""MCMC diagnostics on chains whose answer is known.

AR(1) chains x_t = phi x_{t-1} + e_t have the integrated autocorrelation time
tau = (1 + phi) / (1 - phi); iid chains of one distribution have R-hat -> 1;
chains at shifted means (or drifting within a chain) have R-hat >> 1, the
value following from the means. Where ArviZ is installed its split R-hat must
agree (it is not a dependency).
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy.signal import lfilter

from idbench import Observation, Prior
from idbench.core.interfaces import ParameterSpec
from idbench.estimate.posterior import PosteriorSettings
from idbench.estimate.posterior.diagnostics import autocorr_time, split_rhat
from idbench.estimate.posterior.target import LogPosterior


def ar1(phi: float, chains: int, n: int, p: int = 1, seed: int = 0) -> np.ndarray:
    """Stationary AR(1) chains (chains, n, p) of unit innovations."""
    rng = np.random.default_rng(seed)
    e = rng.standard_normal((chains, n + 1000, p))
    return lfilter([1.0], [1.0, -phi], e, axis=1)[:, 1000:]


@pytest.mark.parametrize("phi", [0.0, 0.5, 0.9])
def test_autocorr_time_of_ar1_chains_is_the_analytic_tau(phi):
    tau = autocorr_time(ar1(phi, chains=8, n=20_000, p=2))
    want = (1 + phi) / (1 - phi)
    # sd of the windowed estimate ~ tau sqrt(2 (2M + 1) / N), M ~ 5 tau: <= 5%
    np.testing.assert_allclose(tau, want, rtol=0.15)


def test_autocorr_time_is_sokals_windowed_sum_of_the_mean_autocorrelation():
    """The library's estimate is the documented one, computed here by its definition."""
    x = ar1(0.7, chains=3, n=400, seed=1)[:, :, 0]
    d = x - x.mean(axis=1, keepdims=True)
    n = x.shape[1]
    rho = np.mean(
        [[np.dot(r[: n - k], r[k:]) / np.dot(r, r) for k in range(n)] for r in d],
        axis=0,
    )
    taus = 2 * np.cumsum(rho) - 1
    m = int(np.argmax(np.arange(n) >= 5.0 * taus))
    assert autocorr_time(x[:, :, None])[0] == pytest.approx(taus[m], rel=1e-10)


def test_a_chain_that_never_moved_has_infinite_tau():
    chains = ar1(0.5, chains=4, n=500, p=2)
    chains[1, :, 0] = 0.3  # stuck on parameter 0 only
    tau = autocorr_time(chains)
    assert tau[0] == np.inf and np.isfinite(tau[1])


def test_split_rhat_of_iid_chains_is_one():
    chains = np.random.default_rng(2).standard_normal((4, 2000, 3))
    rhat = split_rhat(chains)
    assert np.all(np.abs(rhat - 1) < 0.01)


def test_split_rhat_of_chains_at_shifted_means():
    """Means 0, 1, 2, 3: R-hat^2 ~ (m - 1) / m + var(half means) (W = 1)."""
    rng = np.random.default_rng(3)
    shift = np.arange(4.0)
    chains = rng.standard_normal((4, 4000, 1)) + shift[:, None, None]
    m = 2000
    want = np.sqrt((m - 1) / m + np.var(np.repeat(shift, 2), ddof=1))  # 1.56
    assert split_rhat(chains)[0] == pytest.approx(want, rel=0.02)
    assert split_rhat(chains)[0] > 1.5


def test_split_rhat_sees_a_drift_within_each_chain():
    """Chains of one mean that jump halfway: only the split (half-chain) R-hat sees it.

    Half means 0, 0, 0, 0, 2, 2, 2, 2: var = 8/7, R-hat ~ 1.46.
    """
    rng = np.random.default_rng(4)
    chains = rng.standard_normal((4, 2000, 1))
    chains[:, 1000:] += 2.0
    m = 1000
    want = np.sqrt((m - 1) / m + np.var(np.repeat([0.0, 2.0], 4), ddof=1))
    assert split_rhat(chains)[0] == pytest.approx(want, rel=0.02)
    assert split_rhat(chains[:, :1000])[0] < 1.01


def test_split_rhat_drops_the_middle_draw_of_an_odd_chain():
    """A chain of 2m + 1 draws: R-hat of its first m and last m draws."""
    chains = ar1(0.5, chains=3, n=201, p=1, seed=7)
    chains[:, 100] = 1e6  # the middle draw: must not count
    even = np.concatenate([chains[:, :100], chains[:, 101:]], axis=1)
    assert split_rhat(chains)[0] == pytest.approx(split_rhat(even)[0], rel=1e-14)


def test_split_rhat_of_a_constant_half_is_infinite():
    chains = np.random.default_rng(5).standard_normal((2, 100, 1))
    chains[:, :] = 1.0
    assert split_rhat(chains)[0] == np.inf


@pytest.mark.parametrize("case", ["iid", "shifted", "ar1", "short"])
def test_split_rhat_is_arvizs(case):
    az = pytest.importorskip("arviz")
    rng = np.random.default_rng(6)
    chains = {
        "iid": rng.standard_normal((4, 1000, 2)),
        "shifted": rng.standard_normal((4, 1000, 2)) + np.arange(4.0)[:, None, None],
        "ar1": ar1(0.9, chains=4, n=1001, p=2),  # odd: the last draw is dropped
        "short": rng.standard_normal((2, 20, 2)),
    }[case]
    want = az.rhat(az.convert_to_dataset(chains), method="split")["x"].values
    np.testing.assert_allclose(split_rhat(chains), want, rtol=1e-12)


class _Bounded:
    """The least of a model that LogPosterior reads before it solves anything."""

    def __init__(self, lower: float) -> None:
        self.parameters = ParameterSpec(("E",), (lower,), (10.0,))
        self.n_steps = 2


@pytest.mark.parametrize(
    ("lower", "want"), [(0.0, -np.inf), (-1.0, -np.inf), (2.0, np.log(2.0))]
)
def test_log_posterior_bounds_in_xi(lower, want):
    """Under the log a lower bound <= 0 is no bound; the identity keeps it."""
    obs = [None, Observation(np.zeros(1), 1.0, 2)]
    prior = Prior((5.0,), (1.0,))
    lo, hi = LogPosterior(_Bounded(lower), prior, obs, PosteriorSettings()).xi_bounds()
    assert lo[0] == want and hi[0] == pytest.approx(np.log(10.0))
    identity = PosteriorSettings(transform="identity")
    lo, _ = LogPosterior(_Bounded(lower), prior, obs, identity).xi_bounds()
    assert lo[0] == lower
