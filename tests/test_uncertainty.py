"""Uncertainty wiring: paired noise draws, run seeds, coverage/NEES/NIS columns.

Runs on the spring chain of ``test_report_models`` (k, one parameter, fast).
"""

from __future__ import annotations

import numpy as np
import pytest
from test_report_models import SpringPlugin

import idbench
from idbench.config import CompareConfig
from idbench.session import Session
from idbench.sweep import compare, runs_of


@pytest.fixture
def registry():
    pm = idbench.get_plugin_manager(autoload=False)
    pm.register(SpringPlugin(), name="springs")
    yield idbench.build_registry(pm)
    pm.unregister(name="springs")


def chain(**kw) -> CompareConfig:
    base = {
        "model": "spring-chain",
        "meshes": ("5",),
        "truth_mesh": "40",
        "estimators": ("rls",),
        "seeds": 1,
        "steps": 6,
        "obs_every": (1,),
        "noise": (1e-4,),
    }
    return CompareConfig(**{**base, **kw})


# --- common random numbers ----------------------------------------------------


def test_noise_draws_are_shared_across_noise_levels_spacing_meshes(registry):
    config = chain(
        noise=(1e-4, 1e-3), obs_every=(1, 2), meshes=("5", "20"),
        estimators=("rls", "ro-ukf"), seeds=2,
    )  # fmt: skip
    session = Session(registry)
    specs = runs_of(config, registry)
    truth = session.truth(specs[0]).observations

    def noise(spec):
        return [
            None if o is None else o.values - truth[k]
            for k, o in enumerate(session.observations(spec))
        ]

    by = {(s.mesh, s.estimator, s.noise, s.obs_every, s.seed): s for s in specs}
    base = noise(by[("5", "rls", 1e-4, 1, 0)])
    assert all(n is not None for n in base)
    # ten times the sigma: exactly ten times the noise, same draws
    tenfold = noise(by[("5", "rls", 1e-3, 1, 0)])
    for a, b in zip(base, tenfold, strict=True):
        np.testing.assert_allclose(b, 10 * a, rtol=1e-9, atol=0)
    # every second step: the same values at the shared steps, None between
    sparse = noise(by[("5", "rls", 1e-4, 2, 0)])
    for k, (a, b) in enumerate(zip(base, sparse, strict=True), start=1):
        if k % 2 == 0:
            np.testing.assert_array_equal(a, b)
        else:
            assert b is None
    # other estimators and meshes: the same stream
    for key in (("20", "rls", 1e-4, 1, 0), ("5", "ro-ukf", 1e-4, 1, 0)):
        for a, b in zip(base, noise(by[key]), strict=True):
            np.testing.assert_array_equal(a, b)
    # another seed: other draws
    other = noise(by[("5", "rls", 1e-4, 1, 1)])
    assert not np.allclose(base[0], other[0])


# --- run seeds reach estimators with a seed setting -----------------------------


def test_run_seed_reaches_the_ensemble_filter(registry, tmp_path):
    # noise 0: the seeds' data are identical, only the ensemble draws differ
    config = chain(estimators=("enkf",), seeds=2, noise=(0.0,))
    runs, _ = compare(config, tmp_path / "a", registry=registry)
    assert (runs["status"] == "ok").all(), runs["error"].tolist()
    k0, k1 = runs.sort_values("seed")["k_final"]
    assert k0 != k1  # the two seeds draw different ensembles
    again, _ = compare(config, tmp_path / "b", registry=registry)
    np.testing.assert_array_equal(
        again.sort_values("seed")["k_final"], runs.sort_values("seed")["k_final"]
    )
    # a seed the user sets wins over the run's
    fixed = chain(
        estimators=("enkf",), seeds=2, noise=(0.0,),
        estimator_settings={"enkf": {"seed": 7}},
    )  # fmt: skip
    same, _ = compare(fixed, tmp_path / "c", registry=registry)
    assert same["k_final"].nunique() == 1
