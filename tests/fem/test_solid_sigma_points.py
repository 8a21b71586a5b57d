"""Sigma points of p > 1 on organs: ``step_many``'s accelerated chords."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

import idbench
from idbench_fem.bodies.catalog import body_path
from idbench_fem.fem import batched, chords
from idbench_fem.models.solid import make_model

pytest.importorskip("gmsh")  # the organs' meshes are generated on first use

E = 4000.0
# RO-UKF-like sigma points of 4 slabs: the centre and +-40% along two mixes
SIGMA = E * np.array(
    [
        [1.0, 1.0, 1.0, 1.0],
        [1.4, 0.7, 1.2, 0.8],
        [0.6, 1.3, 0.8, 1.2],
        [1.2, 1.2, 0.6, 0.7],
        [0.8, 0.8, 1.4, 1.3],
    ]
)


def _slabs(folder: Path, p: int = 4) -> Path:
    """The shipped liver with ``p`` slabs along x as parameter regions."""
    src = body_path("liver")
    text = src.read_text().replace('"meshes/', f'"{src.parent}/meshes/')
    slabs = ", ".join(f"{{ slab = {{ index = {i}, count = {p} }} }}" for i in range(p))
    path = folder / f"liver-p{p}.toml"
    path.write_text(f"{text}\n[parameters]\nregions = [{slabs}]\n")
    return path


@pytest.fixture(autouse=True)
def accelerate_small_meshes(monkeypatch):
    """The tests' 200-node liver is below the size that accelerates: lower it."""
    monkeypatch.setattr(batched, "ACCELERATE_FROM_DOFS", 0)


@pytest.fixture(scope="module")
def body(tmp_path_factory):
    return _slabs(tmp_path_factory.mktemp("slabs"))


def _model(body, steps=5, **settings):
    load = {"body": str(body), "manipulation": "grasp-lift"}
    sc = idbench.Scenario("grasp-lift", load)
    return make_model(
        idbench.ModelSpec("200", sc, steps, 4, {"reference": "200", **settings})
    )


def _path(model, thetas, k_last=None):
    X = np.zeros((len(thetas), model.n_state))
    out = []
    for k in range(1, (k_last or model.n_steps) + 1):
        X = model.step_many(thetas, k, X)
        out.append(X)
    return out


def test_sigma_points_equal_fresh_newton_with_fewer_factorizations(body, monkeypatch):
    model = _model(body, steps=8)
    assert batched.accelerates(model, 4)
    path = _path(model, SIGMA)
    with monkeypatch.context() as m:  # the same calls with plain chords
        m.setattr(batched, "accelerates", lambda model, p: False)
        chords = _model(body, steps=8)
        _path(chords, SIGMA)
    for k in (1, 4, 8):
        X = path[k - 1]
        prev = np.zeros_like(X) if k == 1 else path[k - 2]
        f_ext = model.external_force(k)
        tol = max(model.rtol * np.linalg.norm(f_ext), model.atol)
        for i, theta in enumerate(SIGMA):
            fresh = _model(body, steps=8)  # no history: plain Newton from prev[i]
            v = fresh.step(theta, k, prev[i])
            atol = 1e-7 * np.abs(v).max()
            np.testing.assert_allclose(X[i], v, rtol=0, atol=atol)
            r = model.internal_force(theta, X[i]) - f_ext
            assert np.linalg.norm(r) <= tol
    # here 38 factorizations with the chords, 26 accelerated
    assert model.factorizations <= 0.75 * chords.factorizations


def test_same_numbers_on_a_fresh_model_and_after_other_runs(body):
    a = _path(_model(body), SIGMA)
    used = _model(body)
    _path(used, 0.8 * SIGMA[::-1], k_last=3)  # another run first, cut short
    used.step_many(SIGMA, 2, np.zeros((len(SIGMA), used.n_state)))  # out of path
    b = _path(used, SIGMA)
    for xa, xb in zip(a, b, strict=True):
        np.testing.assert_array_equal(xa, xb)


def test_the_beam_keeps_the_plain_chords(monkeypatch):
    def refuse(*args, **kwargs):
        raise AssertionError("accelerated chords on the beam")

    monkeypatch.setattr(chords, "accelerated_chords", refuse)
    reg = idbench.build_registry()
    spec = idbench.ModelSpec(mesh="6x2x2", scenario=reg.scenario("bend-y"), n_steps=3)
    beam = reg.model("svk-beam")(spec)
    assert not batched.accelerates(beam, 4)
    theta = np.array([[4000.0], [2500.0], [6000.0]])
    X = np.zeros((3, beam.n_state))
    for k in (1, 2, 3):
        X = beam.step_many(theta, k, X)
    assert beam.batch_stats.modified > 0  # chords ran, not the accelerated ones


def test_the_gate_keeps_plain_chords_for_p1_and_small_meshes(body, monkeypatch):
    model = _model(body)
    assert batched.accelerates(model, 4)  # the fixture's threshold 0
    assert not batched.accelerates(model, 1)
    monkeypatch.setattr(batched, "ACCELERATE_FROM_DOFS", model.assembler.n_free + 1)
    assert not batched.accelerates(model, 4)
