"""Point clouds against markers on the liver (and the kidney).

For each body (examples/liver; examples/kidney with ``--bodies
liver,kidney``: its tumour, parenchyma and tumour E identified) one
comparison whose ``observe`` axis holds the baseline (8 markers) and
depth-camera variants (:mod:`idbench.observe.cloud`): a base cloud
(:data:`BASE`, ``cloud-base``) and, from it, one realism knob varied at a
time: points per frame (:data:`POINTS`), outlier fraction (:data:`OUTLIERS`)
and noise along the ray (:data:`NOISE`), for :data:`ESTIMATORS` and
:data:`SEEDS` noise seeds (each seed draws new marker noise and new clouds).
The table has, per (body, estimator, observation, seed): E / E_true (the
first parameter), the shape error (mm per grid point) and the TRE at the
body's hidden targets (mm), all at the last step, and the forward solves;
:func:`against_markers` compares each observation with the markers of the
same seed (the target: "within 5%").

Run ``python studies/point_clouds.py [--quick] [--out DIR] [--bodies ...]``;
``--quick``: the liver only, small meshes, two knob values each, the RO-UKF,
one seed. A full run also writes each body's summary to
``docs/results/data/point_clouds_<body>.csv``, the numbers of the point
clouds' results page (its table: :func:`markdown`), and each comparison's
report (report.html, with the 3D view) in ``DIR/BODY/ESTIMATOR``.
"""

from __future__ import annotations

import itertools
from pathlib import Path
from typing import Any

import _cli
import numpy as np
import pandas as pd

from idbench.plan.config import CompareConfig
from idbench.run.compare import compare

BODIES = {"liver": "grasp-lift", "kidney": "grasp-pole"}
"""Each body's manipulation."""
STUDIED = ("liver",)
"""The bodies of a full run (``--bodies`` changes it)."""
MESHES = ("1000",)
TRUTH = "4000"
ESTIMATORS: tuple[str, ...] = ("ro-ukf", "etkf")
"""RO-UKF and the ETKF (the EnKF solves an m x m system a step)."""
DENSE_LIMIT = 1000
"""Ensemble filters keep a dense m x m innovation covariance (its NIS a dense
solve a step): they skip clouds of more points (minutes a step at 5,000)."""
ENSEMBLES = ("enkf", "etkf")
SEEDS = 3
STEPS = 20
MARKERS = 8
MARKER_NOISE = 1e-4  # m
BASE = {"points": 1000, "noise": 1e-3, "outliers": 0.05, "holes": 0.1}
POINTS = (50, 200, 1000)
"""At most the distinct pixels the default camera sees of the liver (about
1,300): more points than that are refused."""
OUTLIERS = (0.0, 0.05, 0.1, 0.2)
NOISE = (5e-4, 1e-3, 2e-3)  # m, along the ray
KNOBS = ("points", "outliers", "noise")
METRICS = ("E_ratio", "shape_error_mm", "tre_mm")

QUICK: dict[str, Any] = {
    "bodies": ("liver",),
    "meshes": ("300",),
    "truth": "600",
    "estimators": ("ro-ukf",),
    "seeds": 1,
    "steps": 4,
    "points": (50, 200),
    "outliers": (0.0, 0.2),
    "noise": (1e-3,),
}


def variants(
    points: tuple[int, ...], outliers: tuple[float, ...], noise: tuple[float, ...]
) -> tuple[dict[str, dict[str, Any]], dict[str, tuple[str, float]]]:
    """The ``[observe.NAME]`` tables and, per name, the (knob, value) it varies.

    The base cloud is ``cloud-base`` (knob ``"base"``); a knob value equal to
    the base's is that run, not a copy.
    """
    tables: dict[str, dict[str, Any]] = {"cloud-base": {"kind": "cloud", **BASE}}
    knobs: dict[str, tuple[str, float]] = {"markers": ("baseline", 0.0)}
    knobs["cloud-base"] = ("base", 0.0)
    for knob, values in zip(KNOBS, (points, outliers, noise), strict=True):
        for v in values:
            if v == BASE[knob]:
                continue
            name = f"cloud-{knob}-{v:g}"
            tables[name] = {"kind": "cloud", **BASE, knob: v}
            knobs[name] = (knob, float(v))
    return tables, knobs


