"""Beyond the paper: the tissue's E from a coarse mesh, through its approximation error.

Uncorrected, a coarse mesh identifies its *effective* E (0.51 and 0.65 of
E_true at 240 and 525 nodes in bending) and every estimator is confidently
wrong about the tissue. Corrected (``correction = "approximation-error"``),
the estimator's observation model carries the coarse mesh's discrepancy
against a finer mesh of the same body, calibrated offline on paths of its
own design (:mod:`idbench.calibrate.design`; never the comparison's truth data),
and the estimate is the *physical* E. For each coarse mesh and load path:

- ``uncorrected``: today's default;
- ``used``: calibrated on every path of the comparison, the identified one
  too (its direction, at load states of the prior's draws, not its data);
- ``not used``: calibrated on the design ``DESIGN`` only (14 end tractions,
  none a path of the comparison, whose cone holds them all): how far the
  correction transfers to directions it did not see;
- ``left out`` (``--left-out``): calibrated on the comparison's other paths.

The paths: the five registered beam paths and two new directions
(``mixed-45``, in the x-y plane; ``bend-yz``, the y-z diagonal). Reported per
(mode, mesh, path): E / E_true, |E / E_true - 1|, coverage of E_true by the
95% interval, NEES against E_true, shape error (mm a grid point), step time,
and whether the correction said it extrapolated.

Run ``python studies/physical_stiffness.py [--quick] [--out DIR]``; a full
run writes the liver's reports (report.html, with the 3D view) in
``DIR/liver-MODE``.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import _cli
import numpy as np
import pandas as pd

from idbench import Registry, Scenario, build_registry
from idbench.plan.config import CompareConfig
from idbench.run.compare import compare
from idbench_fem.models.beam_scenarios import BEND_TRACTION, DESIGN_TRACTIONS

# Parameters (full size)
MESHES = ("14x3x3", "20x4x4")  # 240, 525 nodes
TRUTH = "80x11x11"  # 11,664 nodes; also the calibration mesh
SCENARIOS = ("bend-y", "bend-z", "stretch-x", "mixed-30", "mixed-60",
             "mixed-45", "bend-yz")  # fmt: skip
ESTIMATORS = ("ro-ukf",)  # the others: see the README (idbench compare)
SEEDS = 3
STEPS = 20
CALIBRATION: dict[str, Any] = {}  # CalibrationSettings fields (defaults)
# the design's: its fine paths start at the prior's 20% quantile of E, 30
# steps (14 paths x 30 / 20 = 21 fine path simulations per coarse mesh)
DESIGN_CALIBRATION: dict[str, Any] = {"quantile": 0.2, "scaled_steps": 30}
MODES = ("uncorrected", "used", "not used", "left out")

# The liver (examples/liver/body.toml: neo-Hookean, E = 4 kPa, 8 anterior
# markers), its three manipulations; "not used" is calibrated on the design
# body examples/liver/calibration.toml (three other grasp forces, 18 pressure
# caps shifted 4, 8 and 12 mm either way along x, y and z from
# lateral-push's, four gravities tilted 20 deg from -x in x-y and x-z) whose
# loads span the three without containing them.
LIVER_MESHES = ("500", "1000")
LIVER_TRUTH = "4000"  # the example's truth; also the calibration mesh
LIVER_SCENARIOS = ("grasp-lift", "lateral-push", "sag-90")
LIVER_CAPS = tuple(f"cal-push-{side}{shift}" for shift in ("", "2", "3")
                   for side in ("up", "down", "in", "out", "front", "back"))
LIVER_DESIGN = ("cal-grasp-a", "cal-grasp-b", "cal-grasp-c", *LIVER_CAPS,
                "cal-tilt-a", "cal-tilt-b", "cal-tilt-c", "cal-tilt-d")  # fmt: skip
LIVER_STEPS = 20
LIVER_SEEDS = 3
# 25 design paths x 30 / 20 steps: 37.5 fine path simulations per coarse mesh
LIVER_CALIBRATION: dict[str, Any] = {"quantile": 0.25, "scaled_steps": 30,
                                     "features": "linear"}
LIVER_OBSERVATION: dict[str, Any] = {
    "obs_points": (8,), "obs_every": (2,), "noise": (1e-4,), "prior": (2000.0, 2000.0),
}  # fmt: skip
LIVER_DESIGN_BODY = Path(__file__).resolve().parent.parent / "examples" / "liver" / (
    "calibration.toml"
)

QUICK: dict[str, Any] = {
    "MESHES": ("6x2x2",),
    "TRUTH": "9x2x2",
    "SCENARIOS": ("bend-y", "mixed-30", "mixed-60"),
    "ESTIMATORS": ("ro-ukf",),
    "SEEDS": 1,
    "STEPS": 8,
    "CALIBRATION": {"scaled_steps": 12},
    "DESIGN_CALIBRATION": {"quantile": 0.2, "scaled_steps": 12},
    "LIVER_MESHES": ("150",),
    "LIVER_TRUTH": "600",
    "LIVER_SCENARIOS": ("grasp-lift",),
    "LIVER_DESIGN": ("cal-grasp-a", "cal-grasp-b", "cal-grasp-c"),
    "LIVER_STEPS": 6,
    "LIVER_SEEDS": 1,
    "LIVER_CALIBRATION": {"quantile": 0.25, "scaled_steps": 12},  # quadratic
}

# The beam's calibration design (mode "not used"): the 14 end tractions (Pa)
# of the FE plugin's design (idbench_fem.models.beam_scenarios.DESIGN_TRACTIONS),
# named cal-* here, none of them a path of SCENARIOS, whose cone holds every
# one of them (each path's traction is a combination of them with
# coefficients >= 0). Six along +x, -y and -z, each tilted by 0.2 of the
# bending traction towards the other two axes, one way (cal-x, cal-y, cal-z)
# and the other (cal-x2, cal-y2, cal-z2). The x components of the bending
# ones stay at +-0.5 Pa: an end compression beyond a few Pa buckles the beam
# at the prior's low E. Eight combine a moderate axial pull with bending, at
# the bending traction 15 and 75 deg from +x towards -y (cal-xy15, cal-xy75),
# tilted by 0.2 of it towards +z and (suffix b) -z, and likewise towards -z
# (cal-xz15, cal-xz75), tilted towards +y and -y: the beam's response to a
# pull with bending is not the sum of its responses to the two (tension
# stiffens it in bending), and the mixed paths (a small pull with bending, in
# the x-y plane) lie in the cone of the four x-y ones alone.
DESIGN: dict[str, tuple[float, ...]] = {
    "cal-" + name.removeprefix("design-"): traction
    for name, traction in DESIGN_TRACTIONS.items()
}


def new_paths(registry: Registry) -> Registry:
    """The registry with the two new directions and the design (end tractions)."""
    a = math.radians(45.0)
    r = math.sqrt(0.5)
    new = [
        Scenario("mixed-45", {"direction": [math.cos(a), -math.sin(a), 0.0],
                              "magnitude": BEND_TRACTION}, "stretch-x",
                 "traction in the x-y plane, 45 deg from +x to -y"),
        Scenario("bend-yz", {"direction": [0.0, -r, -r],
                             "magnitude": BEND_TRACTION}, "stretch-x",
                 "bending along the y-z diagonal"),
    ]  # fmt: skip
    for name, t in DESIGN.items():
        size = math.sqrt(sum(c * c for c in t))
        load = {"direction": [c / size for c in t], "magnitude": size}
        new.append(Scenario(name, load, "", "calibration design"))
    return registry.with_scenarios(new, "physical_stiffness")


def liver_design(registry: Registry, body: Path = LIVER_DESIGN_BODY) -> Registry:
    """The registry with the liver calibration design's manipulations."""
    from idbench_fem.bodies.catalog import get_body

    spec = str(body)
    found = [m.name for m in get_body(spec).manipulations]
    new = [Scenario(n, {"body": spec, "manipulation": n}) for n in found]
    return registry.with_scenarios(new, "physical_stiffness")


