"""Point clouds against markers and force on the liver and the kidney (issue 27).

For each body (examples/liver, examples/kidney: its tumour, parenchyma and
tumour E identified) and estimator, one comparison whose ``observe`` axis
holds the baselines (8 markers, the tool force) and depth-camera variants
(:mod:`idbench.depth_camera`), each varying one realism knob from a base
cloud (:data:`BASE`): points per frame (:data:`POINTS`), outlier fraction
(:data:`OUTLIERS`) and noise along the ray (:data:`NOISE`). The table has,
per (body, estimator, observation): E / E_true (the first parameter), the
shape error (mm per grid point) and the TRE at the body's hidden targets
(mm), all at the last step, and the forward solves.

Run ``python studies/point_clouds.py [--quick] [--out DIR]``; ``--quick``:
the liver only, small meshes, two knob values each, the RO-UKF.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import _cli
import pandas as pd

from idbench.config import CompareConfig
from idbench.sweep import compare

BODIES = {"liver": "grasp-lift", "kidney": "grasp-pole"}
MESHES = ("1000",)
TRUTH = "4000"
ESTIMATORS: tuple[str, ...] | None = None  # every registered estimator
STEPS = 20
MARKERS = 8
MARKER_NOISE = 1e-4  # m
BASE = {"points": 1000, "noise": 1e-3, "outliers": 0.05, "holes": 0.1}
POINTS = (50, 200, 1000, 5000)
OUTLIERS = (0.0, 0.05, 0.1, 0.2)
NOISE = (5e-4, 1e-3, 2e-3)  # m, along the ray
FORCE_NOISE = 1e-3  # N

QUICK: dict[str, Any] = {
    "bodies": ("liver",),
    "meshes": ("300",),
    "truth": "600",
    "estimators": ("ro-ukf",),
    "steps": 4,
    "points": (50, 200),
    "outliers": (0.0, 0.2),
    "noise": (1e-3,),
}


def variants(
    points: tuple[int, ...], outliers: tuple[float, ...], noise: tuple[float, ...]
) -> tuple[dict[str, dict[str, Any]], dict[str, tuple[str, float]]]:
    """The ``[observe.NAME]`` tables and, per name, the (knob, value) it varies."""
    tables: dict[str, dict[str, Any]] = {"force": {"noise": FORCE_NOISE}}
    knobs: dict[str, tuple[str, float]] = {"markers": ("baseline", 0.0)}
    knobs["force"] = ("baseline", 0.0)
    for knob, values in (("points", points), ("outliers", outliers), ("noise", noise)):
        for v in values:
            name = f"cloud-{knob}-{v:g}"
            tables[name] = {"kind": "cloud", **BASE, knob: v}
            knobs[name] = (knob, float(v))
    return tables, knobs


def compute(quick: bool = False, out: str | Path | None = None) -> pd.DataFrame:
    """One row per (body, estimator, observation): E ratio, shape error, TRE."""
    q = QUICK if quick else {}
    tables, knobs = variants(
        q.get("points", POINTS), q.get("outliers", OUTLIERS), q.get("noise", NOISE)
    )
    rows = []
    for body in q.get("bodies", tuple(BODIES)):
        mesh = q.get("truth", TRUTH)
        config = CompareConfig(
            model="solid",
            model_settings={"solid": {"body": body, "reference": mesh}},
            scenarios=(BODIES[body],),
            meshes=q.get("meshes", MESHES),
            truth_mesh=mesh,
            estimators=q.get("estimators", ESTIMATORS),
            seeds=1,
            steps=q.get("steps", STEPS),
            obs_every=(1,),
            obs_points=(MARKERS,),
            noise=(MARKER_NOISE,),
            observe=tuple(knobs),
            observe_settings=tables,
        )
        folder = None if out is None else Path(out) / body
        runs, _ = compare(config, folder)
        first = next(c[: -len("_true")] for c in runs.columns if c.endswith("_true"))
        for _, r in runs.iterrows():
            knob, value = knobs[r["observe"]]
            rows.append({
                "body": body, "estimator": r["estimator"], "observe": r["observe"],
                "knob": knob, "value": value, "status": r["status"],
                "E_ratio": r[f"{first}_final"] / r[f"{first}_true"],
                "shape_error_mm": 1000.0 * r["shape_error_mean_final"],
                "tre_mm": r.get("tre_final_mm", float("nan")),
                "n_solves": r["n_solves"],
            })  # fmt: skip
    return pd.DataFrame(rows)


def plot(table: pd.DataFrame, path: Path) -> None:
    import matplotlib.pyplot as plt

    knobs = ("points", "outliers", "noise")
    metrics = ("E_ratio", "shape_error_mm", "tre_mm")
    fig, axes = plt.subplots(len(metrics), len(knobs), figsize=(13, 9), squeeze=False)
    ok = table[table["status"] == "ok"]
    for (body, est), df in ok.groupby(["body", "estimator"], sort=False):
        base = df[df["observe"] == "markers"]
        for j, knob in enumerate(knobs):
            d = df[df["knob"] == knob].sort_values("value")
            for i, m in enumerate(metrics):
                ax = axes[i][j]
                (line,) = ax.plot(d["value"], d[m], marker="o", label=f"{body}, {est}")
                if not base.empty:
                    ax.axhline(base[m].iloc[0], color=line.get_color(), ls=":", lw=1)
                ax.set(xlabel=f"cloud {knob}", ylabel=m)
                if knob == "points":
                    ax.set_xscale("log")
    axes[0][0].legend(fontsize="x-small")
    fig.suptitle("clouds (dots) against 8 markers (dotted) at the last step")
    fig.tight_layout()
    fig.savefig(path, dpi=110)


if __name__ == "__main__":
    args = _cli.parser(__doc__, "results/point_clouds").parse_args()
    table = compute(args.quick, args.out)
    print(table.to_string(index=False))
    args.out.mkdir(parents=True, exist_ok=True)
    table.to_csv(args.out / "point_clouds.csv", index=False)
    plot(table, args.out / "point_clouds.png")
