"""Beyond the study: the real-time frontier, shape error against wall time per step.

For every (model mesh, estimator) the shape error reached at the last step
(mean over seeds) is set against the estimator's wall time per load step,
measured on this machine, with the 30 Hz and 60 Hz budgets: the table answers
"which mesh and estimator give the lowest shape error within a real-time
budget" (see :func:`idbench.report.write.frontier`).

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
step (``x_final`` and ``x_true`` for every modulus x, mean over seeds:
``E`` on the liver, ``E_parenchyma`` and ``E_inclusion`` on the kidney).

Run ``python studies/realtime_frontier.py [--quick] [--out DIR] [--organ NAME]``;
it prints the table and writes it to ``<out>/realtime_frontier.csv`` (all
columns) and ``<out>/realtime_frontier.md`` (the docs' table: rate, shape
error in mm per point, E_final / E_true with ``--organ``, the budgets met),
with the figure ``<out>/realtime_frontier.png`` (``<out>`` is ``DIR/NAME``
with ``--organ``). A full ``--organ`` run also writes the table to
``docs/results/data/organ_frontier_<organ>.csv``, the numbers of the organ
frontier's results page.
"""

from __future__ import annotations

from pathlib import Path

import _cli
import pandas as pd

from idbench.report.write import frontier, frontier_figure, parameter_names
from idbench.store.files import atomic_write, atomic_write_bytes

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
    runs, _, traces = _cli.runs(config, out, jobs=1)
    _cli.report(out, quick)  # report.html, with the 3D view
    table = frontier(runs, traces)
    table = table[[c for c in COLUMNS if c in table.columns]]
    return table.merge(moduli(runs), on=["model_nodes", "estimator"], how="left")


def moduli(runs: pd.DataFrame) -> pd.DataFrame:
    """Identified and true moduli per (model nodes, estimator), ok runs only.

    Every parameter ``x`` of the runs (``E`` for one modulus; ``E_parenchyma``
    and ``E_inclusion`` for the kidney's regions) gives ``x_final`` (mean over
    seeds) and ``x_true``.
    """
    names = [n for n in parameter_names(runs) if f"{n}_true" in runs.columns]
    ok = runs[runs["status"] == "ok"]
    agg = {}
    for name in names:
        agg[f"{name}_final"] = (f"{name}_final", "mean")
        agg[f"{name}_true"] = (f"{name}_true", "first")
    return ok.groupby(["model_nodes", "estimator"], as_index=False).agg(**agg)


def plot(table: pd.DataFrame, path: Path, scenario: str = SCENARIO) -> None:
    fig = frontier_figure(table)
    fig.axes[0].set_title(f"Real-time frontier ({scenario}, this machine)")
    fig.tight_layout()
    fig.savefig(path, dpi=110)


def markdown(table: pd.DataFrame) -> str:
    """The docs' table: one row per (nodes, estimator), by nodes and rate.

    Columns: model nodes, estimator, rate (Hz), shape error at the last step
    (mm per grid point, mean over seeds), ``E_final / E_true`` where the table
    has moduli (organs; one column a parameter: the kidney's parenchyma and
    inclusion), and whether the step fits 30 and 60 Hz.
    """
    rows = table.sort_values(["model_nodes", "rate_hz"], ascending=[True, False])
    names = [
        c[: -len("_final")]
        for c in rows.columns
        if c.endswith("_final") and f"{c[: -len('_final')]}_true" in rows.columns
    ]
    head = ["nodes", "estimator", "rate (Hz)", "shape error (mm/pt)"]
    head += [f"{n}_final / {n}_true" for n in names]
    head += ["30 Hz", "60 Hz"]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for _, r in rows.iterrows():
        cells = [
            f"{int(r['model_nodes']):,}",
            str(r["estimator"]),
            f"{r['rate_hz']:.3g}",
            f"{1000.0 * r['shape_error_mean_final']:.3g}",
        ]
        cells += [f"{r[f'{n}_final'] / r[f'{n}_true']:.3f}" for n in names]
        cells += ["yes" if r[f"within_{hz}hz"] else "no" for hz in (30, 60)]
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def save(table: pd.DataFrame, out: Path) -> None:
    """Write ``realtime_frontier.csv`` (all columns) and ``.md`` into ``out``."""
    out.mkdir(parents=True, exist_ok=True)
    atomic_write(out / "realtime_frontier.csv", lambda t: table.to_csv(t, index=False))
    atomic_write_bytes(out / "realtime_frontier.md", markdown(table).encode())


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
    save(table, out)
    if args.organ and not args.quick:  # the numbers of docs/results/organ-frontier.md
        _cli.docs_data(f"organ_frontier_{args.organ}", table)
    plot(table, out / "realtime_frontier.png", scenario)