def _runs(
    p: dict[str, Any],
    registry: Registry,
    out: Path | None,
    name: str,
    scenarios: tuple[str, ...],
    design: tuple[str, ...] | None,
    body: str = "beam",
    calibration: dict[str, Any] | None = None,
) -> pd.DataFrame:
    """One comparison: uncorrected (``design`` None) or calibrated on ``design``.

    ``calibration``: the calibration settings (default the body's).
    """
    settings = (
        {}
        if design is None
        else {e: {"correction": "approximation-error"} for e in p["ESTIMATORS"]}
    )
    if body == "beam":
        common: dict[str, Any] = dict(
            meshes=p["MESHES"], truth_mesh=p["TRUTH"], seeds=p["SEEDS"],
            steps=p["STEPS"], calibration={**(calibration or p["CALIBRATION"]),
                                           "scenarios": list(design or ())},
        )  # fmt: skip
    else:
        common = dict(
            meshes=p["LIVER_MESHES"], truth_mesh=p["LIVER_TRUTH"],
            seeds=p["LIVER_SEEDS"], steps=p["LIVER_STEPS"], model="solid",
            model_settings={"solid": {"body": "liver",
                                      "reference": p["LIVER_TRUTH"]}},
            calibration={**p["LIVER_CALIBRATION"], "scenarios": list(design or ())},
            **LIVER_OBSERVATION,
        )  # fmt: skip
    config = CompareConfig(scenarios=scenarios, estimators=p["ESTIMATORS"],
                           estimator_settings=settings, **common)  # fmt: skip
    runs, _ = compare(config, None if out is None else out / name, registry=registry)
    runs["body"] = body
    return runs


