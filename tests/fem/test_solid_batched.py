"""Batched steps of the ``solid`` model: organs' sigma points share factorizations."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

import idbench
from idbench import Observation, Prior
from idbench.registry.testing import check_batch_model, check_model_settings
from idbench_fem.bodies.catalog import body_path
from idbench_fem.fem import predictions
from idbench_fem.models.solid import make_model
from idbench_fem.models.solid_settings import SolidSettings
from idbench_filters import RoUkf

pytest.importorskip("gmsh")  # the organs' meshes are generated on first use


def _organ(body, manipulation, steps=3, **settings):
    load = {"body": str(body), "manipulation": manipulation}
    sc = idbench.Scenario(manipulation, load)
    spec = idbench.ModelSpec("200", sc, steps, 4, {"reference": "200", **settings})
    return make_model(spec)


def _one_modulus_kidney(tmp_path: Path) -> Path:
    """The kidney without its [parameters]: one E, the tumour 4x that E."""
    text = body_path("kidney").read_text()
    text = text[: text.index("[parameters]")]
    path = tmp_path / "kidney-one-E.toml"
    path.write_text(text)
    return path


@pytest.mark.parametrize(
    ("body", "manipulation", "law", "thetas"),
    [
        ("liver", "grasp-lift", None, [[3000.0], [4000.0], [5500.0]]),
        ("kidney", "grasp-pole", None, [[6e3, 24e3], [4e3, 30e3], [9e3, 15e3]]),
        ("kidney", "grasp-pole", "svk", [[6000.0, 24000.0], [5000.0, 28000.0]]),
    ],
)
def test_step_many_equals_step(body, manipulation, law, thetas):
    model = _organ(body, manipulation, **({"law": law} if law else {}))
    check_batch_model(model, np.array(thetas), steps=2)
    assert model.batch_stats.calls > 0


def test_predictions_scale_the_regions_moduli(tmp_path, monkeypatch):
    """With one E and a tumour 4x stiffer, the sensitivity that predicts the
    sigma points is that of the body's moduli: nearby pairs settle at their
    prediction, as the full UKF's do (a sensitivity at uniform moduli misses
    the tolerance)."""
    model = _organ(_one_modulus_kidney(tmp_path), "grasp-pole", kernel="general")
    assert model.parameters.names == ("E",)
    assert set(np.round(model.unit_moduli, 9)) == {1.0, 4.0}
    u1 = model.step(np.array([6000.0]), 1, model.reset())
    thetas = 6000.0 * (1.0 + 2e-5 * np.linspace(-1.0, 1.0, 11))[:, None]
    states = np.tile(u1, (len(thetas), 1))

    def settled(m):
        before = m.batch_stats.converged_at_prediction
        out = m.step_many(thetas, 2, states)
        for theta, u in zip(thetas, out, strict=True):  # each meets step()'s test
            r = np.linalg.norm(m.internal_force(theta, u) - m.external_force(2))
            assert r <= m.rtol * np.linalg.norm(m.external_force(2)) * (1 + 1e-12)
        return m.batch_stats.converged_at_prediction - before

    assert settled(model) >= 8
    uniform = _organ(_one_modulus_kidney(tmp_path), "grasp-pole", kernel="general")
    monkeypatch.setattr(
        type(uniform), "unit_moduli", np.ones(uniform.assembler.n_elements)
    )  # what a model that ignored the tumour's factor would use
    assert settled(uniform) <= 2


@pytest.mark.parametrize(("law", "cubic"), [("neo-hookean", False), ("svk", True)])
def test_cubic_residuals_only_where_the_force_is_cubic(monkeypatch, law, cubic):
    """Many one-parameter predictions take the SVK cubic's shortcut; a
    neo-Hookean force is not polynomial, so they are assembled."""
    model = _organ("liver", "grasp-lift", law=law)
    assert model.force_is_cubic is cubic
    calls = []
    real = predictions.line_residuals
    monkeypatch.setattr(
        predictions, "line_residuals", lambda *a: calls.append(1) or real(*a)
    )
    r = 2 * predictions.POLYNOMIAL_ABOVE
    thetas = 4000.0 * (1.0 + 1e-3 * np.linspace(-1.0, 1.0, r))
    states = np.tile(model.reset(), (len(thetas), 1))
    out = model.step_many(thetas[:, None], 1, states)
    assert bool(calls) is cubic
    ref = model.step(thetas[:1], 1, model.reset())
    assert np.abs(out[0] - ref).max() <= 1e-6 * np.abs(ref).max()


def test_ro_ukf_with_a_helper_process_equals_one_process():
    estimates = []
    truth = np.array([6000.0, 24000.0])
    for processes in (1, 2):
        model = _organ("kidney", "grasp-pole", steps=3, processes=processes)
        u, obs = model.reset(), {}
        for k in range(1, 4):
            u = model.step(truth, k, u)
            obs[k] = Observation(values=model.observe(u), noise_std=1e-5, step=k)
        est = RoUkf()
        est.start(model, Prior((4000.0, 12000.0), (2000.0, 6000.0)))
        for k in range(1, 4):
            e = est.update(k, obs[k])
        estimates.append(e.mean)
        if processes == 2:
            assert model._helpers and model._helpers[0].calls >= 1
        model.close()
    np.testing.assert_allclose(estimates[1], estimates[0], rtol=1e-6)


def test_processes_is_an_execution_setting():
    check_model_settings(SolidSettings)
    assert SolidSettings(processes=2).identity() == SolidSettings().identity()
    for bad in (0, 1.5, True):
        with pytest.raises(ValueError, match=f"processes {bad!r}: need a whole"):
            SolidSettings(processes=bad)
