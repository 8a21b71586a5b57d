"""The smoothness prior of a parameter field: settings mean what they say."""

from __future__ import annotations

import numpy as np
import pytest

from idbench import FieldPrior, ParameterField


def chain(p: int, dx: float = 1.0, length: float = 10.0) -> ParameterField:
    """Cells of width dx on a line (unit cross-section), neighbours sharing area 1."""
    x = dx * np.arange(p, dtype=float)
    return ParameterField(
        x[:, None], np.full(p, dx),
        np.stack([np.arange(p - 1), np.arange(1, p)], axis=1), np.ones(p - 1),
        length,
    )  # fmt: skip


def grid3(n: int, length: float) -> ParameterField:
    """Unit cubes on an n x n x n grid, face neighbours."""
    idx = np.arange(n**3).reshape(n, n, n)
    x = np.stack(np.meshgrid(*[np.arange(n)] * 3, indexing="ij"), -1).reshape(-1, 3)
    pairs = [np.stack([a.ravel(), b.ravel()], 1) for a, b in (
        (idx[:-1], idx[1:]), (idx[:, :-1], idx[:, 1:]), (idx[:, :, :-1], idx[:, :, 1:])
    )]  # fmt: skip
    edges = np.vstack(pairs)
    return ParameterField(x.astype(float), np.ones(n**3), edges, np.ones(len(edges)),
                          length)  # fmt: skip


def test_every_marginal_std_is_the_setting_and_precision_inverts_cov():
    prior = FieldPrior.of(chain(40), np.zeros(40), 0.7)
    assert np.allclose(np.sqrt(np.diag(prior.cov)), 0.7, rtol=1e-12)
    assert np.allclose(prior.precision @ prior.cov, np.eye(40), atol=1e-8)
    x = np.linspace(-1, 1, 40)
    assert prior.energy(x) == pytest.approx(0.5 * x @ prior.precision @ x)
    assert np.allclose(prior.gradient(x), prior.precision @ x, atol=1e-8)


def test_correlation_length_is_where_correlation_falls_to_0_14():
    # 1-D, nu = 3/2: (1 + sqrt 12) exp(-sqrt 12) = 0.140 at distance rho,
    # away from the ends (the discrete chain: within 0.03)
    rho = 20.0
    C = FieldPrior.of(chain(400, 1.0, rho), np.zeros(400), 1.0).correlation
    for lag, want in ((rho, 0.140), (rho / 2, 0.48), (2 * rho, 0.009)):
        assert C[200, 200 + int(lag)] == pytest.approx(want, abs=0.03)
    # 3-D, nu = 1/2: exp(-2) = 0.135 at rho (an 11^3 grid of unit cells, rho = 4)
    C3 = FieldPrior.of(grid3(11, 4.0), np.zeros(11**3), 1.0).correlation
    centre = 5 * 121 + 5 * 11 + 5
    assert C3[centre, centre + 4] == pytest.approx(np.exp(-2), abs=0.05)
    assert C3[centre, centre + 2] == pytest.approx(np.exp(-1), abs=0.08)


def test_samples_have_the_prior_moments():
    prior = FieldPrior.of(chain(8, length=3.0), np.full(8, 2.0), 0.5)
    draws = prior.sample(np.random.default_rng(0), 40_000)
    assert np.allclose(draws.mean(axis=0), 2.0, atol=0.01)
    assert np.allclose(np.cov(draws, rowvar=False), prior.cov, atol=0.01)


def test_bad_fields_are_refused_in_one_line():
    with pytest.raises(ValueError, match="volumes"):
        ParameterField(np.zeros((2, 3)), np.array([1.0, 0.0]), np.zeros((0, 2)),
                       np.zeros(0), 1.0)  # fmt: skip
    with pytest.raises(ValueError, match="length"):
        ParameterField(np.zeros((1, 3)), np.ones(1), np.zeros((0, 2)), np.zeros(0), 0)
    with pytest.raises(ValueError, match="std"):
        FieldPrior.of(chain(3), np.zeros(3), -1.0)
