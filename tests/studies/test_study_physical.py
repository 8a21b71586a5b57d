"""The physical-stiffness study runs in --quick mode and shows its claim."""

from __future__ import annotations

import numpy as np
import scipy.optimize

from idbench import build_registry
from idbench_fem.models.beam_scenarios import STRETCH_TRACTION


def test_the_corrected_filter_covers_e_true_where_the_uncorrected_cannot(
    study, tmp_path
):
    module = study("physical_stiffness")
    runs = module.compute(quick=True, out=tmp_path)
    table = module.summarise(runs).set_index(["body", "mode"])
    modes = ("uncorrected", "used", "not used")
    assert set(table.index) == {(b, m) for b in ("beam", "liver") for m in modes}
    for body in ("beam", "liver"):
        plain = table.loc[(body, "uncorrected")]
        # uncorrected: the mesh's effective E, confidently wrong about the tissue
        assert plain["cover95_true"] == 0
        assert plain["median_abs_err"] > 0.1
        # corrected, on the paths' own directions and on a design of others
        for mode in ("used", "not used"):
            row = table.loc[(body, mode)]
            assert row["cover95_true"] > plain["cover95_true"], (body, mode)
            assert row["median_abs_err"] < 0.25 * plain["median_abs_err"], (body, mode)
    module.plot(runs, tmp_path / "physical_stiffness.png")
    assert (tmp_path / "physical_stiffness.png").stat().st_size > 1000


def _traction(scenario):
    return np.asarray(scenario.load["direction"]) * scenario.load["magnitude"]


def _in_cone(t, generators) -> bool:
    """``t`` is a combination of ``generators`` with coefficients >= 0."""
    _, residual = scipy.optimize.nnls(np.column_stack(generators), t)
    return bool(residual <= 1e-9 * np.linalg.norm(t))


def test_the_beam_design_spans_the_mixed_paths_with_pulls_in_bending(study):
    # the beam responds to a pull with bending not as to the two apart: the
    # mixed paths (a small pull plus bending) must lie between design
    # tractions that combine the two, and the design repeats no path
    module = study("physical_stiffness")
    registry = module.new_paths(build_registry())
    design = {n: np.asarray(t, dtype=float) for n, t in module.DESIGN.items()}
    paths = {n: _traction(registry.scenario(n)) for n in module.SCENARIOS}
    for name, t in paths.items():
        assert _in_cone(t, list(design.values())), name
        assert not any(np.allclose(t, d, rtol=1e-3) for d in design.values()), name
    bend = module.BEND_TRACTION
    pulls_in_bending = [
        d for d in design.values()
        if 0.1 * bend < d[0] < 0.1 * STRETCH_TRACTION
        and np.hypot(d[1], d[2]) > 0.1 * bend
    ]  # fmt: skip
    assert pulls_in_bending, "no design traction combines a pull with bending"
    for name in ("mixed-30", "mixed-45", "mixed-60"):
        assert _in_cone(paths[name], pulls_in_bending), name
    # the calibration's cost: fine path simulations per coarse mesh (bound 50)
    steps = module.DESIGN_CALIBRATION["scaled_steps"]
    assert len(design) * steps / module.STEPS <= 50


def test_the_liver_design_spans_its_manipulations_without_containing_them(study):
    # sag-90's -x gravity between gravities tilted both ways in x-y and in
    # x-z, grasp-lift's force between the grasps, lateral-push's cap the mean
    # of pairs of caps of its radius shifted a little either way along every
    # axis; no design manipulation is one of the liver's, and the cost is
    # within the bound of 50 fine path simulations per coarse mesh
    from idbench_fem.bodies.catalog import get_body

    module = study("physical_stiffness")
    body = {m.name: m for m in get_body(str(module.LIVER_DESIGN_BODY)).manipulations}
    liver = {m.name: m for m in get_body("liver").manipulations}
    design = [body[n] for n in module.LIVER_DESIGN]

    def of(kind):
        return [m for m in design if m.kind == kind]

    g = np.asarray(liver["sag-90"].vector, dtype=float)
    gravities = [np.asarray(m.vector, dtype=float) for m in of("gravity")]
    for axis in (1, 2):  # the x-y and the x-z plane, tilted both ways
        plane = [v for v in gravities if v[3 - axis] == 0 and v[axis] != 0]
        assert {np.sign(v[axis]) for v in plane} == {-1.0, 1.0}, axis
        assert _in_cone(g, plane), axis
    f = np.asarray(liver["grasp-lift"].vector, dtype=float)
    assert _in_cone(f, [np.asarray(m.vector, dtype=float) for m in of("grasp")])
    push = liver["lateral-push"]
    centre, radius = np.asarray(push.region.sphere[0]), push.region.sphere[1]
    caps = of("pressure")
    assert all(m.pressure == push.pressure and m.region.sphere[1] == radius
               for m in caps)  # fmt: skip
    shifts = [np.asarray(m.region.sphere[0]) - centre for m in caps]
    for axis in range(3):  # pairs either way, the nearest within 0.2 radius
        along = sorted(s[axis] for s in shifts if abs(s[axis]) > 1e-9
                       and np.count_nonzero(np.abs(s) > 1e-9) == 1)
        assert along and np.allclose(along, [-a for a in reversed(along)]), axis
        assert min(np.abs(along)) <= 0.2 * radius, axis
    assert all(0 < np.linalg.norm(s) < radius for s in shifts)
    for m in design:
        same = liver.get(m.name)
        assert same is None or same.vector != m.vector
    cost = len(design) * module.LIVER_CALIBRATION["scaled_steps"] / module.LIVER_STEPS
    assert cost <= 50
