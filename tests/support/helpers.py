"""Small pieces several test files share: a tiny comparison, linear-toy data, a
registry with test plugins."""

from __future__ import annotations

import subprocess
import sys
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


def run_fresh_python(code: str, timeout: float) -> None:
    """Run ``code`` in a new interpreter; assert it exits 0 (else its stderr)."""
    proc = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, timeout=timeout
    )
    assert proc.returncode == 0, proc.stderr


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


ORGAN_AXES = (60.0, 40.0, 30.0)
"""Semi-axes (mm) of the synthetic organ surface: an ellipsoid."""


def ellipsoid_surface(level: int = 2, axes=ORGAN_AXES):  # type: ignore[no-untyped-def]
    """An ellipsoid triangulated from a subdivided icosahedron: (V, 3), (T, 3).

    ``level`` 2: 162 vertices and 320 triangles, outward normals; jittered
    slightly (seeded) so that no two triangles are symmetric images.
    """
    import numpy as np

    t = (1 + 5**0.5) / 2
    v = np.array([[-1, t, 0], [1, t, 0], [-1, -t, 0], [1, -t, 0], [0, -1, t],
                  [0, 1, t], [0, -1, -t], [0, 1, -t], [t, 0, -1], [t, 0, 1],
                  [-t, 0, -1], [-t, 0, 1]], dtype=float)  # fmt: skip
    f = np.array([[0, 11, 5], [0, 5, 1], [0, 1, 7], [0, 7, 10], [0, 10, 11],
                  [1, 5, 9], [5, 11, 4], [11, 10, 2], [10, 7, 6], [7, 1, 8],
                  [3, 9, 4], [3, 4, 2], [3, 2, 6], [3, 6, 8], [3, 8, 9],
                  [4, 9, 5], [2, 4, 11], [6, 2, 10], [8, 6, 7], [9, 8, 1]])  # fmt: skip
    v /= np.linalg.norm(v, axis=1)[:, None]
    for _ in range(level):
        e = np.sort(np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]]), axis=1)
        edges, inverse = np.unique(e, axis=0, return_inverse=True)
        mid = v[edges].mean(axis=1)
        mid /= np.linalg.norm(mid, axis=1)[:, None]
        m = inverse.reshape(3, -1).T + len(v)
        v = np.vstack([v, mid])
        a, b, c = f.T
        ab, bc, ca = m.T
        f = np.vstack([np.c_[a, ab, ca], np.c_[b, bc, ab], np.c_[c, ca, bc],
                       np.c_[ab, bc, ca]])  # fmt: skip
    rng = np.random.default_rng(7)
    v = v * (1 + 0.003 * rng.standard_normal((len(v), 1)))
    return v * np.asarray(axes, dtype=float), f


def write_surface(path, points, triangles) -> None:  # type: ignore[no-untyped-def]
    """Write a triangulated surface (STL, OBJ or PLY by the suffix) with meshio."""
    import meshio
    import numpy as np

    cells = [("triangle", np.asarray(triangles, dtype=np.int32))]  # PLY: 32 bits
    meshio.write_points_cells(str(path), points, cells)


def folded(points):  # type: ignore[no-untyped-def]
    """A copy of an ellipsoid's vertices with the +x tip pushed through the body.

    The tip's triangles then cross the far side: a fold near x = -axes[0].
    """
    out = points.copy()
    tip = int(out[:, 0].argmax())
    out[tip] = [-1.5 * out[tip, 0], 3.0, 2.0]
    return out


ORGAN_BODY = """
[mesh]
truth = "meshes/organ-n1200.msh"
models = ["meshes/organ-n150.msh"]

[material]
law = "neo-hookean"
E = 4000.0
nu = 0.45
density = 1000.0

[fixed]
half_space = { point = [-0.045, 0.0, 0.0], normal = [-1.0, 0.0, 0.0] }

[[manipulation]]
name = "push"
kind = "pressure"
region = { sphere = { centre = [0.06, 0.0, 0.0], radius = 0.025 } }
pressure = 100.0

[[manipulation]]
name = "push-conserved"
kind = "pressure"
region = { sphere = { centre = [0.06, 0.0, 0.0], radius = 0.025 } }
pressure = 100.0
conserve = "resultant"

[[manipulation]]
name = "lift"
kind = "grasp"
point = [0.03, 0.0, 0.03]
radius = 0.01
force = [0.0, 0.0, 0.3]

[[manipulation]]
name = "sag"
kind = "gravity"
acceleration = [0.0, 0.0, -9.81]
conserve = "resultant"

[markers]
points = [[0.04, 0.0, 0.025], [0.0, 0.0, 0.03], [0.05, -0.02, 0.0]]

[shape_error]
grid = [8, 5, 4]
margin = 0.003

[targets]
lesion = [0.02, 0.0, 0.0]
"""
"""A body on the synthetic organ (:func:`organ_body`): a pressure inside a
sphere (as is and conserved), a grasp and a conserved gravity."""


def organ_body(folder, sizes=(150, 1200)):  # type: ignore[no-untyped-def]
    """Write the synthetic organ's meshes (``sizes`` nodes) and ORGAN_BODY there.

    Returns the body TOML's path; the meshes are ``meshes/organ-nN.msh``.
    """
    from pathlib import Path

    from idbench_fem.bodies.surface_file import merged
    from idbench_fem.bodies.surface_mesh import mesh_surface

    folder = Path(folder)
    (folder / "meshes").mkdir(parents=True, exist_ok=True)
    v, f = ellipsoid_surface(2)
    surface = merged("organ", v / 1000.0, f)
    for n in sizes:
        mesh_surface(surface, n, folder / "meshes" / f"organ-n{n}.msh")
    path = folder / "body.toml"
    path.write_text(ORGAN_BODY)
    return path
