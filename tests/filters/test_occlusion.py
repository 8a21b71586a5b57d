"""Occluded observation entries (NaN) are the model and observation without them.

On the linear-Gaussian toy, every estimator given observations with some
entries NaN (a different set each step, one step all NaN) must give what it
gives on a model whose observation drops those entries at that step, fed the
observations without them (and no observation where all were NaN).
"""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest
from support.helpers import linear_data
from support.toymodels import SensitiveLinearToy

from idbench import Filter, MaskedModel, Observation, Prior
from idbench_filters import BatchLs, Enkf, Etkf, Lms, Rls, RoUkf, Ukf

SIGMA = 0.05
M, STEPS = 5, 6
HIDDEN = {1: [1], 2: [0, 3, 4], 3: list(range(M)), 5: [2]}  # step -> NaN entries
RTOL = 1e-11


def masks() -> dict[int, np.ndarray]:
    """The visible entries of each step's observation (all where not listed)."""
    out = {}
    for k in range(1, STEPS + 1):
        seen = np.ones(M, dtype=bool)
        seen[HIDDEN.get(k, [])] = False
        out[k] = seen
    return out


class Dropped(SensitiveLinearToy):
    """The toy whose observation at step k has only step k's visible entries.

    The step is the last one solved (the sequential filters observe the
    states of the step they just advanced to) or, with ``tagged``, appended
    to the state (batch least squares observes a whole path afterwards).
    """

    def __init__(self, seen: dict[int, np.ndarray], tagged: bool, **kw: Any) -> None:
        super().__init__(**kw)
        self.seen, self.tagged, self.k = seen, tagged, 0

    def reset(self) -> np.ndarray:
        return np.zeros(self.A.shape[0] + self.tagged)

    def step(self, theta, k, state, *, substeps=1):  # type: ignore[no-untyped-def]
        self.k = k
        u = super().step(theta, k, state, substeps=substeps)
        return np.append(u, float(k)) if self.tagged else u

    def step_of(self, state: np.ndarray) -> int:
        return round(float(state[-1])) if self.tagged else self.k

    def observe(self, state: np.ndarray) -> np.ndarray:
        u = state[:-1] if self.tagged else state
        k = self.step_of(state)
        return self.full(u) if k == 0 else self.full(u)[self.seen[k]]

    def full(self, u: np.ndarray) -> np.ndarray:
        return self.H @ u

    def sensitivity(self, theta, k, state):  # type: ignore[no-untyped-def]
        return super().sensitivity(theta, k, state)[self.seen[k]]


class Corrected(SensitiveLinearToy):
    """A corrected toy: observe adds mu, observation_cov is a fixed SPD Sigma."""

    def __init__(self, **kw: Any) -> None:
        super().__init__(**kw)
        rng = np.random.default_rng(7)
        m = self.H.shape[0]
        self.mu = 0.01 * rng.normal(size=m)
        a = rng.normal(size=(m, m))
        self.sigma = 1e-3 * (a @ a.T / m + np.eye(m))

    def observe(self, state: np.ndarray) -> np.ndarray:
        return super().observe(state) + self.mu

    def observation_cov(self, state: np.ndarray) -> np.ndarray:
        return self.sigma


class DroppedCorrected(Dropped):
    """:class:`Corrected` without each step's hidden entries."""

    def __init__(self, seen: dict[int, np.ndarray], tagged: bool, **kw: Any) -> None:
        super().__init__(seen, tagged, **kw)
        self.mu, self.sigma = (lambda c: (c.mu, c.sigma))(Corrected(**kw))

    def full(self, u: np.ndarray) -> np.ndarray:
        return self.H @ u + self.mu

    def observation_cov(self, state: np.ndarray) -> np.ndarray:
        seen = self.seen[self.step_of(state)]
        return self.sigma[np.ix_(seen, seen)]


def occluded(obs: dict[int, Observation]) -> dict[int, Observation]:
    """The observations with each step's hidden entries NaN."""
    out = {}
    for k, o in obs.items():
        y = np.array(o.values, dtype=float)
        y[HIDDEN.get(k, [])] = np.nan
        out[k] = Observation(y, o.noise_std, k)
    return out


def dropped(obs: dict[int, Observation]) -> dict[int, Observation]:
    """The observations without each step's hidden entries (none if all are)."""
    seen = masks()
    return {
        k: Observation(np.asarray(o.values)[seen[k]], o.noise_std, k)
        for k, o in obs.items()
        if seen[k].any()
    }


