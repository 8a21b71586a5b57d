"""Reduced models of a fine mesh: exact when nothing is left out, FD, convergence."""

from __future__ import annotations

import numpy as np
import pytest
from support.bodies import write_beam_body
from support.designs import write_designed_beam

import idbench
from idbench.registry.testing import check_model
from idbench_fem.bodies.box import parse as beam_mesh
from idbench_fem.fem.ecsw import ecsw
from idbench_fem.fem.element_set import ElementSet
from idbench_fem.fem.hyper import HyperReduced
from idbench_fem.fem.law_assembly import LawAssembler
from idbench_fem.fem.materials import make_material
from idbench_fem.fem.pod import modes_for, pod
from idbench_fem.models.reduced import ReducedModel
from idbench_fem.models.reduction import (
    Reduction,
    ReductionSpec,
    element_dofs,
    element_factors,
    element_set,
    parse_spec,
)
from idbench_fem.models.solid import SolidModel, make_model

LAWS = ("svk", "neo-hookean")


def model(body, mesh="truth", manipulation="end", steps=4, **settings):
    scenario = idbench.Scenario(
        manipulation, {"body": str(body), "manipulation": manipulation}
    )
    return make_model(idbench.ModelSpec(mesh, scenario, steps, 2, settings or None))


def path(m, theta, steps=None):
    u, out = m.reset(), []
    for k in range(1, (steps or m.n_steps) + 1):
        u = m.step(np.atleast_1d(theta), k, u)
        out.append(u)
    return np.array(out)


def whole(full: SolidModel) -> ReducedModel:
    """Every mode (V = I) and every element with weight 1."""
    n, T = full.n_state, len(full.mesh()[1])
    red = Reduction("all", np.eye(n), np.ones(n), np.arange(T), np.ones(T), {})
    rom = ReducedModel(full, red, ReductionSpec("truth"))
    rom.rtol = full.rtol  # the full model's tolerance (the reduced default: 1e-6)
    return rom


@pytest.mark.parametrize("law", LAWS)
def test_element_kernels_equal_the_assembler(law):
    beam = beam_mesh("3x2x2")
    free = np.ones(len(beam.points), dtype=bool)
    asm = LawAssembler(beam.points, beam.tets, free, make_material(law, 1.0, 0.45),
                       compiled=False)  # fmt: skip
    rng = np.random.default_rng(1)
    u = 1e-3 * rng.standard_normal(asm.n_free)
    modulus = rng.uniform(1.0, 2.0, len(beam.tets))
    kin = asm.kinematics(u, modulus)
    es = ElementSet(asm.grads, asm.volumes, law, 0.45)
    st = es.state(u[asm.element_dofs].reshape(-1, 4, 3))
    ref_f = asm.element_forces(kin).reshape(-1, 12)
    f = es.forces(st, modulus)
    np.testing.assert_allclose(f, ref_f, atol=1e-14 * abs(ref_f).max())
    ref_k = asm.element_tangents(kin, modulus)
    k = es.tangents(st, modulus)
    np.testing.assert_allclose(k, ref_k, atol=1e-13 * abs(ref_k).max())


@pytest.mark.parametrize("law", LAWS)
def test_every_mode_and_element_is_the_full_model(tmp_path, law):
    body, _ = write_beam_body(tmp_path, "6x2x2", law=law)
    full = model(body)
    rom = whole(full)
    theta = np.array([5000.0])
    U, Q = path(full, theta), path(rom, theta)
    assert np.abs(U).max() > 1e-3  # a large deformation
    # equal to the Newton tolerance (both converge to rtol 1e-8 of the load)
    np.testing.assert_allclose(Q, U, rtol=0, atol=1e-7 * np.abs(U).max())
    np.testing.assert_allclose(rom.observe(Q[-1]), full.observe(U[-1]), rtol=1e-7)
    np.testing.assert_allclose(
        rom.sensitivity(theta, 4, Q[-1]), full.sensitivity(theta, 4, U[-1]), rtol=1e-6
    )
    assert rom.diagnostics()["reduction_residual"] < 1e-7  # the full residual
    assert rom.diagnostics()["reduction_error_estimate"] < 1e-7
    assert rom.diagnostic_warning() == ""


def sampled_hyper(full, modes=6, count=20, seed=2, compiled=None):
    """A HyperReduced of ``full`` on a random basis and random sampled elements."""
    _, tets = full.mesh()
    rng = np.random.default_rng(seed)
    V = np.linalg.qr(rng.standard_normal((full.n_state, modes)))[0]
    pick = np.sort(rng.choice(len(tets), count, replace=False))
    return HyperReduced(
        element_set(full, tets[pick]), element_dofs(full, tets[pick]), V,
        rng.uniform(0.5, 3.0, len(pick)), element_factors(full)[pick],
        full.element_regions[pick], full.parameters.p, compiled=compiled,
    )  # fmt: skip


