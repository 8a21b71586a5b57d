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

With ``--organ liver`` or ``--organ kidney`` the same frontier is drawn for a
shipped organ (the ``solid`` model: the liver's grasp-lift with one E, the
kidney's grasp-pole with two, parenchyma and tumour) on meshes of about 500
to 4,000 nodes against the 16,000-node truth, for every estimator (the full
UKF only where it fits its budget), with the identified moduli at the last
step (``E_final``, mean over seeds; the kidney's parenchyma) in the table.

Run ``python studies/realtime_frontier.py [--quick] [--out DIR] [--organ NAME]``.
"""

from __future__ import annotations

from pathlib import Path

import _cli
import pandas as pd

from idbench.report import frontier, frontier_figure

SCENARIO = "bend-y"
FULL = {
    "meshes": ("9x2x2", "14x3x3", "20x4x4", "30x5x5", "40x6x6"),
    "truth_mesh": "80x11x11",
    "estimators": ("ro-ukf", "ukf", "rls", "lms", "batch-ls"),
    "scenarios": (SCENARIO,),
    "seeds": 2,
    "estimator_settings": {},  # ukf keeps max_solves = 1500
}
"""The comparison at full size: about 90, 240, 525, 1100, 2000 nodes."""
QUICK = {
    **_cli.QUICK,
    "estimator_settings": {"ukf": {"max_solves": 200}},  # 4x1x1 only
}

ORGANS = {"liver": "grasp-lift", "kidney": "grasp-pole"}
"""The shipped organs and the manipulation each frontier runs."""
ORGAN_FULL = {
    "model": "solid",
    "meshes": ("500", "1000", "2000", "4000"),
    "truth_mesh": "16000",
    "estimators": ("ro-ukf", "ukf", "enkf", "etkf", "rls", "lms", "batch-ls"),
    "seeds": 1,
    "estimator_settings": {},
}
"""An organ's comparison at full size (its manipulation: :data:`ORGANS`)."""
ORGAN_QUICK = {
    "meshes": ("150", "300"),
    "truth_mesh": "600",
    "estimators": ("ro-ukf", "rls"),
    "steps": 6,
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
    runs, _, traces = _cli.runs(_cli.config(quick, FULL, QUICK), out, jobs=1)
    table = frontier(runs, traces)
    return table[[c for c in COLUMNS if c in table.columns]]


def compute_organ(
    organ: str, quick: bool = False, out: str | Path | None = None
) -> pd.DataFrame:
    """The frontier of a shipped organ (``"liver"`` or ``"kidney"``), with E_final.

    Raises
    ------
    ValueError
        For an organ not in :data:`ORGANS`.
    """
    if organ not in ORGANS:
        raise ValueError(f"organ {organ!r}: allowed are {', '.join(ORGANS)}")
    truth = (ORGAN_QUICK if quick else ORGAN_FULL)["truth_mesh"]
    config = _cli.config(
        quick,
        ORGAN_FULL,
        ORGAN_QUICK,
        scenarios=(ORGANS[organ],),
        model_settings={"solid": {"body": organ, "reference": truth}},
    )
    runs, ok, traces = _cli.runs(config, out, jobs=1)
    table = frontier(runs, traces)
    table = table[[c for c in COLUMNS if c in table.columns]]
    E = ok.groupby(["model_nodes", "estimator"], as_index=False).agg(
        E_final=("E_final", "mean"), E_true=("E_true", "first")
    )
    return table.merge(E, on=["model_nodes", "estimator"], how="left")


def plot(table: pd.DataFrame, path: Path, scenario: str = SCENARIO) -> None:
    fig = frontier_figure(table)
    fig.axes[0].set_title(f"Real-time frontier ({scenario}, this machine)")
    fig.tight_layout()
    fig.savefig(path, dpi=110)


def show(table: pd.DataFrame) -> None:
    """Print the table, numbers to 4 significant digits."""
    fmt = "{:.4g}".format
    with pd.option_context("display.width", 200, "display.float_format", fmt):
        _cli.show(table)


if __name__ == "__main__":
    parser = _cli.parser(__doc__, "results/frontier")
    parser.add_argument("--organ", choices=sorted(ORGANS), help="a shipped organ")
    args = parser.parse_args()
    if args.organ:
        out = args.out / args.organ
        table = compute_organ(args.organ, args.quick, out)
        scenario = f"{args.organ} {ORGANS[args.organ]}"
    else:
        out, table, scenario = args.out, compute(args.quick, args.out), SCENARIO
    show(table)
    plot(table, out / "realtime_frontier.png", scenario)