def run(est: Filter, model: Any, prior: Prior, obs: dict[int, Observation]):
    est.start(model, prior)
    out = []
    for k in range(1, STEPS + 1):
        e = est.update(k, obs.get(k))
        nu = None
        if k in obs and est.innovation is not None:
            nu = tuple(np.array(a, dtype=float) for a in est.innovation)
        out.append((e, nu))
    return out


FILTERS = {
    "ro-ukf": lambda c: RoUkf(transform="identity", correction=c),
    "ro-ukf-star": lambda c: RoUkf(
        transform="identity", sigma_points="star", correction=c
    ),
    "ukf": lambda c: Ukf(transform="identity", correction=c),
    "rls": lambda c: Rls(transform="identity", correction=c),
    "lms": lambda c: Lms(transform="identity", correction=c),
    "enkf": lambda c: Enkf(transform="identity", members=8, correction=c),
    "etkf": lambda c: Etkf(transform="identity", members=8, correction=c),
    "batch-ls-each": lambda c: BatchLs(
        transform="identity", refit="each", correction=c
    ),
    "batch-ls-end": lambda c: BatchLs(transform="identity", correction=c),
}


@pytest.mark.parametrize("correction", ["none", "approximation-error"])
@pytest.mark.parametrize("name", sorted(FILTERS))
def test_nan_entries_are_the_model_without_them(name: str, correction: str) -> None:
    kw = {"p": 2, "n": 4, "m": M, "n_steps": STEPS, "seed": 3}
    tagged = name.startswith("batch-ls")
    if correction == "none":
        full: Any = SensitiveLinearToy(**kw)
        reduced: Any = Dropped(masks(), tagged, **kw)
    else:
        full = Corrected(**kw)
        reduced = DroppedCorrected(masks(), tagged, **kw)
    prior = Prior((1.0, 0.5), (2.0, 1.5))
    obs = linear_data(full, np.array([3.0, -1.5]), 1, SIGMA)
    got = run(FILTERS[name](correction), full, prior, occluded(obs))
    want = run(FILTERS[name](correction), reduced, prior, dropped(obs))
    for k, ((g, g_nu), (w, w_nu)) in enumerate(zip(got, want, strict=True), start=1):
        assert np.all(np.isfinite(g.mean)), f"step {k}: {g.mean}"
        np.testing.assert_allclose(g.mean, w.mean, rtol=RTOL, err_msg=f"step {k}")
        np.testing.assert_allclose(g.std, w.std, rtol=RTOL, err_msg=f"step {k}")
        if k == 3:  # every entry hidden: no observation, no innovation of its own
            assert g_nu is None, f"step {k}: {g_nu}"
            continue
        assert (g_nu is None) == (w_nu is None), f"step {k}"
        if g_nu is not None and w_nu is not None:
            assert g_nu[0].shape == (int(masks()[k].sum()),)  # visible entries
            for a, b in zip(g_nu, w_nu, strict=True):
                np.testing.assert_allclose(a, b, rtol=RTOL, atol=1e-15)


def test_occlusion_changes_the_answer() -> None:
    """The masked run is not the run on the full observation (the test can fail)."""
    kw = {"p": 2, "n": 4, "m": M, "n_steps": STEPS, "seed": 3}
    model = SensitiveLinearToy(**kw)
    prior = Prior((1.0, 0.5), (2.0, 1.5))
    obs = linear_data(model, np.array([3.0, -1.5]), 1, SIGMA)
    masked = run(RoUkf(transform="identity"), model, prior, occluded(obs))[-1][0]
    full = run(RoUkf(transform="identity"), model, prior, obs)[-1][0]
    assert not np.allclose(masked.mean, full.mean, rtol=1e-6)


def test_masked_model_restricts_observe_sensitivity_and_sigma_only() -> None:
    full = Corrected(p=2, n=4, m=M, n_steps=STEPS, seed=3)
    seen = masks()[2]
    view = MaskedModel(full, seen)
    u = full.step(np.array([1.0, 2.0]), 2, full.reset())
    np.testing.assert_array_equal(view.observe(u), full.observe(u)[seen])
    np.testing.assert_array_equal(
        view.sensitivity(np.ones(2), 2, u), full.sensitivity(np.ones(2), 2, u)[seen]
    )
    np.testing.assert_array_equal(
        view.observation_cov(u), full.sigma[np.ix_(seen, seen)]
    )
    assert view.n_steps == full.n_steps and view.parameters is full.parameters
    assert view.step is not None and not hasattr(
        MaskedModel(SensitiveLinearToy(), seen), "observation_cov"
    )
