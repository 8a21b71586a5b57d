"""Heterogeneous tissue: a stiff inclusion identified with p = 2, 4, 8 regions.

Beyond the paper. The truth beam has a box-shaped inclusion
3x stiffer than the rest (a tumour): x in [0.08, 0.12] m, the central quarter
of the section (y, z in [0.0075, 0.0225] m), resolved by the fine truth mesh.
The model mesh (20x4x4, whose element faces fit the box) identifies p moduli:
the inclusion (last region) and a background split into p - 1 equal slabs
along x (model options ``inclusion`` and ``regions``). The truth has the same
regions, with E_true in every slab and 3 E_true in the inclusion, so the
physical truth is the same for every p.

For every p, scenario and estimator (RO-UKF with p + 1 simplex sigma points,
"ro-ukf star" with 2p + 1 star points, RLS, batch least squares) the table
gives, over seeds:

- ``err_true``: RMS over regions of |ln(E_r / E_r,true)| (includes the coarse
  mesh's stiffening, which makes identified moduli low);
- ``err_ref``: RMS over regions of |ln(E_r / E_r,ref)|, E_ref being batch least
  squares on the same model mesh and data (the best constant regional moduli
  for this mesh: the estimator's own error; NaN where that fit failed);
- ``incl_ratio``, ``bg_ratio``: inclusion E / its truth and mean background
  E / E_true; ``contrast``: inclusion E / mean background E (truth: 3);
- ``shape_error`` (mean grid-point distance at the last step, m; ``_direct``:
  the same model mesh run with the true moduli), ``transfer_ratio`` (shape
  error on the other load path with the identified moduli, over that of the
  true moduli);
- ``solves_step`` (forward solves a step) and ``wall_step`` (seconds a step),
  from the traces, so diverged runs count up to their last step; batch least
  squares fits once at step K, its cost is spread over the K steps.

Rows with ``estimator = "ukf (2n+1)"`` give the full UKF's cost analytically:
2n + 1 forward solves a step with n = 3 x free nodes + p, for several meshes,
against its budget (``max_solves`` of the ``ukf`` estimator, default 600); set
``UKF_MESH`` to also run the full UKF there (bend-y, p = 2) and measure it.

Run ``python studies/heterogeneous_inclusion.py [--quick] [--out DIR]``.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import _cli
import numpy as np
import pandas as pd

from idbench import CompareConfig, ModelSpec, build_registry, compare

# Parameters (full size)
INCLUSION = (0.08, 0.12, 0.0075, 0.0225, 0.0075, 0.0225)
"""Inclusion box (x0, x1, y0, y1, z0, z1) in m: 5% of the volume."""
STIFFER = 3.0
P_VALUES = (2, 4, 8)
MODEL_MESH = "20x4x4"
TRUTH = "80x11x11"
ESTIMATORS = ("ro-ukf", "rls", "batch-ls")
VARIANTS: dict[str, tuple[str, dict[str, Any]]] = {
    "ro-ukf star": ("ro-ukf", {"sigma_points": "star"}),  # 2p + 1 solves a step
}
SCENARIOS = ("bend-y", "stretch-x")
MARKERS = 18  # the 4 end-face corners and 7 points along each top edge
SEEDS = 2
UKF_MESH: str | None = None  # e.g. "9x2x2": also run the full UKF (bend-y, p = 2)
COST_MESHES = ("9x2x2", "14x3x3", "20x4x4", "40x6x6")

QUICK: dict[str, Any] = {
    "p_values": (2, 4),
    "mesh": "10x4x4",
    "truth_mesh": "20x8x8",
    "scenarios": ("stretch-x",),
    "seeds": 1,
    "steps": 6,
    "ukf_mesh": None,
    "variants": {},
    "cost_meshes": ("9x2x2", "10x4x4"),
}


def options(p: int) -> dict[str, Any]:
    """Beam settings for p regions: p - 1 background slabs and the inclusion."""
    return {
        "parameters": "E_regions",
        "inclusion": INCLUSION,
        "regions": p - 1,
        "true_factors": (1.0,) * (p - 1) + (STIFFER,),
    }


def compute(
    quick: bool = False, out: str | Path | None = None, jobs: int = 1
) -> pd.DataFrame:
    """One row per (scenario, p, estimator, mesh): accuracy and cost, seed means."""
    s: dict[str, Any] = {
        "p_values": P_VALUES,
        "mesh": MODEL_MESH,
        "truth_mesh": TRUTH,
        "scenarios": SCENARIOS,
        "seeds": SEEDS,
        "steps": 20,
        "ukf_mesh": UKF_MESH,
        "variants": VARIANTS,
        "cost_meshes": COST_MESHES,
    }
    if quick:
        s.update(QUICK)
    variant_dirs = {"-" + k.replace(" ", "-"): k for k in s["variants"]}
    rows = []
    for p in s["p_values"]:
        common = {
            "truth_mesh": s["truth_mesh"],
            "steps": s["steps"],
            "obs_points": (MARKERS,),
            "model_settings": {"svk-beam": options(p)},
        }
        grids = [
            (
                "",
                CompareConfig(
                    meshes=(s["mesh"],),
                    estimators=ESTIMATORS,
                    scenarios=s["scenarios"],
                    seeds=s["seeds"],
                    **common,
                ),
            )
        ]
        for label, (name, settings) in s["variants"].items():
            grids.append(
                (
                    "-" + label.replace(" ", "-"),
                    CompareConfig(
                        meshes=(s["mesh"],),
                        estimators=(name,),
                        estimator_settings={name: settings},
                        scenarios=s["scenarios"],
                        seeds=s["seeds"],
                        **common,
                    ),
                )
            )
        if s["ukf_mesh"] and p == 2:
            grids.append(
                (
                    "-ukf",
                    CompareConfig(
                        meshes=(s["ukf_mesh"],),
                        estimators=("ukf",),
                        scenarios=("bend-y",),
                        seeds=1,
                        **common,
                    ),
                )
            )
        for suffix, config in grids:
            where = Path(out) / f"p{p}{suffix}" if out is not None else None
            runs, traces = compare(config, where, jobs=jobs)
            per_step = traces.groupby("run_id")[["n_solves", "wall_s"]].mean()
            runs = runs.join(per_step.add_suffix("_trace"), on="run_id")
            label = variant_dirs.get(suffix, "")
            rows.extend(score(r, p, label) for _, r in runs.iterrows())
    table = (
        pd.DataFrame(rows)
        .groupby(["scenario", "p", "estimator", "mesh"], sort=False)
        .agg(
            runs=("ok", "size"),
            ok=("ok", "sum"),
            **{
                c: (c, "mean")
                for c in (
                    "err_true",
                    "err_ref",
                    "incl_ratio",
                    "bg_ratio",
                    "contrast",
                    "shape_error",
                    "shape_error_direct",
                    "transfer_ratio",
                    "solves_step",
                    "wall_step",
                )
            },
        )
        .reset_index()
    )
    return pd.concat([table, full_ukf_cost(s["cost_meshes"], s["p_values"])])


def score(run: pd.Series, p: int, label: str = "") -> dict[str, Any]:
    """Accuracy and cost of one run (NaN accuracy unless its status is ok)."""
    names = [f"E_region{r}" for r in range(p)]
    est = np.array([run.get(f"{n}_final", np.nan) for n in names], dtype=float)
    true = np.array([run.get(f"{n}_true", np.nan) for n in names], dtype=float)
    ref = np.array([run.get(f"{n}_ref", np.nan) for n in names], dtype=float)
    ok = run["status"] == "ok"
    if not ok:
        est[:] = np.nan
    return {
        "scenario": run["scenario"],
        "p": p,
        "estimator": label or run["estimator"],
        "mesh": run["mesh"],
        "ok": ok,
        "err_true": float(np.sqrt(np.mean(np.log(est / true) ** 2))),
        "err_ref": float(np.sqrt(np.mean(np.log(est / ref) ** 2))),
        "incl_ratio": est[-1] / true[-1],
        "bg_ratio": float(np.mean(est[:-1] / true[:-1])),
        "contrast": est[-1] / float(np.mean(est[:-1])),
        "shape_error": run.get("shape_error_mean_final", np.nan) if ok else np.nan,
        "shape_error_direct": run.get("shape_error_direct_mean", np.nan),
        "transfer_ratio": (
            run.get("transfer_error", np.nan) / run.get("transfer_error_direct", np.nan)
            if ok
            else np.nan
        ),
        "solves_step": run.get("n_solves_trace", np.nan),
        "wall_step": run.get("wall_s_trace", np.nan),
    }


def full_ukf_cost(meshes: tuple[str, ...], p_values: tuple[int, ...]) -> pd.DataFrame:
    """Full UKF forward solves a step, 2n + 1 with n = 3 x free nodes + p."""
    registry = build_registry()
    budget = registry.estimator("ukf")().max_solves
    make = registry.model("svk-beam")
    rows = []
    for mesh in meshes:
        model = make(
            ModelSpec(
                mesh=mesh,
                scenario=registry.scenario("bend-y"),
                n_steps=1,
                settings=options(p_values[0]),
            )
        )
        for p in p_values:
            n = model.n_state + p
            rows.append(
                {
                    "scenario": "",
                    "p": p,
                    "estimator": "ukf (2n+1)",
                    "mesh": mesh,
                    "model_nodes": model.n_nodes,
                    "solves_step": 2 * n + 1,
                    "budget": budget,
                    "affordable": 2 * n + 1 <= budget,
                }
            )
    return pd.DataFrame(rows)


def plot(table: pd.DataFrame, path: Path) -> None:
    import matplotlib.pyplot as plt

    # runs with no successful seed are left out (their cost stops at a failure)
    measured = table[(table["estimator"] != "ukf (2n+1)") & (table["ok"] > 0)]
    analytic = table[table["estimator"] == "ukf (2n+1)"]
    fig, axes = plt.subplots(2, 3, figsize=(15, 8.5))
    ax = dict(
        zip(("incl", "bg", "contrast", "err", "solves", "wall"), axes.flat, strict=True)
    )
    styles = dict(
        zip(sorted(measured["scenario"].unique()), ("-", "--", ":"), strict=False)
    )
    cycle = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    colors = dict(zip((*ESTIMATORS, *VARIANTS, "ukf"), cycle, strict=False))
    for (scen, est, mesh), df in measured.groupby(["scenario", "estimator", "mesh"]):
        label = f"{est}, {scen}" + (f" ({mesh})" if est == "ukf" else "")
        kw = {"marker": "o", "ls": styles[scen], "color": colors.get(est)}
        for key, col in (
            ("incl", "incl_ratio"),
            ("bg", "bg_ratio"),
            ("contrast", "contrast"),
            ("err", "err_ref"),
            ("solves", "solves_step"),
            ("wall", "wall_step"),
        ):
            ax[key].plot(df["p"], df[col], label=label, **kw)
    for key in ("incl", "bg"):
        ax[key].axhline(1.0, color="k", ls="--", lw=1)
    ax["contrast"].axhline(STIFFER, color="k", ls="--", lw=1)
    for mesh, df in analytic.groupby("mesh", sort=False):
        ax["solves"].plot(df["p"], df["solves_step"], color="grey", ls="-.", lw=1)
        ax["solves"].annotate(
            f"full UKF, {mesh} ({df['model_nodes'].iloc[0]:.0f} nodes)",
            (df["p"].iloc[-1], df["solves_step"].iloc[-1]),
            fontsize=7, color="grey", va="bottom", ha="right",
        )  # fmt: skip
    budget = int(analytic["budget"].iloc[0])
    ax["solves"].axhline(budget, color="r", lw=1, label=f"UKF budget ({budget})")
    p_label = "parameter regions p (p - 1 slabs + inclusion)"
    ax["incl"].set(
        ylabel="E_inclusion / truth",
        yscale="log",
        title="inclusion modulus (truth 3 E_true)",
    )
    ax["bg"].set(ylabel="mean E_slab / E_true", yscale="log", title="background moduli")
    ax["contrast"].set(
        ylabel="E_inclusion / mean E_slab",
        yscale="log",
        title="identified contrast (truth 3)",
    )
    ax["err"].set(
        ylabel="RMS |ln(E_r / E_r,ref)|",
        yscale="log",
        title="distance to the batch-LS fit (batch-ls: 0)",
    )
    ax["solves"].set(
        ylabel="forward solves per load step",
        yscale="log",
        title="cost: solves per step",
    )
    ax["wall"].set(ylabel="wall seconds per load step", yscale="log",
                   title="cost: wall time per step (shared machine)")  # fmt: skip
    for a in axes.flat:
        a.set_xticks(sorted(table["p"].unique()))
        a.set_xlabel(p_label)
    ax["incl"].legend(fontsize=7)
    ax["solves"].legend(fontsize=6, loc="center left")
    fig.suptitle(
        f"Stiff inclusion ({STIFFER:g} E_true, 5% of the volume): "
        f"regional E and cost against p"
    )
    fig.tight_layout()
    fig.savefig(path, dpi=110)


def show(table: pd.DataFrame) -> None:
    """Print the table, numbers to 4 significant digits."""
    with pd.option_context("display.width", 200):
        print(table.to_string(index=False, float_format="{:.4g}".format))


if __name__ == "__main__":
    jobs = {"type": int, "default": 1, "help": "worker processes"}
    _cli.main(
        __doc__, "results/inclusion", compute, plot, "heterogeneous_inclusion",
        printed=show, csv=True, options={"jobs": jobs},
    )  # fmt: skip