@pytest.mark.parametrize("compiled", [False, True])
@pytest.mark.parametrize("law", LAWS)
def test_reduced_force_and_tangent_match_finite_differences(tmp_path, law, compiled):
    body, _ = write_beam_body(tmp_path, "4x2x2", law=law)
    hyper = sampled_hyper(model(body), compiled=compiled)
    if compiled and not hyper.compiled:
        pytest.skip("numba is not available")
    theta = np.array([4000.0])
    q = 2e-3 * np.random.default_rng(5).standard_normal(6)
    K = hyper.tangent(hyper.evaluate(q), theta)
    np.testing.assert_allclose(K, K.T, atol=1e-12 * abs(K).max())
    h = 1e-7
    fd = np.column_stack([
        (hyper.force(hyper.evaluate(q + h * e), theta)
         - hyper.force(hyper.evaluate(q - h * e), theta)) / (2 * h)
        for e in np.eye(6)
    ])  # fmt: skip
    np.testing.assert_allclose(K, fd, atol=1e-6 * abs(K).max())
    # and the force is linear in theta, region by region
    st = hyper.evaluate(q)
    np.testing.assert_allclose(hyper.force(st, 2 * theta), 2 * hyper.force(st, theta))


@pytest.mark.parametrize("law", LAWS)
def test_compiled_and_numpy_reductions_agree(tmp_path, law):
    body, _ = write_beam_body(tmp_path, "4x2x2", law=law)
    full = model(body)
    fast, slow = sampled_hyper(full, compiled=True), sampled_hyper(full, compiled=False)
    if not fast.compiled:
        pytest.skip("numba is not available")
    q = 2e-3 * np.random.default_rng(6).standard_normal(6)
    a, b = fast.evaluate(q), slow.evaluate(q)
    np.testing.assert_allclose(a.g, b.g, rtol=0, atol=1e-12 * abs(b.g).max())
    np.testing.assert_allclose(a.det, b.det, rtol=1e-13)
    Ka, Kb = fast.region_tangents(a), slow.region_tangents(b)
    np.testing.assert_allclose(Ka, Kb, rtol=0, atol=1e-12 * abs(Kb).max())


@pytest.fixture(scope="module")
def designed(tmp_path_factory):
    """A beam body with a design of five end tractions (none the body's own)."""
    return write_designed_beam(tmp_path_factory.mktemp("designed"), "8x2x2")[0]


def test_error_decreases_as_modes_are_added(designed):
    theta = np.array([4000.0])  # inside the design's moduli, not one of its paths
    U = path(model(designed), theta)
    peak = np.abs(U).max()
    errors = []
    for modes in (2, 4, 8):
        rom = model(designed, f"rom:truth:{modes}:all")
        assert rom.n_state == modes
        Q = path(rom, theta)
        lifted = Q @ rom.reduction.basis.T
        errors.append(np.abs(lifted - U).max() / peak)
    assert errors[0] > errors[1] > errors[2]
    assert errors[2] < 1e-2


def test_ecsw_samples_few_elements_that_fit_the_reduced_forces(designed):
    theta = np.array([4000.0])
    exact = model(designed, "rom:truth:8:all")
    sampled = model(designed, "rom:truth:8:0.001")
    n_tets = len(exact.mesh()[1])
    red = sampled.reduction
    assert 0 < len(red.elements) < n_tets
    assert np.all(red.weights > 0)
    assert red.info["ecsw_fit"] <= 1e-3
    Qe, Qs = path(exact, theta), path(sampled, theta)
    scale = np.abs(Qe).max()
    np.testing.assert_allclose(Qs, Qe, atol=2e-2 * scale)


def test_ecsw_is_exact_on_its_training_with_every_element():
    """A tolerance below round-off keeps every element it needs: the fit is tight."""
    beam = beam_mesh("3x1x1")
    free = np.ones(len(beam.points), dtype=bool)
    free[beam.points[:, 0] < 1e-9] = False
    asm = LawAssembler(beam.points, beam.tets, free, make_material("svk", 1.0, 0.45),
                       compiled=False)  # fmt: skip
    rng = np.random.default_rng(3)
    V = np.linalg.qr(rng.standard_normal((asm.n_free, 3)))[0]
    es = ElementSet(asm.grads, asm.volumes, "svk", 0.45)
    T = len(beam.tets)
    out = ecsw(es, asm.element_dofs, V, np.ones(T), np.zeros(T, int), 1,
               1e-3 * rng.standard_normal((4, 3)), tolerance=1e-9)  # fmt: skip
    assert out.residual <= 1e-9 and np.all(out.weights > 0)


