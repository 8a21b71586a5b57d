"""Beyond the paper: is the estimators' reported uncertainty calibrated?

Every estimator reports a standard deviation with its E. This study scores it:
the share of seeds whose 68% and 95% intervals hold E_true (coverage), the
mean NEES against E_true (1 if calibrated), and, against what an ideal
Bayesian would conclude with the same coarse model, the coverage of the
reference posterior's mean and the ratio of the reported std to the
posterior's std. Coarse meshes of 90, 240 and 525 nodes against the
11,664-node truth, and a control with mesh = truth (no model error), at noise
1e-4 and 1e-3 m.

The remedy (the RO-UKF's ``model_error`` setting, "ro-ukf+me"): R is widened
by e^2, e the RMS marker misfit of the coarse mesh at its best constant E on
the noise-free truth of the same path (:func:`idbench.estimate.posterior.model_error`;
a calibration on the very path later identified, so the best case for it).
Reported: coverage of E_true before and after, and the cost in accuracy of
the mean (|E_final - E_ref| / E_ref, shape error).

Run ``python studies/uncertainty_calibration.py [--quick] [--out DIR]``.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import _cli
import numpy as np
import pandas as pd

from idbench import CompareConfig, compare
from idbench.estimate.posterior import model_error
from idbench.run.compare import runs_of
from idbench.run.session import Session
from idbench.score import metrics

# Parameters (full size)
MESHES = ("9x2x2", "14x3x3", "20x4x4")  # 90, 240, 525 nodes
TRUTH = "80x11x11"
CONTROL = "14x3x3"  # mesh = truth: the control without model error
POSTERIOR_MESHES = ("9x2x2", "14x3x3")  # the reference posterior's grid costs
ESTIMATORS = ("ro-ukf", "enkf", "etkf", "rls", "batch-ls")
REMEDY = "ro-ukf"
NOISE = (1e-4, 1e-3)
SEEDS = 4
STEPS = 20
SCENARIO = "bend-y"
POSTERIOR = {"span": 3.0, "zoom_points": 21, "points": 41}

QUICK: dict[str, Any] = {
    "MESHES": ("6x2x2",),
    "TRUTH": "14x3x3",
    "CONTROL": "6x2x2",
    "POSTERIOR_MESHES": ("6x2x2",),
    "ESTIMATORS": ("ro-ukf", "etkf", "batch-ls"),
    "SEEDS": 2,
    "STEPS": 6,
    "POSTERIOR": {"span": 3.0, "zoom_points": 11, "points": 21},
}


def _compare(p: dict[str, Any], out: Path | None, name: str, **kw: Any) -> pd.DataFrame:
    base = {
        "scenarios": (SCENARIO,),
        "estimators": p["ESTIMATORS"],
        "noise": NOISE,
        "seeds": p["SEEDS"],
        "steps": p["STEPS"],
    }
    config = CompareConfig(**{**base, **kw})
    runs, _ = compare(config, None if out is None else out / name)
    return runs


def misfit_std(mesh: str, truth: str, steps: int) -> float:
    """RMS coarse-vs-truth marker misfit (m) at the best constant E, noise-free.

    E_ref is the batch fit to the noise-free truth observations of the path;
    the misfit is one path simulation at E_ref (see ``posterior.model_error``).
    """
    config = CompareConfig(
        scenarios=(SCENARIO,), meshes=(mesh,), truth_mesh=truth,
        estimators=("batch-ls",), noise=(0.0,), seeds=1, steps=steps,
    )  # fmt: skip
    session = Session()
    spec = runs_of(config, session.registry)[0]
    theta = session.reference(spec)
    model = session.model(spec, mesh, role="ref")
    return model_error(model, theta, session.observations(spec))


def compute(quick: bool = False, out: str | Path | None = None) -> pd.DataFrame:
    """Calibration per (case, noise, estimator); one row each.

    Columns: ``case`` (the mesh, or ``= truth`` for the control),
    ``model_nodes``, ``noise``, ``estimator`` (``ro-ukf+me``: the remedy),
    ``n`` (seeds), ``model_error`` (e, m; remedy rows), ``E_ratio`` (mean
    E_final / E_true), ``E_std`` (mean reported std), ``ref_error`` (mean
    |E_final - E_ref| / E_ref), ``cover68_true``, ``cover95_true``,
    ``cover95_ref`` (shares of seeds), ``nees_true`` (mean), ``crps`` (mean,
    Pa), ``shape_error_mm`` (mm per grid point at the last step); where the
    reference posterior was computed: ``post_ratio`` (posterior mean /
    E_true), ``std_over_post`` (mean reported std / posterior std),
    ``cover95_post`` (share of seeds whose 95% interval holds the posterior
    mean), ``w1_over_post`` (mean W1 distance / posterior std; not for the
    remedy, run without the posterior and given the same one afterwards),
    ``post_converged`` (share).
    """
    p = {k: globals()[k] for k in QUICK}
    if quick:
        p.update(QUICK)
    root = None if out is None else Path(out)
    parts = []
    for mesh in p["MESHES"]:
        post = mesh in p["POSTERIOR_MESHES"]
        runs = _compare(
            p, root, mesh, meshes=(mesh,), truth_mesh=p["TRUTH"], posterior=post,
            posterior_settings=p["POSTERIOR"],
        )  # fmt: skip
        runs["case"] = mesh
        e = misfit_std(mesh, p["TRUTH"], p["STEPS"])
        fixed = _compare(
            p, root, f"{mesh}-remedy", meshes=(mesh,), truth_mesh=p["TRUTH"],
            estimators=(REMEDY,), estimator_settings={REMEDY: {"model_error": e}},
        )  # fmt: skip
        if post:  # same data and mesh: the same posterior, computed once
            cols = ["E_post_mean", "E_post_std", "posterior_converged"]
            same = runs.drop_duplicates(["noise", "seed"]).set_index(["noise", "seed"])
            at = pd.MultiIndex.from_frame(fixed[["noise", "seed"]])
            for c in cols:
                fixed[c] = same[c].reindex(at).to_numpy()
        fixed["case"] = mesh
        fixed["estimator"] = f"{REMEDY}+me"
        fixed["model_error"] = e
        parts += [runs, fixed]
    control = _compare(
        p, root, "control", meshes=(p["CONTROL"],), truth_mesh=p["CONTROL"]
    )
    control["case"] = "= truth"
    parts.append(control)
    return summarise(pd.concat(parts, ignore_index=True))


def summarise(runs: pd.DataFrame) -> pd.DataFrame:
    """The per-(case, noise, estimator) table of :func:`compute` from its runs."""
    ok = runs[runs["status"] == "ok"].copy()
    ok["ref_error"] = (ok["E_final"] - ok["E_ref"]).abs() / ok["E_ref"]
    ok["E_ratio"] = ok["E_final"] / ok["E_true"]
    ok["shape_error_mm"] = 1000 * ok["shape_error_mean_final"]
    if "model_error" not in ok:
        ok["model_error"] = np.nan
    has_post = "E_post_mean" in ok
    if has_post:
        ok["cover95_post"] = metrics.coverage(
            ok["E_final"], ok["E_std_final"], ok["E_post_mean"], 0.95
        )
        ok["cover95_post"] = ok["cover95_post"].where(ok["E_post_mean"].notna())
        ok["post_ratio"] = ok["E_post_mean"] / ok["E_true"]
        ok["std_over_post"] = ok["E_std_final"] / ok["E_post_std"]
        ok["w1_over_post"] = ok["w1_posterior"] / ok["E_post_std"]
        ok["post_converged"] = (
            ok["posterior_converged"].astype(float).where(ok["E_post_mean"].notna())
        )
    cols = {
        "model_nodes": "first", "model_error": "mean", "E_ratio": "mean",
        "E_std_final": "mean", "ref_error": "mean", "E_cover68_true": "mean",
        "E_cover95_true": "mean", "E_cover95_ref": "mean", "nees_true": "mean",
        "E_crps": "mean", "shape_error_mm": "mean",
    }  # fmt: skip
    if has_post:
        for c in ("post_ratio", "std_over_post", "cover95_post", "w1_over_post",
                  "post_converged"):  # fmt: skip
            cols[c] = "mean"
    keys = ["case", "noise", "estimator"]
    table = ok.groupby(keys, sort=False).agg(n=("seed", "size"), **{
        c: (c, how) for c, how in cols.items()
    })  # fmt: skip
    table = table.rename(
        columns={
            "E_std_final": "E_std", "E_cover68_true": "cover68_true",
            "E_cover95_true": "cover95_true", "E_cover95_ref": "cover95_ref",
            "E_crps": "crps",
        }
    )  # fmt: skip
    return table.reset_index()


def plot(table: pd.DataFrame, path: Path) -> None:
    import matplotlib.pyplot as plt

    from idbench.report.figures import style

    cases = list(dict.fromkeys(table["case"]))
    nodes = table.groupby("case", sort=False)["model_nodes"].first()
    labels = [
        f"{nodes[c]:.0f}" if c != "= truth" else f"{nodes[c]:.0f}\nmesh = truth"
        for c in cases
    ]
    estimators = list(dict.fromkeys(table["estimator"]))
    noises = sorted(table["noise"].unique())
    panels = [
        ("cover95_true", "95% interval holds E_true\n(share of seeds)", 0.95,
         False),
        ("cover95_post", "95% interval holds posterior mean\n(share of seeds)",
         0.95, False),
        ("nees_true", "mean NEES against E_true", 1.0, True),
    ]  # fmt: skip
    fig, axs = plt.subplots(
        len(noises), len(panels), figsize=(15, 3.8 * len(noises)), squeeze=False
    )
    for r, noise in enumerate(noises):
        d = table[table["noise"] == noise]
        for c, (col, ylabel, nominal, log) in enumerate(panels):
            ax = axs[r, c]
            for i, est in enumerate(estimators):
                e = d[d["estimator"] == est].set_index("case")
                if col not in e:
                    continue
                y = e[col].reindex(cases)
                x = np.arange(len(cases)) + (i - (len(estimators) - 1) / 2) * 0.07
                ok = y.notna().to_numpy()
                line = ok & (np.array(cases) != "= truth")  # no line to the control
                st = style(i)
                ax.plot(x[line], y.to_numpy()[line], ls="-", lw=1, ms=7, label=est,
                        **st)  # fmt: skip
                ax.plot(x[ok & ~line], y.to_numpy()[ok & ~line], ls="", ms=7, **st)
            ax.axhline(nominal, color="0.4", ls="--", lw=1)
            ax.set_xticks(range(len(cases)), labels)
            ax.set(xlabel="model nodes", ylabel=ylabel, title=f"noise {noise:g} m")
            if log:
                ax.set_yscale("log")
            else:
                ax.set_ylim(-0.05, 1.05)
    handles, names = axs[0, 0].get_legend_handles_labels()
    fig.legend(handles, names, loc="center left", bbox_to_anchor=(1.0, 0.5),
               frameon=False)  # fmt: skip
    fig.suptitle("Is the reported uncertainty calibrated? (dashed: nominal)", y=1.0)
    fig.tight_layout()
    fig.savefig(path, dpi=110, bbox_inches="tight")


def show(table: pd.DataFrame) -> None:
    """Print the table, all columns."""
    with pd.option_context("display.width", 250, "display.max_columns", 40):
        _cli.show(table)


if __name__ == "__main__":
    _cli.main(
        __doc__, "results/uncertainty", compute, plot, "uncertainty_calibration",
        printed=show, csv=True,
    )  # fmt: skip