def compute(
    quick: bool = False,
    out: str | Path | None = None,
    bodies: str | tuple[str, ...] | None = None,
) -> pd.DataFrame:
    """One row per (body, estimator, observation, seed): E ratio, shape, TRE."""
    q = QUICK if quick else {}
    tables, knobs = variants(
        q.get("points", POINTS), q.get("outliers", OUTLIERS), q.get("noise", NOISE)
    )
    if isinstance(bodies, str):
        bodies = tuple(b.strip() for b in bodies.split(","))
    rows = []
    for body, estimator in itertools.product(
        bodies or q.get("bodies", STUDIED), q.get("estimators", ESTIMATORS)
    ):
        mesh = q.get("truth", TRUTH)
        observed = tuple(
            name for name in knobs
            if estimator not in ENSEMBLES
            or tables.get(name, {}).get("points", 0) <= DENSE_LIMIT
        )  # fmt: skip
        config = CompareConfig(
            model="solid",
            model_settings={"solid": {"body": body, "reference": mesh}},
            scenarios=(BODIES[body],),
            meshes=q.get("meshes", MESHES),
            truth_mesh=mesh,
            estimators=(estimator,),
            seeds=q.get("seeds", SEEDS),
            steps=q.get("steps", STEPS),
            obs_every=(1,),
            obs_points=(MARKERS,),
            noise=(MARKER_NOISE,),
            observe=observed,
            observe_settings={n: t for n, t in tables.items() if n in observed},
        )
        folder = None if out is None else Path(out) / body / estimator
        runs, _ = compare(config, folder)
        _cli.report(folder, quick)  # report.html, with the 3D view
        first = next(c[: -len("_true")] for c in runs.columns if c.endswith("_true"))
        for _, r in runs.iterrows():
            knob, value = knobs[r["observe"]]
            rows.append({
                "body": body, "estimator": r["estimator"], "observe": r["observe"],
                "seed": int(r["seed"]), "knob": knob, "value": value,
                "status": r["status"],
                "E_ratio": r[f"{first}_final"] / r[f"{first}_true"],
                "shape_error_mm": 1000.0 * r["shape_error_mean_final"],
                "tre_mm": r.get("tre_final_mm", float("nan")),
                "n_solves": r["n_solves"],
            })  # fmt: skip
    return pd.DataFrame(rows)


def against_markers(table: pd.DataFrame) -> pd.DataFrame:
    """Per (body, estimator, observation): means over seeds and the worst seed.

    ``dE_pct`` and ``dshape_pct`` are, per seed, 100 (x / x_markers - 1) for
    the identified E and the final shape error against the 8-marker run of
    the same seed; the table has their mean and largest magnitude over seeds
    (``*_worst``), and ``within_5pct`` whether every seed is within 5% on
    both.
    """
    ok = table[table["status"] == "ok"]
    keys = ["body", "estimator", "seed"]
    base = ok[ok["observe"] == "markers"].set_index(keys)
    rows = []
    for (body, est, name), df in ok.groupby(
        ["body", "estimator", "observe"], sort=False
    ):
        ref = base.loc[[(body, est, s) for s in df["seed"]]]
        dE = 100 * (df["E_ratio"].to_numpy() / ref["E_ratio"].to_numpy() - 1)
        dS = 100 * (
            df["shape_error_mm"].to_numpy() / ref["shape_error_mm"].to_numpy() - 1
        )
        rows.append({
            "body": body, "estimator": est, "observe": name,
            "knob": df["knob"].iloc[0], "value": df["value"].iloc[0],
            "seeds": len(df),
            "E_ratio": df["E_ratio"].mean(), "E_ratio_sd": df["E_ratio"].std(),
            "shape_error_mm": df["shape_error_mm"].mean(),
            "tre_mm": df["tre_mm"].mean(),
            "dE_pct": dE.mean(), "dE_pct_worst": dE[np.argmax(np.abs(dE))],
            "dshape_pct": dS.mean(), "dshape_pct_worst": dS[np.argmax(np.abs(dS))],
            "within_5pct": bool((np.abs(dE) <= 5).all() and (np.abs(dS) <= 5).all()),
            "n_solves": df["n_solves"].mean(),
        })  # fmt: skip
    return pd.DataFrame(rows)


def label(observe: str, knob: str, value: float) -> str:
    """What the results page calls an observation (the base cloud in bold)."""
    if observe == "markers":
        return f"{MARKERS} markers"
    if knob == "base":
        return (
            f"**cloud: {BASE['points']:,} pts, {1000 * BASE['noise']:g} mm, "
            f"{100 * BASE['outliers']:g}% outliers**"
        )
    if knob == "points":
        return f"{int(value):,} points"
    if knob == "outliers":
        return f"{100 * value:g}% outliers"
    if knob == "noise":
        return f"{1000 * value:g} mm noise"
    return observe