def compute(
    quick: bool = False,
    out: str | Path | None = None,
    bodies: tuple[str, ...] = ("beam", "liver"),
    left_out: bool = False,
    used: bool = True,
) -> pd.DataFrame:
    """Runs of every (body, mode, mesh, path, estimator, seed); one row each.

    Columns: the runs table's, plus ``body``, ``mode`` and ``E_ratio``
    (E_final / E_true); ``extrapolated`` (the correction warned it
    extrapolated). ``left_out``: also the beam's leave-one-path-out
    calibrations (mode ``"left out"``); ``used`` False: not the beam's
    calibrations on the paths' own directions (mode ``"used"``).
    """
    p = {k: globals()[k] for k in QUICK}
    if quick:
        p.update(QUICK)
    root = None if out is None else Path(out)
    registry = liver_design(new_paths(build_registry()))
    parts = []
    if "beam" in bodies:
        scenarios = tuple(p["SCENARIOS"])
        plain = _runs(p, registry, root, "uncorrected", scenarios, None)
        plain["mode"] = "uncorrected"
        parts.append(plain)
        if used:
            own = _runs(p, registry, root, "used", scenarios, scenarios)
            own["mode"] = "used"
            parts.append(own)
        design = _runs(p, registry, root, "design", scenarios, tuple(DESIGN),
                       calibration=p["DESIGN_CALIBRATION"])  # fmt: skip
        design["mode"] = "not used"
        parts.append(design)
        for held in scenarios if left_out else ():
            others = tuple(s for s in scenarios if s != held)
            loo = _runs(p, registry, root, f"not-used-{held}", (held,), others)
            loo["mode"] = "left out"
            parts.append(loo)
    if "liver" in bodies:
        scenarios = tuple(p["LIVER_SCENARIOS"])
        for mode, design in (("uncorrected", None), ("used", scenarios),
                             ("not used", tuple(p["LIVER_DESIGN"]))):  # fmt: skip
            name = "liver-" + mode.replace(" ", "-")
            runs = _runs(p, registry, root, name, scenarios, design, "liver")
            _cli.report(None if root is None else root / name, quick)  # 3D view
            runs["mode"] = mode
            parts.append(runs)
    runs = pd.concat(parts, ignore_index=True)
    runs["E_ratio"] = runs["E_final"] / runs["E_true"]
    warning = runs["warning"].fillna("").astype(str)
    runs["extrapolated"] = warning.str.contains("extrapolated")
    return runs


