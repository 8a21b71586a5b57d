"""Reproduces Fig. 5: shape error against mesh resolution, direct vs assimilated.

The shape error (docs/design.md section 5) is the sum over a 20 x 4 x 4 grid inside
the beam of the distances between the grid moved by the model and by the truth,
at the last load step. "Direct" runs the model mesh with E_true and no data;
"ro-ukf" is the filter's own (state-corrected) estimate of the beam at the end
of the path; "rls" is its forward simulation with the evolving estimate, i.e.
close to re-running the path with the identified, effective E. Expected: the
error falls with resolution, and assimilation reduces it markedly on coarse
meshes, where E_true is far from the mesh's effective modulus.

Run ``python studies/fig5_shape_error.py [--quick] [--out DIR]``.
"""

from __future__ import annotations

from pathlib import Path

import _cli
import pandas as pd

SCENARIO = "bend-y"
FULL = {
    "meshes": ("9x2x2", "14x3x3", "20x4x4", "30x5x5", "40x6x6"),
    "truth_mesh": "80x11x11",
    "estimators": ("ro-ukf", "rls"),
    "scenarios": (SCENARIO,),
    "seeds": 3,
}
"""The comparison at full size: about 90 to 2,000 model nodes, truth about 11,700."""
QUICK = _cli.QUICK
DIRECT = "direct (E_true)"


def compute(quick: bool = False, out: str | Path | None = None) -> pd.DataFrame:
    """Final shape error per (model nodes, method), mean and std over seeds.

    ``method`` is an estimator name or ``"direct (E_true)"``; ``shape_error``
    is the paper's sum over the grid (m), ``shape_error_mean`` the mean per
    grid point (m), ``vs_direct`` the ratio to the direct error on that mesh.
    """
    runs, ok, _ = _cli.runs(_cli.config(quick, FULL, QUICK), out)
    assimilated = _cli.over_seeds(
        ok.rename(columns={"estimator": "method"}),
        ["model_nodes", "mesh", "method"],
        sd=("shape_error",),
        count="n_runs",
        shape_error="shape_error_final",
        shape_error_mean="shape_error_mean_final",
        E="E_final",
    )
    # The direct run has no noise and no estimator: one value per mesh.
    direct = (
        runs.dropna(subset=["shape_error_direct"])
        .groupby(["model_nodes", "mesh"])
        .agg(
            shape_error=("shape_error_direct", "first"),
            shape_error_mean=("shape_error_direct_mean", "first"),
            E=("E_true", "first"),
        )
        .reset_index()
        .assign(method=DIRECT, shape_error_sd=0.0, n_runs=1)
    )
    table = pd.concat([direct, assimilated], ignore_index=True)
    base = direct.set_index("model_nodes")["shape_error"]
    table["vs_direct"] = table["shape_error"] / table["model_nodes"].map(base)
    table["model_nodes"] = table["model_nodes"].astype(int)
    return table.sort_values(["method", "model_nodes"]).reset_index(drop=True)[
        [
            "method",
            "mesh",
            "model_nodes",
            "shape_error",
            "shape_error_sd",
            "shape_error_mean",
            "vs_direct",
            "E",
            "n_runs",
        ]
    ]


def plot(table: pd.DataFrame, path: Path) -> None:
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6, 4))
    styles = {
        DIRECT: {"color": "k", "ls": "--", "marker": "s"},
        "ro-ukf": {"color": "C0", "marker": "o", "ms": 8, "mfc": "none"},
        "rls": {"color": "C1", "ls": ":", "marker": "x", "ms": 7},
    }
    for method, df in table.groupby("method", sort=False):
        ax.errorbar(
            df["model_nodes"],
            df["shape_error"],
            yerr=df["shape_error_sd"].fillna(0),
            label=str(method),
            capsize=3,
            **styles.get(str(method), {"marker": "o"}),
        )
    ax.set(
        xscale="log",
        yscale="log",
        xlabel="model nodes",
        ylabel="shape error at last step (m, sum over grid)",
        title=f"Fig. 5: shape error against resolution ({SCENARIO})",
    )
    ax.legend()
    fig.tight_layout()
    fig.savefig(path, dpi=110)


if __name__ == "__main__":
    _cli.main(__doc__, "results/fig5", compute, plot, "fig5_shape_error")
