"""Reproduces Figs. 2 and 5 and the transfer error on the liver, SVK and neo-Hookean.

The study's three claims, checked on an organ instead of the beam: the shipped
liver (examples/liver/body.toml: 16 x 10 x 8 cm lobe hanging from its
ligament, E = 4 kPa, nu = 0.47), three manipulations (grasp-lift, a 0.5 N
grasp of the inferior edge; lateral-push, a 400 Pa dead pressure on the right
lobe's tip; sag-90, gravity after a 90-degree reorientation), 8 anterior
markers, for each law:

- Fig. 2: E identified by the RO-UKF at the last step against model nodes
  (coarse meshes are stiffer, so they identify a lower E);
- Fig. 5: shape error at the last step, direct (model mesh with E_true) vs
  assimilated (the RO-UKF's own state);
- transfer: the E identified on one manipulation simulates the next one
  (grasp-lift -> lateral-push -> sag-90 -> grasp-lift); its shape error
  against that of E_true ("direct") on the same mesh.

SVK cannot follow the liver's loads: whatever the step count, Newton meets an
inverted element or stalls (SVK softens in compression) at about 45% of the
sag-90 weight on a 500-node mesh and 25% on 6,000 nodes, and at 70% of the
grasp on 6,000 nodes. So for SVK the study scales the grasp and the push to
30% (:data:`LOAD_SCALE`; the RO-UKF's low sigma point, about half of E_true,
doubles the strain) and leaves sag-90 out (:data:`SKIP`), transferring
between the other two.

Run ``python studies/organ_discretization.py [--quick] [--out DIR]``; a full
run writes each law's report (report.html, with the 3D view) in ``DIR/LAW``.
"""

from __future__ import annotations

from pathlib import Path

import _cli
import pandas as pd

from idbench import CompareConfig, Scenario, build_registry, compare

# Parameters (full size: liver meshes of about 200 to 2,000 nodes, truth 16,000)
LAWS = ("neo-hookean", "svk")
SCENARIOS = ("grasp-lift", "lateral-push", "sag-90")
MESHES = ("200", "500", "1000", "2000")
TRUTH = "16000"
ESTIMATOR = "ro-ukf"
SEEDS = 1
STEPS = 20
MARKERS = 8
NOISE = 1e-4  # m
PRIOR = (3000.0, 1500.0)  # Pa: sigma points near 1,900 and 4,800 Pa
SKIP = {"svk": ("sag-90",)}  # manipulations a law cannot follow (see above)
LOAD_SCALE = {"svk": 0.3}  # end loads as a fraction of the body's

QUICK = {
    "scenarios": ("grasp-lift", "lateral-push"),
    "meshes": ("150", "300"),
    "truth_mesh": "600",
    "steps": 6,
}


