"""Small pieces several test files share: a tiny comparison, linear-toy data, a
registry with test plugins."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest

import idbench
from idbench import CompareConfig, Observation, Prior
from idbench.cli.commands import main
from support.toymodels import LinearToy

TRUTH, MODEL, STEPS = "12x3x3", "4x1x1", 5
"""The tiny comparison's truth mesh, model mesh and load steps."""


def tiny(**overrides: Any) -> CompareConfig:
    """One RLS run on the tiny beam (``overrides`` replace its settings)."""
    base: dict[str, Any] = {
        "truth_mesh": TRUTH,
        "meshes": (MODEL,),
        "steps": STEPS,
        "seeds": 1,
        "estimators": ("rls",),
    }
    return CompareConfig(**{**base, **overrides})


def registry_with(plugins: dict[str, object]) -> idbench.Registry:
    """The built-in plugins' registry with ``plugins`` (name: plugin object) added.

    Third-party entry points are not loaded; each call has a fresh plugin
    manager, so nothing needs unregistering.
    """
    pm = idbench.get_plugin_manager(autoload=False)
    for name, plugin in plugins.items():
        pm.register(plugin, name=name)
    return idbench.build_registry(pm)


def compare_into(folder: Path, *args: str) -> Path:
    """Run ``idbench compare ARGS -q`` into ``folder/out``; that folder.

    With its own truth cache ``folder/cache``: for module-scoped fixtures,
    which cannot use the per-test cache of conftest.
    """
    out = folder / "out"
    with pytest.MonkeyPatch.context() as mp:
        mp.setenv("IDBENCH_CACHE_DIR", str(folder / "cache"))
        assert main(["compare", *args, "--out", str(out), "-q"]) == 0
    return out


def linear_data(
    model: LinearToy, theta: np.ndarray, every: int, sigma: float, seed: int = 1
) -> dict[int, Observation]:
    """Observations H_k theta + noise (std ``sigma``) of every ``every``-th step."""
    rng = np.random.default_rng(seed)
    obs = {}
    for k in range(1, model.n_steps + 1):
        if k % every == 0:
            y = model.jac(k) @ theta + sigma * rng.normal(size=model.H.shape[0])
            obs[k] = Observation(values=y, noise_std=sigma, step=k)
    return obs


def linear_posteriors(
    model: LinearToy, prior: Prior, obs: dict[int, Observation], sigma: float
) -> list[tuple[np.ndarray, np.ndarray]]:
    """The exact Gaussian posterior (mean, covariance) of theta after each step."""
    info = np.diag(1.0 / np.asarray(prior.std) ** 2)
    rhs = info @ np.asarray(prior.mean)
    out = []
    for k in range(1, model.n_steps + 1):
        if k in obs:
            J = model.jac(k)
            info = info + J.T @ J / sigma**2
            rhs = rhs + J.T @ obs[k].values / sigma**2
        P = np.linalg.inv(info)
        out.append((P @ rhs, P))
    return out


def write_box_mesh(path, n_x: int, length: float, width: float, n_yz: int = 3) -> None:
    """A structured tet box mesh [0, length] x [0, width]^2 written to ``path``."""
    import meshio
    import numpy as np
    from skfem import MeshTet

    m = MeshTet.init_tensor(
        np.linspace(0, length, n_x),
        np.linspace(0, width, n_yz),
        np.linspace(0, width, n_yz),
    )
    meshio.write(path, meshio.Mesh(m.p.T, [("tetra", m.t.T)]))


SIGMA = 0.05
"""The noise std of the linear toy's data in the ensemble and posterior tests."""


def make_data(
    model: LinearToy, theta: np.ndarray, every: int, seed: int = 1
) -> dict[int, Observation]:
    """:func:`linear_data` with noise std :data:`SIGMA`."""
    return linear_data(model, theta, every, SIGMA, seed)
