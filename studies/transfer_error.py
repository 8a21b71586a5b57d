"""Beyond the paper: identify E on one manipulation, predict another.

The paper warns that the effective modulus of a coarse mesh depends on the
deformation, so a value fitted on one manipulation misleads on another. For
each source load path, the RO-UKF identifies E on the model mesh; that E then
simulates the source's transfer target (``stretch-x`` for bending and mixed
paths, ``bend-y`` for ``stretch-x``) and the shape error at the last step is
compared with two baselines on the same mesh and target: E identified by the
RO-UKF on the target's own data ("fit on target"), and E_true ("direct").
All three are plain forward simulations of the target path with a constant E.

Run ``python studies/transfer_error.py [--quick] [--out DIR]``.
"""

from __future__ import annotations

from pathlib import Path

import _cli
import numpy as np
import pandas as pd

from idbench import simulate_path
from idbench.plan.runspec import RunSpec
from idbench.run.compare import runs_of as expand
from idbench.run.session import Session
from idbench.score import metrics

ESTIMATOR = "ro-ukf"
FULL = {
    "scenarios": ("bend-y", "bend-z", "mixed-30", "mixed-60", "stretch-x"),
    "meshes": ("14x3x3", "20x4x4"),
    "truth_mesh": "80x11x11",
    "estimators": (ESTIMATOR,),
    "seeds": 3,
}
"""The comparison at full size (the sources: its scenarios): the paper's 239-
and 510-node models, truth 11,700 nodes."""
BARS = {
    "transfer_error": "E fitted on source (transfer)",
    "fit_on_target": "E fitted on target",
    "direct": "E_true (direct)",
}

QUICK = {
    "scenarios": ("bend-y", "stretch-x"),
    "meshes": ("8x2x2",),
    "truth_mesh": "24x4x4",
    "seeds": 1,
    "steps": 6,
}


def predict(session: Session, spec: RunSpec, scenario: str, theta: float) -> float:
    """Final-step shape error (sum, m) of ``scenario`` on the run's mesh at E."""
    model = session.model(spec, spec.mesh, scenario, role="metrics")
    truth = session.truth(spec, scenario)
    states = simulate_path(model, np.atleast_1d(theta))
    return metrics.shape_error(model.grid(states[-1]), truth.grid[-1])[0]


def compute(quick: bool = False, out: str | Path | None = None) -> pd.DataFrame:
    """Shape error on the transfer target per (source, model mesh).

    Columns: ``transfer_error`` (E identified on the source), ``fit_on_target``
    (E identified on the target itself, same seed), ``direct`` (E_true), each
    a mean over seeds with ``*_sd``; ``E_source`` and ``E_target`` the mean
    identified moduli; ``transfer_vs_fit`` the ratio of the first two errors.
    """
    config = _cli.config(quick, FULL, QUICK)
    runs, ok, _ = _cli.runs(config, out)
    specs = {s.run_id: s for s in expand(config)}
    ok = ok.set_index(["scenario", "mesh", "seed"])
    session = Session()
    rows = []
    for (source, mesh, seed), run in ok.iterrows():
        target = run["transfer_scenario"]
        if (target, mesh, seed) not in ok.index:
            continue
        E_target = ok.loc[(target, mesh, seed), "E_final"]
        spec = specs[run["run_id"]]
        rows.append(
            {
                "source": source,
                "target": target,
                "mesh": mesh,
                "model_nodes": int(run["model_nodes"]),
                "seed": seed,
                "E_source": run["E_final"],
                "E_target": E_target,
                "transfer_error": run["transfer_error"],
                "fit_on_target": predict(session, spec, target, E_target),
                "direct": run["transfer_error_direct"],
            }
        )
    per_seed = pd.DataFrame(rows)
    columns = ("E_source", "E_target", "transfer_error", "fit_on_target", "direct")
    table = _cli.over_seeds(
        per_seed,
        ["source", "target", "mesh", "model_nodes"],
        sd=("transfer_error", "fit_on_target"),
        count="n_seeds",
        sort=False,
        **{c: c for c in columns},
    )
    table["transfer_vs_fit"] = table["transfer_error"] / table["fit_on_target"]
    table["E_true"] = float(runs["E_true"].iloc[0])
    return table


def plot(table: pd.DataFrame, path: Path) -> None:
    import matplotlib.pyplot as plt

    meshes = list(dict.fromkeys(table["mesh"]))
    fig, axes = plt.subplots(
        1, len(meshes), figsize=(5.5 * len(meshes), 4), sharey=True, squeeze=False
    )
    width = 0.8 / len(BARS)
    for ax, mesh in zip(axes[0], meshes, strict=True):
        df = table[table["mesh"] == mesh]
        x = np.arange(len(df))
        for i, (col, label) in enumerate(BARS.items()):
            sd = df.get(f"{col}_sd")
            ax.bar(
                x + (i - (len(BARS) - 1) / 2) * width,
                df[col],
                width,
                yerr=None if sd is None else sd.fillna(0),
                capsize=2,
                label=label,
            )
        labels = df["source"] + "\n-> " + df["target"]
        ax.set_xticks(x, labels.tolist(), fontsize="small")
        ax.set(
            yscale="log",
            title=f"{mesh} ({int(df['model_nodes'].iloc[0])} nodes)",
        )
    axes[0, 0].set_ylabel("shape error on target, last step (m)")
    axes[0, -1].legend(fontsize="small")
    fig.suptitle(f"Transfer error: identify on one path, predict another ({ESTIMATOR})")
    fig.tight_layout()
    fig.savefig(path, dpi=110)


if __name__ == "__main__":
    _cli.main(__doc__, "results/transfer", compute, plot, "transfer_error")
