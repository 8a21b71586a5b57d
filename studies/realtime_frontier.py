"""Beyond the study: the real-time frontier, shape error against wall time per step.

For every (model mesh, estimator) the shape error reached at the last step
(mean over seeds) is set against the estimator's wall time per load step,
measured on this machine, with the 30 Hz and 60 Hz budgets: the table answers
"which mesh and estimator give the lowest shape error within a real-time
budget" (see :func:`idbench.report.frontier`).

Wall time per step is the estimator's ``update`` time only (the harness's
metrics solves are excluded): the larger of the median step and the total over
the run / K. Filters work evenly and are charged their typical step;
``batch-ls`` with ``refit="end"`` does all its work at step K and is charged
that fit / K, the cost a real-time loop would pay if it spread the fit over the
path (it then still needs one display solve a step, not counted here). The
full UKF runs only where its 2n+1 solves a step fit its ``max_solves`` budget
(default 1500: the 9x2x2 and 14x3x3 meshes); elsewhere it is ``skipped``
and not plotted.
Runs are serial (``jobs=1``) so that timings are not disturbed.

Run ``python studies/realtime_frontier.py [--quick] [--out DIR]``.
"""

from __future__ import annotations

from pathlib import Path

import _cli
import pandas as pd

from idbench import compare
from idbench.report import frontier, frontier_figure

# Parameters (full size: about 90, 240, 525, 1100, 2000 nodes)
MESHES = ("9x2x2", "14x3x3", "20x4x4", "30x5x5", "40x6x6")
TRUTH = "80x11x11"
ESTIMATORS = ("ro-ukf", "ukf", "rls", "lms", "batch-ls")
SCENARIO = "bend-y"
SEEDS = 2
SETTINGS: dict[str, dict[str, object]] = {}  # ukf keeps max_solves = 1500

QUICK = {
    "meshes": ("4x1x1", "8x2x2", "12x3x3"),
    "truth_mesh": "24x4x4",
    "seeds": 1,
    "steps": 6,
    "estimator_settings": {"ukf": {"max_solves": 200}},  # 4x1x1 only
}

COLUMNS = [
    "model_nodes",
    "estimator",
    "seeds",
    "shape_error_final",
    "shape_error_mean_final",
    "wall_s_median",
    "wall_s_amortised",
    "wall_s_step",
    "rate_hz",
    "within_30hz",
    "within_60hz",
    "best_30hz",
    "best_60hz",
    "pareto",
]


def compute(quick: bool = False, out: str | Path | None = None) -> pd.DataFrame:
    """The frontier table: one row per (model nodes, estimator) that ran."""
    config = _cli.config(
        quick,
        QUICK,
        meshes=MESHES,
        truth_mesh=TRUTH,
        estimators=ESTIMATORS,
        scenarios=(SCENARIO,),
        seeds=SEEDS,
        estimator_settings=SETTINGS,
    )
    runs, traces = compare(config, out, jobs=1)
    table = frontier(runs, traces)
    return table[[c for c in COLUMNS if c in table.columns]]


def plot(table: pd.DataFrame, path: Path) -> None:
    fig = frontier_figure(table)
    fig.axes[0].set_title(f"Real-time frontier ({SCENARIO}, this machine)")
    fig.tight_layout()
    fig.savefig(path, dpi=110)


def show(table: pd.DataFrame) -> None:
    """Print the table, numbers to 4 significant digits."""
    fmt = "{:.4g}".format
    with pd.option_context("display.width", 200, "display.float_format", fmt):
        _cli.show(table)


if __name__ == "__main__":
    _cli.main(
        __doc__, "results/frontier", compute, plot, "realtime_frontier", printed=show
    )
