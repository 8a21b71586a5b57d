"""Beyond the study: a calibrated, load-dependent effective E for a coarse mesh.

The study ends by noting that no strategy exists to choose effective parameter
values for a coarse mesh. This script calibrates one offline
(:func:`idbench_fem.tools.calibrate.calibrate`): the 510-node model's best constant E
against the 11,700-node truth over traction directions from stretching (0 deg)
to bending (90 deg) and ten load levels, interpolated as E_eff(direction,
magnitude). It then drives the coarse model on manipulations held back from
the calibration with that E (no observations at run time) and compares its
shape error with E_true, with one constant E identified on bending, and with
the RO-UKF assimilating sparse marker data.

Run ``python studies/calibrated_stiffness.py [--quick] [--out DIR]``.
"""

from __future__ import annotations

from pathlib import Path

import _cli
import pandas as pd

from idbench_fem.tools.calibrate import (
    Calibration,
    CalibrationSettings,
    calibrate,
    collapse,
    direction,
    evaluate,
)

# Parameters (full size: the study's 510-node model, truth about 11,700 nodes)
MESH = "20x4x4"
TRUTH = "80x11x11"
STEPS = 10  # calibration load levels per direction
EVAL_STEPS = 20  # held-back manipulations: the default load path
SEEDS = 3  # RO-UKF noise seeds
HELD_BACK = ("mixed-30", "mixed-60", "bend-z", "stretch-x")
PULLS = (3.0, 10.0)  # ad-hoc paths off the angle grid, where E_eff changes fast

QUICK = {"mesh": "6x2x2", "truth_mesh": "18x3x3", "angles": (0.0, 2.0, 15.0, 90.0),
         "steps": 3}  # fmt: skip
QUICK_EVAL = {"steps": 4, "seeds": 1}


def compute(
    quick: bool = False, out: str | Path | None = None
) -> tuple[Calibration, pd.DataFrame, pd.DataFrame]:
    """The calibration, its collapse check and the held-back scores.

    Returns
    -------
    tuple
        The :class:`Calibration` (table and interpolant), the collapse table
        (RMS relative error of E_eff predicted for unseen directions by each
        coordinate set) and the evaluation table (shape error per held-back
        scenario and method, see :func:`idbench_fem.tools.calibrate.evaluate`).
    """
    settings = CalibrationSettings(mesh=MESH, truth_mesh=TRUTH, steps=STEPS)
    eval_kw = {"steps": EVAL_STEPS, "seeds": SEEDS}
    if quick:
        settings = CalibrationSettings(**QUICK)  # type: ignore[arg-type]
        eval_kw = dict(QUICK_EVAL)
    cal = calibrate(settings)
    fit = collapse(cal)
    ukf_out = Path(out) / "ro-ukf" if out is not None else None
    paths = [*HELD_BACK, *(cal.manipulation(a) for a in PULLS)]
    scores = evaluate(cal, paths, out=ukf_out, **eval_kw)
    if out is not None:
        cal.save(out)
        fit.to_csv(Path(out) / "collapse.csv", index=False)
        scores.to_csv(Path(out) / "evaluation.csv", index=False)
    return cal, fit, scores


def plot(cal: Calibration, scores: pd.DataFrame, path: Path) -> None:
    """E_eff over direction and load (left), held-back shape error (right)."""
    import matplotlib.pyplot as plt
    import numpy as np

    fig, (ax1, ax2) = plt.subplots(1, 2, figsize=(11, 4.2))
    table = cal.table
    fine = np.linspace(table["angle"].min(), table["angle"].max(), 361)
    cmap = plt.get_cmap("viridis")
    fractions = sorted(table["fraction"].unique())
    for f in [*fractions[:: max(1, len(fractions) // 4)], fractions[-1]]:
        color = cmap(f)
        curve = [cal.E_eff(direction(a), f * cal.magnitude_at(a)) for a in fine]
        ax1.plot(fine + 0.1, np.array(curve) / cal.settings.E_true, color=color)
        pts = table[table["fraction"] == f]
        ax1.plot(pts["angle"] + 0.1, pts["ratio"], "o", ms=3, color=color,
                 label=f"load {f:.1f}")  # fmt: skip
    ax1.set(
        xscale="log",
        xlabel="traction angle from +x, degrees (+0.1, log scale)",
        ylabel="E_eff / E_true",
        title=f"calibrated effective E ({cal.settings.mesh})",
    )
    ax1.legend(fontsize=8)

    methods = ["E_true", "constant", "calibrated", "ro-ukf"]
    names = list(dict.fromkeys(scores["scenario"]))
    width = 0.8 / len(methods)
    for i, method in enumerate(methods):
        mine = scores[scores["method"] == method].set_index("scenario")
        values = [1e3 * mine["shape_error_path"].get(n, np.nan) for n in names]
        ax2.bar(np.arange(len(names)) + i * width, values, width, label=method)
    ax2.set_xticks(np.arange(len(names)) + 0.4 - width / 2, names)
    ax2.set(
        ylabel="shape error, mean over path (mm)",
        title="held-back manipulations",
    )
    ax2.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)


if __name__ == "__main__":
    parser = _cli.parser(__doc__, "results/calibrated")
    args = parser.parse_args()
    cal, fit, scores = compute(args.quick, args.out)
    wide = cal.table.pivot(index="fraction", columns="angle", values="ratio")
    print(wide.round(3).to_string())
    print(fit.round(4).to_string(index=False))
    print(scores.round(6).to_string(index=False))
    plot(cal, scores, args.out / "calibrated_stiffness.png")
