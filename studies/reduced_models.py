"""Reproduces the resolution axis with reduced fine meshes: the liver and the kidney.

The organ's question, on its own resolution: coarse meshes are stiff, so the
E they identify is low; a fine mesh is right but slow. A reduced model of the
fine mesh (``--meshes rom:16000:40``: POD of the body's ``[design]`` paths,
Galerkin projection, ECSW hyper-reduction; :mod:`idbench_fem.models.reduced`)
runs at a cost set by its modes and sampled elements, not by the mesh. For
each shipped organ and its manipulation (the liver's grasp-lift, p = 1; the
kidney's grasp-pole, p = 2), one comparison against the 16,000-node truth
(the full fine model, never a reduced one) with the RO-UKF on

- coarse meshes (about 500, 1,000 and 2,000 nodes);
- reduced models of the 4,000- and 16,000-node meshes;
- the full 16,000-node model itself (the truth mesh: the reference estimate,
  ``E_full``, that a reduction of it should reproduce),

gives one row per mesh: E / E_true (each parameter), E / E_full, the rate
(1 / the larger of the median and the mean wall time of a step), the shape
error, and for reduced models their modes, sampled elements, offline cost
(fine paths and steps of the design) and the largest fine residual at the
lifted state measured in the runs (``reduction_residual``, relative to the
load) and the error it estimates (``reduction_error_estimate``, one Jacobi
step, a share of the peak displacement). A second table
scores each reduction against the full fine model on manipulations and
moduli its design did not hold: the largest nodal displacement error over
the path as a share of the peak displacement (``reduction_error``).

Run ``python studies/reduced_models.py [--quick] [--out DIR]`` (full size:
the designs' fine paths take about 40 min per organ on one core the first
time, then come from the cache).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import _cli
import numpy as np
import pandas as pd

import idbench
from idbench import CompareConfig, ModelSpec, Scenario, compare

# Parameters (full size)
ORGANS = {"liver": "grasp-lift", "kidney": "grasp-pole"}
COARSE = ("500", "1000", "2000")
REDUCED = ("rom:4000:40", "rom:16000:40", "rom:16000:60")
TRUTH = "16000"
PRIORS = {"liver": (2000.0, 2000.0), "kidney": (3000.0, 3000.0)}
SEEDS = 3
STEPS = 20
NOISE = 1e-4  # m
UNSEEN = {"liver": ("grasp-lift", "lateral-push", "sag-90"),
          "kidney": ("grasp-pole", "probe-press", "sag")}  # fmt: skip
"""The manipulations a reduction is scored on (none is a design path)."""
MODULI = (1.0, 0.6)
"""Moduli the reductions are scored at, as multiples of the true ones."""

QUICK = {
    "organs": ("liver",),
    "coarse": ("200",),
    "reduced": ("rom:1000:30",),
    "truth": "1000",
    "steps": 6,
    "unseen": {"liver": ("grasp-lift",)},
    "moduli": (1.0,),
    "seeds": 1,
}


def _settings(quick: bool, **given: Any) -> dict:
    full = {"organs": tuple(ORGANS), "coarse": COARSE, "reduced": REDUCED,
            "truth": TRUTH, "steps": STEPS, "unseen": UNSEEN,
            "moduli": MODULI, "seeds": SEEDS}  # fmt: skip
    chosen = {k: v for k, v in given.items() if v}  # the command line's
    return {**full, **(QUICK if quick else {}), **chosen}


def compute(
    quick: bool = False, out: str | Path | None = None, **given: Any
) -> pd.DataFrame:
    """One row per (organ, mesh): identified moduli, rate, the reduction's size.

    Columns: ``organ``, ``mesh``, ``kind`` (coarse, reduced, full),
    ``model_nodes``, ``modes``, ``elements``, ``fine_paths``,
    ``fine_steps``, per parameter ``x``: ``x_ratio`` (x / x_true) and
    ``x_vs_full`` (x / the full fine model's), ``rate_hz``,
    ``shape_error_mm`` (mm per grid point, last step), ``cover95`` (the
    share of runs whose 95% interval of the first parameter holds its true
    value), ``tre_mm`` (hidden targets, last step) and
    ``reduction_residual``, ``reduction_error_estimate`` (the largest of the
    runs). ``given``: settings that replace the study's (``organs``,
    ``truth``, ``reduced``, ``coarse``, ``seeds``).
    """
    s = _settings(quick, **given)
    tables = []
    for organ in s["organs"]:
        meshes = (*s["coarse"], *s["reduced"], s["truth"])
        config = CompareConfig(
            model="solid", scenarios=(ORGANS[organ],), meshes=meshes,
            truth_mesh=s["truth"], estimators=("ro-ukf",), seeds=s["seeds"],
            steps=s["steps"], noise=(NOISE,), prior=PRIORS[organ],
            model_settings={"solid": {"body": organ, "reference": s["truth"]}},
        )  # fmt: skip
        folder = None if out is None else Path(out) / organ
        runs, traces = compare(config, folder, jobs=1)
        tables.append(_table(organ, runs, traces, s["truth"]))
    return pd.concat(tables, ignore_index=True)


def _table(
    organ: str, runs: pd.DataFrame, traces: pd.DataFrame, truth: str
) -> pd.DataFrame:
    ok = runs[runs["status"] == "ok"].copy()
    names = [c.removesuffix("_true") for c in ok.columns if c.endswith("_true")]
    names = [n for n in names if f"{n}_final" in ok]
    steps = traces.groupby("run_id")["wall_s"].agg(["median", "mean"])
    ok["rate_hz"] = 1.0 / ok["run_id"].map(steps.max(axis=1))
    rows = []
    full = ok[ok["mesh"] == truth]
    for mesh, df in ok.groupby("mesh", sort=False):
        nodes = int(df["model_nodes"].iloc[0])
        row = {"organ": organ, "mesh": mesh, "model_nodes": nodes}
        reduced = str(mesh).startswith("rom:")
        row["kind"] = "full" if mesh == truth else "reduced" if reduced else "coarse"
        for n in names:
            row[f"{n}_ratio"] = float((df[f"{n}_final"] / df[f"{n}_true"]).mean())
            if len(full):
                row[f"{n}_vs_full"] = float(
                    df[f"{n}_final"].mean() / full[f"{n}_final"].mean()
                )
        row["rate_hz"] = float(df["rate_hz"].mean())
        row["shape_error_mm"] = 1000.0 * float(df["shape_error_mean_final"].mean())
        cover = f"{names[0]}_cover95_true"
        row["cover95"] = float(df[cover].mean()) if cover in df else np.nan
        row["tre_mm"] = float(df["tre_final_mm"].mean()) if "tre_final_mm" in df \
            else np.nan
        for column in ("reduction_residual", "reduction_error_estimate"):
            if column in df:
                row[column] = float(df[column].max())
        rows.append(row)
    table = pd.DataFrame(rows)
    return _sizes(organ, table)


def _sizes(organ: str, table: pd.DataFrame) -> pd.DataFrame:
    """The reductions' modes, sampled elements and offline cost (from the cache)."""
    for i, r in table.iterrows():
        if r["kind"] != "reduced":
            continue
        model = _model(organ, ORGANS[organ], str(r["mesh"]), 2)
        red = model.reduction
        table.loc[i, "modes"] = red.modes
        table.loc[i, "elements"] = len(red.elements)
        table.loc[i, "fine_paths"] = red.info["fine_paths"]
        table.loc[i, "fine_steps"] = red.info["fine_steps"]
    return table