def summarise(runs: pd.DataFrame, by: tuple[str, ...] = ("body", "mode",
              "model_nodes", "estimator")) -> pd.DataFrame:  # fmt: skip
    """Median |E/E_true - 1|, coverage of E_true, mean NEES, ... per group."""
    ok = runs[runs["status"] == "ok"].copy()
    ok["abs_err"] = ok["E_relerr_true"].abs()
    ok["shape_error_mm"] = 1000 * ok["shape_error_mean_final"]
    table = ok.groupby(list(by), sort=False).agg(
        n=("seed", "size"),
        E_ratio=("E_ratio", "median"),
        median_abs_err=("abs_err", "median"),
        max_abs_err=("abs_err", "max"),
        cover95_true=("E_cover95_true", "mean"),
        nees_true=("nees_true", "mean"),
        shape_error_mm=("shape_error_mm", "mean"),
        wall_s_step=("wall_s_step", "mean"),
        extrapolated=("extrapolated", "mean"),
    )
    return table.reset_index()


def plot(runs: pd.DataFrame, path: Path) -> None:
    import matplotlib.pyplot as plt

    from idbench.report.figures import style

    ok = runs[(runs["status"] == "ok") & (runs["estimator"] == "ro-ukf")]
    fig, axs = plt.subplots(1, 2, figsize=(11, 4))
    cases = [(b, m) for b in ("beam", "liver") for m in MODES]
    for i, (body, mode) in enumerate(cases):
        d = ok[(ok["mode"] == mode) & (ok["body"] == body)]
        if d.empty:
            continue
        g = d.groupby("model_nodes")
        nodes = np.array(sorted(g.groups))
        med = g["E_ratio"].median().reindex(nodes)
        lo, hi = g["E_ratio"].min().reindex(nodes), g["E_ratio"].max().reindex(nodes)
        cover = g["E_cover95_true"].mean().reindex(nodes)
        st = style(i)
        label = f"{body}: {mode}"
        shift = 1 + 0.03 * (MODES.index(mode) - 1)
        axs[0].errorbar(nodes * shift, med, yerr=[med - lo, hi - med], capsize=3,
                        label=label, **st)  # fmt: skip
        axs[1].plot(nodes, cover, label=label, **st)
    axs[0].axhline(1.0, color="0.4", ls="--", lw=1)
    axs[0].set_ylabel("identified E / E_true (median, range over paths, seeds)")
    axs[1].axhline(0.95, color="0.4", ls="--", lw=1)
    axs[1].set_ylabel("95% interval holds E_true (share of runs)")
    axs[1].set_ylim(-0.05, 1.05)
    for ax in axs:
        ax.set_xscale("log")
        ax.set_xlabel("model nodes")
        ax.legend(fontsize=8)
    fig.suptitle("RO-UKF: effective (uncorrected) vs physical E (corrected)")
    fig.tight_layout()
    fig.savefig(path, dpi=130)


if __name__ == "__main__":
    parser = _cli.parser(__doc__, "results/physical")
    parser.add_argument("--bodies", default="beam,liver",
                        help="comma-separated: beam, liver (default both)")
    parser.add_argument("--left-out", action="store_true",
                        help="also the beam's leave-one-path-out calibrations")
    parser.add_argument("--no-used", action="store_true",
                        help="leave out the beam's calibrations on its own paths")
    args = parser.parse_args()
    runs = compute(args.quick, args.out, tuple(args.bodies.split(",")),
                   args.left_out, not args.no_used)  # fmt: skip
    args.out.mkdir(parents=True, exist_ok=True)
    runs.to_parquet(args.out / "physical_stiffness_runs.parquet")
    table = summarise(runs)
    table.to_csv(args.out / "physical_stiffness.csv", index=False)
    by_path = summarise(runs, ("body", "mode", "model_nodes", "scenario",
                               "estimator"))  # fmt: skip
    by_path.to_csv(args.out / "physical_stiffness_paths.csv", index=False)
    with pd.option_context("display.width", 250, "display.max_columns", 40):
        print(table.to_string(index=False))
        print(by_path[by_path["estimator"] == "ro-ukf"].to_string(index=False))
    plot(runs, args.out / "physical_stiffness.png")