def compute(
    quick: bool = False, out: str | Path | None = None, truth: str | None = None
) -> pd.DataFrame:
    """One row per (law, scenario, model mesh): identified E and shape errors.

    Columns: ``E`` (RO-UKF, last step, mean over seeds), ``E_ratio`` (E / E_true),
    ``shape_error`` (assimilated) and ``shape_error_direct`` (E_true) at the last
    step (m, sum over the points), ``transfer_scenario``, ``transfer_error``
    (the identified E on that path) and ``transfer_error_direct`` (E_true).
    ``truth`` overrides the truth mesh (a node count).
    """
    settings = {
        "scenarios": SCENARIOS,
        "meshes": MESHES,
        "truth_mesh": TRUTH,
        "estimators": (ESTIMATOR,),
        "seeds": SEEDS,
        "steps": STEPS,
        "obs_points": (MARKERS,),
        "noise": (NOISE,),
        "prior": PRIOR,
    }
    if quick:
        settings.update(QUICK)
    if truth is not None:
        settings["truth_mesh"] = truth
    tables = []
    for law in LAWS:
        solid = {
            "law": law,
            "reference": settings["truth_mesh"],
            "load_scale": LOAD_SCALE.get(law, 1.0),
        }
        kept = [s for s in settings["scenarios"] if s not in SKIP.get(law, ())]
        registry = build_registry()
        cycle = []  # transfer to the next kept manipulation
        for i, name in enumerate(kept):
            sc = registry.scenario(name)
            target = kept[(i + 1) % len(kept)] if len(kept) > 1 else ""
            cycle.append(Scenario(name, sc.load, target, sc.description))
        registry = registry.with_scenarios(cycle, "organ_discretization")
        config = CompareConfig(
            model="solid",
            model_settings={"solid": solid},
            **{**settings, "scenarios": tuple(kept)},
        )
        folder = None if out is None else Path(out) / law
        runs, _ = compare(config, folder, registry=registry)
        _cli.report(folder, quick)  # report.html, with the 3D view
        ok = runs[runs["status"] == "ok"]
        direct = ("shape_error_direct", "transfer_scenario", "transfer_error_direct")
        table = _cli.over_seeds(
            ok,
            ["scenario", "mesh", "model_nodes"],
            first=("E_true", *direct),
            count="n_runs",
            sort=False,
            E="E_final",
            shape_error="shape_error_final",
            transfer_error="transfer_error",
        )
        table.insert(0, "law", law)
        table.insert(1, "load_scale", LOAD_SCALE.get(law, 1.0))
        table["n_failed"] = len(runs) - len(ok)
        tables.append(table)
    table = pd.concat(tables, ignore_index=True)
    table["E_ratio"] = table["E"] / table["E_true"]
    table["model_nodes"] = table["model_nodes"].astype(int)
    return table.sort_values(["law", "scenario", "model_nodes"]).reset_index(drop=True)


def plot(table: pd.DataFrame, path: Path) -> None:
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 3, figsize=(16, 4.4))
    colours = {s: f"C{i}" for i, s in enumerate(dict.fromkeys(table["scenario"]))}
    lines = {"svk": "-", "neo-hookean": "--"}
    for (law, scenario), df in table.groupby(["law", "scenario"], sort=False):
        style = {"color": colours[scenario], "ls": lines.get(str(law), ":")}
        label = f"{scenario}, {law}"
        x = df["model_nodes"]
        axes[0].plot(x, df["E_ratio"], marker="o", label=label, **style)
        axes[1].plot(x, df["shape_error_direct"], marker="s", mfc="none", **style)
        axes[1].plot(x, df["shape_error"], marker="o", **style)
        axes[2].plot(x, df["transfer_error_direct"], marker="s", mfc="none", **style)
        axes[2].plot(
            x,
            df["transfer_error"],
            marker="o",
            label=f"-> {df['transfer_scenario'].iloc[0]}, {law}",
            **style,
        )
    axes[0].axhline(1.0, color="k", lw=0.8)
    axes[0].set(ylabel="identified E / E_true (RO-UKF, last step)",
                title="Fig. 2 on the liver: identified E")  # fmt: skip
    axes[1].set(yscale="log", ylabel="shape error, last step (m, sum)",
                title="Fig. 5: direct (squares) vs assimilated (dots)")  # fmt: skip
    axes[2].set(yscale="log", ylabel="shape error on the next manipulation (m)",
                title="Transfer: identified E (dots) vs E_true (squares)")  # fmt: skip
    for ax in axes:
        ax.set(xscale="log", xlabel="model nodes")
    axes[0].legend(fontsize="x-small")
    axes[2].legend(fontsize="x-small")
    fig.tight_layout()
    fig.savefig(path, dpi=110)


if __name__ == "__main__":
    truth = {"help": f"truth mesh node count (default {TRUTH})"}
    _cli.main(
        __doc__, "results/organ", compute, plot, "organ_discretization",
        csv=True, options={"truth": truth},
    )  # fmt: skip
