"""Steps of the ``solid`` model along a path reuse the previous step's factorization."""

from __future__ import annotations

import numpy as np
import pytest

import idbench
from idbench_fem.fem import chords
from idbench_fem.models.solid import make_model

pytest.importorskip("gmsh")  # the organs' meshes are generated on first use


def _liver(steps=6):
    sc = idbench.Scenario("grasp-lift", {"body": "liver", "manipulation": "grasp-lift"})
    return make_model(idbench.ModelSpec("200", sc, steps, 4, {"reference": "200"}))


def _path(model, theta, k_last=None):
    u, out = model.reset(), []
    for k in range(1, (k_last or model.n_steps) + 1):
        u = model.step(theta, k, u)
        out.append(u)
    return out


def test_a_path_factors_less_and_equals_fresh_solves():
    theta = np.array([4000.0])
    model = _liver()
    f0 = model.factorizations
    path = _path(model, theta)
    reused, plain = model.factorizations - f0, 0
    for k, u in enumerate(path, start=1):
        prev = model.reset() if k == 1 else path[k - 2]
        fresh = _liver()  # no history: its plain Newton from the same state
        f1 = fresh.factorizations
        v = fresh.step(theta, k, prev)
        plain += fresh.factorizations - f1
        scale = np.abs(v).max()
        np.testing.assert_allclose(u, v, rtol=0, atol=1e-7 * scale)
        # and it meets the model's own residual test
        r = model.internal_force(theta, u) - model.external_force(k)
        tol = max(model.rtol * np.linalg.norm(model.external_force(k)), model.atol)
        assert np.linalg.norm(r) <= tol
    # plain Newton factors 3 times a step here; the path about half as often
    assert reused < 0.6 * plain


def test_same_numbers_on_a_fresh_model_and_after_other_runs():
    theta = np.array([4000.0])
    a = _path(_liver(), theta)
    used = _liver()
    _path(used, np.array([2500.0]), k_last=4)  # another run first, cut short
    used.step(theta, 3, used.reset())  # and a step out of any path
    b = _path(used, theta)
    for ua, ub in zip(a, b, strict=True):
        np.testing.assert_array_equal(ua, ub)


def test_a_step_not_continuing_the_last_one_is_plain_newton():
    theta = np.array([4000.0])
    model = _liver()
    path = _path(model, theta, k_last=3)
    f0 = model.factorizations
    # step 3 again from step 2's state: not the continuation of step 3
    v = model.step(theta, 3, path[1])
    assert model.factorizations > f0
    fresh = _liver()
    np.testing.assert_array_equal(v, fresh.step(theta, 3, path[1]))


def test_useful_chords_counts_the_chords_before_a_discarded_one():
    assert chords.useful_chords(["c", "x", "F", "c"]) == 1
    assert chords.useful_chords(["x", "F"]) == 0
    assert chords.useful_chords(["c", "c"]) is None  # converged by chords
    assert chords.useful_chords(["c", "F", "x"]) is None  # refactored first
    assert chords.useful_chords([]) is None


def test_a_path_step_skips_the_chord_that_stalled_on_the_step_before(monkeypatch):
    """On the liver the second chord of each step stalls (a soft mode the old
    tangent misses): the next step refactors after one chord instead."""
    theta = np.array([4000.0])

    def discarded(model):
        wasted = 0
        u = model.reset()
        for k in range(1, model.n_steps + 1):
            u = model.step(theta, k, u)
            wasted += model._last_path_step.record.count("x")
        return wasted, u

    learned, u_learned = discarded(_liver(8))
    monkeypatch.setattr(chords, "useful_chords", lambda record: None)
    blind, u_blind = discarded(_liver(8))
    assert blind >= 4  # the stall happens at (nearly) every step without the rule
    assert learned <= 1  # with it, at most the first time
    np.testing.assert_allclose(
        u_learned, u_blind, rtol=0, atol=1e-7 * np.abs(u_blind).max()
    )
