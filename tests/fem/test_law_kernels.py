"""Compiled general-law kernels: equal to the numpy path, tangent = f's derivative."""

from __future__ import annotations

import numpy as np
import pytest

from idbench_fem.bodies.box import parse as beam_mesh
from idbench_fem.fem import kernels
from idbench_fem.fem.law_assembly import LawAssembler
from idbench_fem.fem.materials import make_material

pytestmark = pytest.mark.skipif(not kernels.available(), reason="numba not usable")

LAWS = ["svk", "neo-hookean"]


def pair(law: str, spec: str = "3x1x1"):
    """The compiled and numpy assemblers of ``law`` on a beam, x = 0 fixed."""
    beam = beam_mesh(spec)
    free = beam.points[:, 0] > 1e-9
    mat = make_material(law, 1.0, 0.4)
    fast = LawAssembler(beam.points, beam.tets, free, mat, compiled=True)
    fast.h = float(np.cbrt(fast.volumes.min()))  # an element's size
    return (
        fast,
        LawAssembler(beam.points, beam.tets, free, mat, compiled=False),
    )


def state(asm, seed=0, scale=0.1):
    """Random displacements of about ``scale`` element sizes, and moduli."""
    rng = np.random.default_rng(seed)
    u = scale * asm.h * rng.standard_normal(asm.n_free)
    modulus = rng.uniform(1.0, 3.0, asm.n_elements)
    return u, modulus


@pytest.mark.parametrize("law", LAWS)
@pytest.mark.parametrize("upper", [False, True])
def test_compiled_equals_numpy_to_round_off(law, upper):
    fast, ref = pair(law)
    assert fast.compiled and not ref.compiled
    u, modulus = state(fast)
    kf, kr = fast.kinematics(u, modulus), ref.kinematics(u, modulus)
    assert kf.forces is not None and kr.forces is None
    assert np.all(kr.det > 0)  # a real deformation, no inverted element
    np.testing.assert_allclose(kf.F, kr.F, rtol=1e-12, atol=1e-15)
    np.testing.assert_allclose(kf.det, kr.det, rtol=1e-12)
    scale = np.abs(kr.S).max()
    np.testing.assert_allclose(kf.S, kr.S, rtol=1e-12, atol=1e-12 * scale)
    fr = ref.forces(kr)
    np.testing.assert_allclose(
        fast.forces(kf), fr, rtol=1e-12, atol=1e-12 * np.abs(fr).max()
    )
    pf, pr = fast.pattern(upper), ref.pattern(upper)
    tf, tr = fast.tangent_data(kf, modulus, pf), ref.tangent_data(kr, modulus, pr)
    np.testing.assert_allclose(tf, tr, rtol=1e-12, atol=1e-12 * np.abs(tr).max())
    # region forces (numpy, from the compiled F and S) agree too
    regions = np.arange(fast.n_elements) % 2
    np.testing.assert_allclose(
        fast.region_forces(kf, regions, 2), ref.region_forces(kr, regions, 2),
        rtol=1e-12, atol=1e-12 * np.abs(fr).max(),
    )  # fmt: skip


@pytest.mark.parametrize("law", LAWS)
def test_compiled_tangent_is_the_derivative_of_the_force(law):
    fast, _ = pair(law)
    u, modulus = state(fast, seed=1)
    pat = fast.pattern(upper=True)
    K = pat.matrix(fast.tangent_data(fast.kinematics(u, modulus), modulus, pat))
    K = K.toarray()
    h = 1e-7
    for j in (0, 5, 13, fast.n_free - 1):
        e = np.zeros(fast.n_free)
        e[j] = h
        fp = fast.forces(fast.kinematics(u + e, modulus))
        fm = fast.forces(fast.kinematics(u - e, modulus))
        np.testing.assert_allclose(
            (fp - fm) / (2 * h), K[:, j], rtol=1e-5, atol=1e-6 * np.abs(K).max()
        )


def test_inverted_element_is_flagged_and_nan_like_numpy():
    fast, ref = pair("neo-hookean")
    _, modulus = state(fast)
    u = np.zeros(fast.n_free)
    u[0::3] = -50 * fast.h  # every free node pushed through the fixed end: inverts some
    kf, kr = fast.kinematics(u, modulus), ref.kinematics(u, modulus)
    bad = kr.det <= 0
    assert bad.any()
    np.testing.assert_array_equal(kf.det <= 0, bad)
    assert not np.all(np.isfinite(fast.forces(kf)))
    assert not np.all(np.isfinite(ref.forces(kr)))


def test_switch_off(monkeypatch):
    monkeypatch.setenv(kernels.ENV, "0")
    beam = beam_mesh("2x1x1")
    asm = LawAssembler(beam.points, beam.tets, beam.points[:, 0] > 1e-9,
                       make_material("neo-hookean", 1.0, 0.4))  # fmt: skip
    assert not asm.compiled
