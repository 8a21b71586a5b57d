"""Reproduces Fig. 2: identified E against model mesh resolution (bending).

Coarse P1 meshes are stiffer than the truth, so the identified modulus is low
and approaches E_true from below as the model mesh is refined. The RO-UKF is
the study's estimator; the others run alongside.

Run ``python studies/fig2_stiffness_vs_resolution.py [--quick] [--out DIR]``.
"""

from __future__ import annotations

from pathlib import Path

import _cli
import pandas as pd

SCENARIO = "bend-y"
FULL = {
    "meshes": ("9x2x2", "14x3x3", "20x4x4", "30x5x5", "40x6x6", "60x8x8"),
    "truth_mesh": "80x11x11",
    "estimators": ("ro-ukf", "rls", "batch-ls"),
    "scenarios": (SCENARIO,),
    "seeds": 3,
}
"""The comparison at full size: the study's resolutions, truth about 11,000 nodes."""
QUICK = _cli.QUICK


def compute(quick: bool = False, out: str | Path | None = None) -> pd.DataFrame:
    """Identified E per (model nodes, estimator), mean and std over seeds."""
    _, ok, _ = _cli.runs(_cli.config(quick, FULL, QUICK), out)
    by = ["model_nodes", "estimator"]
    table = _cli.over_seeds(
        ok, by, sd=("E",), first=("E_true",), E="E_final", E_ref="E_ref"
    )
    table["ratio"] = table["E"] / table["E_true"]
    return table


def plot(table: pd.DataFrame, path: Path) -> None:
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6, 4))
    for est, df in table.groupby("estimator"):
        ax.errorbar(
            df["model_nodes"],
            df["E"],
            yerr=df["E_sd"].fillna(0),
            marker="o",
            label=str(est),
        )
    ax.axhline(table["E_true"].iloc[0], color="k", ls="--", label="E_true")
    ax.set(
        xscale="log",
        xlabel="model nodes",
        ylabel="identified E (Pa)",
        title=f"Fig. 2: identified E against resolution ({SCENARIO})",
    )
    ax.legend()
    fig.savefig(path, dpi=110)


if __name__ == "__main__":
    _cli.main(__doc__, "results/fig2", compute, plot, "fig2_stiffness_vs_resolution")
