"""The registered ``svk-beam`` model and its noise-free data, for estimator tests.

A test that needs the beam skips while no ``svk-beam`` model is registered.
"""

from __future__ import annotations

from functools import cache

import numpy as np
import pytest

import idbench
from idbench import ModelSpec, Observation

E_TRUE = 5000.0


@cache
def registry() -> idbench.Registry:
    return idbench.build_registry()


def beam(mesh: str, n_steps: int = 10, scenario: str = "bend-y", **kw):
    reg = registry()
    if "svk-beam" not in reg.models:
        pytest.skip("no 'svk-beam' model registered (plugin idbench_fem)")
    spec = ModelSpec(mesh=mesh, scenario=reg.scenario(scenario), n_steps=n_steps, **kw)
    return reg.model("svk-beam")(spec)


def observe_truth(model, theta, noise_std=0.0):
    u = model.reset()
    obs = {}
    for k in range(1, model.n_steps + 1):
        u = model.step(np.asarray(theta, dtype=float), k, u)
        obs[k] = Observation(values=model.observe(u), noise_std=noise_std, step=k)
    return obs