def _model(organ: str, manipulation: str, mesh: str, steps: int):
    load = {"body": organ, "manipulation": manipulation}
    fine = mesh.split(":")[1] if mesh.startswith("rom:") else mesh
    spec = ModelSpec(mesh, Scenario(manipulation, load), steps, 2,
                     {"body": organ, "reference": fine})  # fmt: skip
    return idbench.build_registry().model("solid")(spec)


def reduction_errors(quick: bool = False, **given: Any) -> pd.DataFrame:
    """Each reduction against the full fine model on paths outside its design.

    One row per (organ, reduction, manipulation, modulus multiple):
    ``reduction_error`` (the largest nodal displacement error over the path,
    over the peak nodal displacement of the full model), ``peak_mm``,
    ``reduction_residual`` and ``reduction_error_estimate`` (the largest
    measured).
    """
    s = _settings(quick, **given)
    rows = []
    for organ in s["organs"]:
        for manipulation in s["unseen"][organ]:
            for mesh in s["reduced"]:
                fine_spec = mesh.split(":")[1]
                full = _model(organ, manipulation, fine_spec, s["steps"])
                rom = _model(organ, manipulation, mesh, s["steps"])
                for scale in s["moduli"]:
                    theta = scale * np.array(full.parameters.default)
                    U = idbench.simulate_truth(full, theta).states
                    n = U.shape[0]
                    peak = np.linalg.norm(U.reshape(n, -1, 3), axis=2).max()
                    q, worst = rom.reset(), 0.0
                    for k in range(1, n + 1):
                        q = rom.step(theta, k, q)
                        d = (rom.lift(q) - U[k - 1]).reshape(-1, 3)
                        worst = max(worst, float(np.linalg.norm(d, axis=1).max()))
                    rows.append({
                        "organ": organ, "reduction": mesh, "manipulation": manipulation,
                        "moduli": scale, "reduction_error": worst / peak,
                        "peak_mm": 1000.0 * peak,
                        **rom.diagnostics(),
                    })  # fmt: skip
    return pd.DataFrame(rows)


