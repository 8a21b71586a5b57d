"""Reproduces Figs. 3 and 4: the effective E depends on direction and strength.

The study's 510-node model (here 20x4x4, 525 nodes) follows quasi-static paths
in which the end traction grows, in five directions (stretching, bending in y
and z, mixed). Two
views of its effective Young's modulus per load step:

- the RO-UKF's estimate from sparse noisy marker data (the study's Fig. 3), as
  a mean over seeds;
- the best constant E at each load level, fitted noise-free on the whole
  shape-error grid (:func:`idbench.calibrate.effective.effective_path`): what the filter
  would track with perfect data.

Fig. 4 shows the same per-level values as a heat map over the positions the
end-face centre reaches.

Run ``python studies/fig3_fig4_effective_stiffness.py [--quick] [--out DIR]``.
"""

from __future__ import annotations

from pathlib import Path

import _cli
import numpy as np
import pandas as pd

from idbench import CompareConfig, effective_path
from idbench.run.compare import plan
from idbench.run.session import Session

FULL = {
    "meshes": ("20x4x4",),
    "truth_mesh": "80x11x11",
    "estimators": ("ro-ukf",),
    "scenarios": ("stretch-x", "mixed-30", "mixed-60", "bend-y", "bend-z"),
    "seeds": 3,
    "obs_every": (1,),  # the filter sees every load step, as in the study's Fig. 3
}
"""The comparison at full size: the study's 510-node model, truth about 11,700."""
QUICK = {
    "meshes": ("8x2x2",),
    "truth_mesh": "24x4x4",
    "scenarios": ("stretch-x", "bend-y"),
    "seeds": 1,
    "steps": 6,
}


def compute(quick: bool = False, out: str | Path | None = None) -> pd.DataFrame:
    """Per (scenario, step): load, truth tip displacement, effective and RO-UKF E.

    Columns: scenario, step, load (fraction k/K of the end traction), tip_x/y/z (truth
    displacement of the end-face centre, m), E_eff (best constant E at this
    load level), E_ukf and E_ukf_sd (RO-UKF mean and spread over seeds),
    E_ref (batch least squares over the whole path), E_true, and the ratios
    ``eff_ratio = E_eff / E_true`` and ``ukf_ratio = E_ukf / E_true``.
    """
    config = _cli.config(quick, FULL, QUICK)
    _, ok, traces = _cli.runs(config, out)
    traces = traces.merge(ok[["run_id", "scenario", "E_ref"]], on="run_id")
    truth = ("load", "tip_x", "tip_y", "tip_z")  # the same for every seed
    ukf = _cli.over_seeds(
        traces,
        ["scenario", "step"],
        sd=("E_ukf",),
        first=truth,
        E_ukf="E",
        E_ref="E_ref",
    )
    eff = _effective(config)
    table = ukf.merge(eff, on=["scenario", "step"])
    E_true = float(ok["E_true"].iloc[0])
    table["E_true"] = E_true
    table["eff_ratio"] = table["E_eff"] / E_true
    table["ukf_ratio"] = table["E_ukf"] / E_true
    return table


def _effective(config: CompareConfig) -> pd.DataFrame:
    """Best constant E per load level on the whole grid, noise-free."""
    session = Session()
    rows = []
    for spec in plan(config, session).runs:
        if spec.seed != 0:
            continue
        truth = session.truth(spec)
        model = session.model(spec, spec.mesh, role="effective")
        path = effective_path(model, truth.grid, session.theta_true(spec))
        for k in range(1, model.n_steps + 1):
            rows.append(
                {
                    "scenario": spec.scenario,
                    "step": k,
                    "E_eff": path.theta[k - 1, 0],
                    "rms": path.residual[k - 1],
                }
            )
    return pd.DataFrame(rows)


def plot(table: pd.DataFrame, path: Path) -> None:
    """Fig. 3 (E against step) and Fig. 4 (heat map over tip positions)."""
    import matplotlib.pyplot as plt
    from matplotlib.tri import Triangulation

    fig, (ax3, ax4) = plt.subplots(1, 2, figsize=(11, 4.2))
    groups = table.groupby("scenario")
    for (name, df), color in zip(groups, plt.cm.tab10.colors, strict=False):
        ax3.plot(df["step"], df["ukf_ratio"], "-o", ms=3, color=color, label=name)
        ax3.plot(df["step"], df["eff_ratio"], "--", color=color)
    ax3.axhline(1.0, color="k", lw=0.8)
    ax3.set(
        xlabel="load step",
        ylabel="E / E_true",
        title="Fig. 3: RO-UKF (solid), best constant per level (dashed)",
    )
    ax3.legend(fontsize=8)

    # positions reached by the end-face centre: axial and transverse
    transverse = np.where(
        table["scenario"] == "bend-z", -table["tip_z"], -table["tip_y"]
    )
    x = 1.0 + table["tip_x"] / 0.2  # in beam lengths from the clamp
    y = transverse / 0.2
    levels = np.linspace(table["eff_ratio"].min(), table["eff_ratio"].max(), 12)
    in_plane = (table["scenario"] != "bend-z").to_numpy()
    if in_plane.sum() >= 3 and np.ptp(levels) > 0:
        tri = Triangulation(x[in_plane], y[in_plane])
        values = table["eff_ratio"][in_plane]
        ax4.tricontourf(tri, values, levels=levels, cmap="viridis")
    sc = ax4.scatter(
        x, y, c=table["eff_ratio"], cmap="viridis", vmin=levels[0], vmax=levels[-1],
        edgecolors="k", linewidths=0.3, s=22,
    )  # fmt: skip
    fig.colorbar(sc, ax=ax4, label="best constant E / E_true")
    ax4.set(
        xlabel="tip x position / L",
        ylabel="tip transverse displacement / L (-y; -z for bend-z)",
        title="Fig. 4: effective E over the tip positions reached",
    )
    fig.tight_layout()
    fig.savefig(path, dpi=110)


def show(table: pd.DataFrame) -> None:
    """Print the table (4 decimals) and each scenario's range of the ratios."""
    with pd.option_context("display.width", 160, "display.max_rows", 200):
        _cli.show(table.round(4))
    summary = table.groupby("scenario")[["eff_ratio", "ukf_ratio"]].agg(
        ["first", "last", "min", "max"]
    )
    print(summary.round(3).to_string())


if __name__ == "__main__":
    name = "fig3_fig4_effective_stiffness"
    _cli.main(__doc__, "results/fig3_fig4", compute, plot, name, printed=show)