def _pct(mean: float, worst: float) -> str:
    def text(x: float) -> str:
        return f"{x:+,.0f}%" if abs(x) >= 1000 else f"{x:+.1f}%"

    return text(mean) if text(mean) == text(worst) else f"{text(mean)} ({text(worst)})"


def markdown(summary: pd.DataFrame) -> str:
    """The results page's table of one body: :func:`against_markers`' rows.

    One row per (estimator, observation) in the summary's order: E / E_true
    and its sd over seeds, shape error and TRE (mm), the change in E and in
    shape error against the markers (mean and worst seed) and whether every
    seed is within 5% of them.
    """
    head = ["estimator", "observation", "E / E_true", "sd over seeds",
            "shape error (mm)", "TRE (mm)", "dE vs markers, mean (worst)",
            "d shape, mean (worst)", "within 5%, every seed"]  # fmt: skip
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for _, r in summary.iterrows():
        base = r["observe"] == "markers"
        within = "yes" if bool(r["within_5pct"]) else "no"
        if r["knob"] == "base":
            within = f"**{within}**"
        cells = [
            str(r["estimator"]),
            label(r["observe"], r["knob"], float(r["value"])),
            f"{r['E_ratio']:.3f}",
            f"{r['E_ratio_sd']:.3f}",
            f"{r['shape_error_mm']:.3g}",
            f"{r['tre_mm']:.3g}",
            "-" if base else _pct(r["dE_pct"], r["dE_pct_worst"]),
            "-" if base else _pct(r["dshape_pct"], r["dshape_pct_worst"]),
            "-" if base else within,
        ]
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def plot(table: pd.DataFrame, path: Path) -> None:
    """Each metric against each knob (mean and range over seeds); markers dotted."""
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(len(METRICS), len(KNOBS), figsize=(13, 9), squeeze=False)
    ok = table[table["status"] == "ok"]
    for (body, est), df in ok.groupby(["body", "estimator"], sort=False):
        base = df[df["observe"] == "markers"]
        cbase = df[df["knob"] == "base"]
        for j, knob in enumerate(KNOBS):
            d = df[df["knob"] == knob]
            if not cbase.empty:
                d = pd.concat([d, cbase.assign(value=float(BASE[knob]))])
            if knob == "noise":  # mm on the axis
                d = d.assign(value=1000.0 * d["value"])
            g = d.groupby("value")
            for i, m in enumerate(METRICS):
                ax = axes[i][j]
                mean, lo, hi = g[m].mean(), g[m].min(), g[m].max()
                (line,) = ax.plot(mean.index, mean, marker="o", label=f"{body}, {est}")
                ax.fill_between(mean.index, lo, hi, color=line.get_color(), alpha=0.15)
                if not base.empty:
                    ax.axhline(base[m].mean(), color=line.get_color(), ls=":", lw=1)
                unit = " (mm along the ray)" if knob == "noise" else ""
                ax.set(xlabel=f"cloud {knob}{unit}", ylabel=m)
                if knob == "points":
                    ax.set_xscale("log")
    axes[0][0].legend(fontsize="x-small")
    fig.suptitle(
        "clouds (mean, band: range over seeds) against 8 markers (dotted), last "
        "step; one knob varied from the base cloud"
    )
    fig.tight_layout()
    fig.savefig(path, dpi=110)


if __name__ == "__main__":
    args = _cli.parser(__doc__, "results/point_clouds")
    args.add_argument("--bodies", default=None, help="e.g. liver,kidney")
    ns = args.parse_args()
    table = compute(ns.quick, ns.out, ns.bodies)
    ns.out.mkdir(parents=True, exist_ok=True)
    table.to_csv(ns.out / "point_clouds.csv", index=False)
    summary = against_markers(table)
    summary.to_csv(ns.out / "point_clouds_summary.csv", index=False)
    if not ns.quick:  # the numbers of docs/results/point-clouds.md
        for body, rows in summary.groupby("body", sort=False):
            _cli.docs_data(f"point_clouds_{body}", rows)
    pd.set_option("display.width", 250)
    print(table.to_string(index=False))
    print(summary.to_string(index=False))
    plot(table, ns.out / "point_clouds.png")