def test_pod_modes_for_a_tolerance():
    rng = np.random.default_rng(4)
    basis = np.linalg.qr(rng.standard_normal((50, 3)))[0]
    snaps = (rng.standard_normal((20, 3)) * [10.0, 1.0, 0.1]) @ basis.T
    modes, s = pod(snaps)
    assert modes.shape == (50, 3)
    assert modes_for(s, 0.5) == 1 and modes_for(s, 1e-6) == 3


def test_the_reduced_model_meets_the_protocol(designed):
    rom = model(designed, "rom:truth:6")
    # quasi-Newton lands just inside the tolerance (1e-8 of the load), not
    # beyond it as Newton's quadratic steps do: a wider finite difference
    check_model(rom, np.array([5000.0]), fd_rel_step=1e-3, fd_rtol=1e-3)
    assert rom.n_nodes == model(designed).n_nodes
    assert rom.reduces == "truth"


def test_a_large_residual_flags_the_run(designed):
    rom = model(designed, "rom:truth:2:all", steps=5)
    path(rom, np.array([3000.0]))
    worst = rom.diagnostics()["reduction_error_estimate"]
    assert worst > 1e-3  # two modes: far from the full model
    rom.error_tolerance = worst / 2
    assert "error estimate reached" in rom.diagnostic_warning()
    import copy

    assert copy.copy(rom).diagnostics() == {}  # a run's copy starts afresh


@pytest.mark.parametrize(
    "spec, expected",
    [
        ("rom:16000", ReductionSpec("16000")),
        ("rom:truth:40", ReductionSpec("truth", modes=40)),
        ("rom:4000:1e-5", ReductionSpec("4000", pod_tolerance=1e-5)),
        ("rom:4000:40:all", ReductionSpec("4000", modes=40, ecsw_tolerance=0.0)),
        ("rom:4000:40:0.01", ReductionSpec("4000", modes=40, ecsw_tolerance=0.01)),
        ("rom:4000:40:300", ReductionSpec("4000", modes=40, max_elements=300)),
    ],
)
def test_spec_syntax(spec, expected):
    assert parse_spec(spec) == expected


@pytest.mark.parametrize("spec", ["rom:", "rom:4000:0", "rom:4000:2.5", "rom:4000:4:x",
                                  "rom:4000:4:5:6"])  # fmt: skip
def test_bad_specs_are_refused_in_one_line(spec):
    with pytest.raises(idbench.ConfigError, match="rom:MESH"):
        parse_spec(spec)


def test_a_body_without_design_is_refused(tmp_path):
    body, _ = write_beam_body(tmp_path, "4x2x2")
    with pytest.raises(idbench.ConfigError, match=r"\[design\]"):
        model(body, "rom:truth:4")


@pytest.mark.parametrize(
    "extra, match",
    [
        ('manipulations = ["nope"]', "no manipulation 'nope'"),
        ("paths = 0", "paths = 0"),
        ("colour = 1", "unknown key 'colour'"),
    ],
)
def test_bad_designs_are_refused(tmp_path, extra, match):
    with pytest.raises(ValueError, match=match):
        body, _ = write_designed_beam(tmp_path, "4x2x2", extra=extra)
        from idbench_fem.bodies.description import load_body

        load_body(body)


def test_moduli_must_name_every_parameter(tmp_path):
    body, _ = write_designed_beam(tmp_path, "4x2x2")
    text = body.read_text().replace("moduli = { E =", "moduli = { G =")
    body.write_text(text)
    from idbench_fem.bodies.description import load_body

    with pytest.raises(ValueError, match="for each parameter: E"):
        load_body(body)


def test_one_range_of_E_serves_every_parameter(tmp_path):
    from idbench_fem.bodies.description import load_body

    body, _ = write_designed_beam(tmp_path, "4x2x2")
    slabs = "{ slab = { index = 0, count = 2 } }, { slab = { index = 1, count = 2 } }"
    body.write_text(body.read_text() + f"\n[parameters]\nregions = [{slabs}]\n")
    design = load_body(body).design
    assert [m[0] for m in design.moduli] == ["E_region0", "E_region1"]
    np.testing.assert_allclose(design.thetas(), [[2500.0, 2500.0]])


def test_the_beam_reduces_like_a_body():
    reg = idbench.build_registry()
    scenario = reg.scenario("bend-y")  # not one of the beam's design tractions
    full = reg.model("svk-beam")(idbench.ModelSpec("8x2x2", scenario, 4, 2))
    rom = reg.model("svk-beam")(idbench.ModelSpec("rom:8x2x2:12", scenario, 4, 2))
    assert rom.n_state == 12 and rom.reduction.info["fine_paths"] == 14
    theta = np.array([5000.0])
    U, Q = path(full, theta), path(rom, theta)
    lifted = Q @ rom.reduction.basis.T
    assert np.abs(lifted - U).max() < 1e-2 * np.abs(U).max()