def markdown(table: pd.DataFrame) -> str:
    """The docs' table: one row per (organ, mesh)."""
    names = sorted({c[: -len("_ratio")] for c in table.columns if c.endswith("_ratio")})
    head = ["organ", "mesh", "nodes", "modes / elements"]
    head += [f"{n} / true" for n in names] + [f"{n} / full" for n in names]
    head += ["95% covers true", "TRE (mm)", "rate (Hz)", "shape error (mm/pt)",
             "fine residual", "error estimate"]  # fmt: skip
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for _, r in table.iterrows():
        size = (f"{int(r['modes'])} / {int(r['elements']):,}"
                if r["kind"] == "reduced" else "")  # fmt: skip
        cells = [str(r["organ"]), f"`{r['mesh']}`", f"{int(r['model_nodes']):,}", size]
        cells += [_num(r.get(f"{n}_ratio")) for n in names]
        cells += [_num(r.get(f"{n}_vs_full")) for n in names]
        cells += [_num(r.get("cover95"), "{:.2f}"), _num(r.get("tre_mm"), "{:.3g}")]
        cells += [f"{r['rate_hz']:.3g}", f"{r['shape_error_mm']:.3g}",
                  _num(r.get("reduction_residual"), "{:.2g}"),
                  _num(r.get("reduction_error_estimate"), "{:.2g}")]  # fmt: skip
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)


def markdown_errors(errors: pd.DataFrame) -> str:
    """The docs' table of each reduction on paths outside its design."""
    head = ["organ", "reduction", "manipulation", "moduli (x true)",
            "error / peak displacement", "peak (mm)", "error estimate"]  # fmt: skip
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for _, r in errors.iterrows():
        cells = [str(r["organ"]), f"`{r['reduction']}`", str(r["manipulation"]),
                 f"{r['moduli']:g}", f"{100 * r['reduction_error']:.2f}%",
                 f"{r['peak_mm']:.3g}",
                 _num(r.get("reduction_error_estimate"), "{:.2%}")]  # fmt: skip
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)


def _num(value: object, fmt: str = "{:.3f}") -> str:
    if value is None or not np.isfinite(float(value)):  # type: ignore[arg-type]
        return ""
    return fmt.format(float(value))  # type: ignore[arg-type]


def plot(table: pd.DataFrame, path: Path) -> None:
    import matplotlib.pyplot as plt

    organs = list(dict.fromkeys(table["organ"]))
    fig, axes = plt.subplots(1, len(organs), figsize=(6.5 * len(organs), 4.4),
                             squeeze=False)  # fmt: skip
    markers = {"coarse": "o", "reduced": "s", "full": "*"}
    for ax, organ in zip(axes[0], organs, strict=True):
        df = table[table["organ"] == organ]
        first = next(c for c in df.columns if c.endswith("_ratio"))
        for kind, part in df.groupby("kind"):
            ax.scatter(part["rate_hz"], part[first], marker=markers[str(kind)],
                       s=60, label=str(kind))  # fmt: skip
            for _, r in part.iterrows():
                ax.annotate(str(r["mesh"]), (r["rate_hz"], r[first]), fontsize=7)
        ax.axhline(1.0, color="k", lw=0.8)
        ax.set(xscale="log", xlabel="RO-UKF rate (Hz, this machine)",
               ylabel=f"{first[: -len('_ratio')]} / true", title=organ)  # fmt: skip
        ax.legend(fontsize="small")
    fig.tight_layout()
    fig.savefig(path, dpi=110)


def main() -> None:
    p = _cli.parser(__doc__, "results/reduced")
    p.add_argument("--organs", type=lambda v: tuple(v.split(",")),
                   help=f"default {','.join(ORGANS)}")  # fmt: skip
    p.add_argument("--truth", help=f"the fine (truth) mesh, default {TRUTH}")
    p.add_argument("--reduced", type=lambda v: tuple(v.split(",")),
                   help=f"reduced models, default {','.join(REDUCED)}")  # fmt: skip
    p.add_argument("--seeds", type=int, help=f"default {SEEDS}")
    args = p.parse_args()
    given = {"organs": args.organs, "truth": args.truth, "reduced": args.reduced,
             "seeds": args.seeds}  # fmt: skip
    table = compute(args.quick, args.out, **given)
    errors = reduction_errors(args.quick, **given)
    args.out.mkdir(parents=True, exist_ok=True)
    table.to_csv(args.out / "reduced_models.csv", index=False)
    errors.to_csv(args.out / "reduction_errors.csv", index=False)
    print(markdown(table))
    print(errors.to_string(index=False))
    if not args.quick:
        _cli.docs_data("reduced_models", table)
        _cli.docs_data("reduction_errors", errors)
    plot(table, args.out / "reduced_models.png")


if __name__ == "__main__":
    main()
