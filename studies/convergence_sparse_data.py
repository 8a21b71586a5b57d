"""Tests the paper's convergence claim: which estimator settles first as data thin out.

The paper says Bayesian filters (RO-UKF, and the full UKF it reduces) reach the
effective modulus fastest when there is little data. Here every estimator runs
on the same noisy marker streams of one bending path and we measure its
settling step (docs/design.md section 5,
:func:`idbench.score.metrics.settling_step`): the
first load step after which its estimate stays within 5 % of E_ref, the batch
least-squares fit of the run's own data. Sparsity is varied one axis at a time
from the default (2 markers, every 2nd step, sigma = 1e-4 m): fewer markers,
observations every k-th step, more noise. RO-UKF, RLS, LMS and batch least
squares refitted at every observation run on the 14x3x3 model (240 nodes); the
full UKF, whose cost grows with the mesh, only on 9x2x2 (90 nodes), next to an
RO-UKF on the same mesh for a like-for-like pair, at the default and at the
sparsest level of each axis.

Prior: E0 = E_true = 5000 Pa, std 2500 Pa, the nominal modulus a user would
take from a material test. The compare default (2500 +- 2500 Pa) happens to lie
within 1 % of E_ref of the 14x3x3 model (about 2525 Pa, the coarse mesh being
stiffer), so every estimator would "settle" at step 1 before seeing any data.

Counting runs that never settle: a run whose last estimate is outside the 5 %
band, or that diverged or failed, is counted as settling at step K + 1 ("not
within the path"). Means and confidence intervals use these censored values,
so never settling is penalised rather than dropped; ``never`` gives the
fraction of such runs next to them. Runs the estimator skipped (the full UKF
over its solve budget) are left out. Confidence intervals are 95 % percentile
bootstraps over seeds with a seeded :class:`numpy.random.Generator`.

Run ``python studies/convergence_sparse_data.py [--quick] [--out DIR]``.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import _cli
import numpy as np
import pandas as pd

from idbench import CompareConfig, compare

# Parameters (full size: truth about 11,700 nodes, model 240 nodes, UKF 90 nodes)
TRUTH = "80x11x11"
MESH = "14x3x3"
UKF_MESH = "9x2x2"
SCENARIO = "bend-y"
STEPS = 20
ESTIMATORS = ("ro-ukf", "rls", "lms", "batch-ls")
UKF_ESTIMATORS = ("ukf", "ro-ukf")
SETTINGS = {"batch-ls": {"refit": "each"}}
BAYESIAN = ("ro-ukf", "ukf")
ONLINE = ("ro-ukf", "ukf", "rls", "lms")  # recursive: a fixed cost per step
DEFAULT = {"obs_points": 2, "obs_every": 2, "noise": 1e-4}
# Levels of each axis, from dense to sparse.
AXES: dict[str, tuple[Any, ...]] = {
    "obs_points": (8, 4, 2, 1),
    "obs_every": (1, 2, 4),
    "noise": (1e-5, 1e-4, 1e-3),
}
PRIOR = (5000.0, 2500.0)
SEEDS = 6
UKF_SEEDS = 3
JOBS = 2
BOOTSTRAP = 2000
CI_LEVEL = 0.95
RNG_SEED = 20250601

QUICK: dict[str, Any] = {
    "truth_mesh": "24x4x4",
    "mesh": "8x2x2",
    "ukf_mesh": "4x1x1",
    "steps": 6,
    "seeds": 2,
    "ukf_seeds": 2,
    "axes": {"obs_points": (4, 2, 1), "obs_every": (1, 2), "noise": (1e-4, 1e-3)},
    "jobs": 1,
}


def _levels_to_run(axes: dict[str, tuple[Any, ...]], ukf: bool) -> dict[str, tuple]:
    """Levels each per-axis compare call runs (the default point runs once).

    The default point is run with the first axis only; the other axes reuse
    it. For the UKF only the default and the sparsest level of each axis run.
    """
    out = {}
    first = True
    for axis, levels in axes.items():
        chosen = (levels[-1],) if ukf else levels
        if first:
            chosen = tuple(dict.fromkeys((DEFAULT[axis], *chosen)))
            first = False
        else:
            chosen = tuple(v for v in chosen if v != DEFAULT[axis])
        out[axis] = chosen
    return out


def _run_axes(
    base: dict[str, Any],
    axes: dict[str, tuple[Any, ...]],
    ukf: bool,
    out: Path | None,
    jobs: int,
) -> pd.DataFrame:
    frames = []
    for axis, levels in _levels_to_run(axes, ukf).items():
        if not levels:
            continue
        sparsity = {k: (v,) for k, v in DEFAULT.items()}
        sparsity[axis] = tuple(levels)
        cfg = CompareConfig(**base, **sparsity)
        tag = f"{'ukf' if ukf else 'main'}-{axis}"
        runs, _ = compare(cfg, out / tag if out else None, jobs=jobs)
        frames.append(runs)
    return pd.concat(frames, ignore_index=True)


def bootstrap_ci(
    values: np.ndarray, rng: np.random.Generator, n: int = BOOTSTRAP
) -> tuple[float, float]:
    """Percentile bootstrap interval (level ``CI_LEVEL``) of the mean of ``values``."""
    values = np.asarray(values, dtype=float)
    if values.size == 0:
        return np.nan, np.nan
    if values.size == 1:
        return float(values[0]), float(values[0])
    idx = rng.integers(0, values.size, size=(n, values.size))
    means = values[idx].mean(axis=1)
    tail = 100 * (1 - CI_LEVEL) / 2
    lo, hi = np.percentile(means, [tail, 100 - tail])
    return float(lo), float(hi)


def summarise(
    runs: pd.DataFrame,
    axes: dict[str, tuple[Any, ...]],
    main_mesh: str,
    steps: int,
    rng: np.random.Generator,
) -> pd.DataFrame:
    """One row per (axis, level, method): settling step and final error over seeds."""
    runs = runs[runs["status"] != "skipped"].drop_duplicates("run_id").copy()
    settled = runs["settling_step"].where(runs["status"] == "ok")
    runs["settle"] = settled.fillna(steps + 1)
    runs["never"] = settled.isna()
    runs["E_err"] = (runs["E_final"] / runs["E_ref"] - 1).abs()
    tagged = runs["estimator"] + "@" + runs["mesh"]
    runs["method"] = np.where(runs["mesh"] == main_mesh, runs["estimator"], tagged)
    rows = []
    for axis, levels in axes.items():
        others = [a for a in DEFAULT if a != axis]
        at_default = np.logical_and.reduce(
            [np.isclose(runs[a].astype(float), float(DEFAULT[a])) for a in others]
        )
        sub = runs[at_default]
        for level in levels:
            here = sub[np.isclose(sub[axis].astype(float), float(level))]
            for (method, mesh), g in here.groupby(["method", "mesh"], sort=True):
                lo, hi = bootstrap_ci(g["settle"].to_numpy(), rng)
                ok = g[g["status"] == "ok"]
                rows.append(
                    {
                        "axis": axis,
                        "level": level,
                        "method": method,
                        "mesh": mesh,
                        "runs": len(g),
                        "settle": g["settle"].mean(),
                        "settle_lo": lo,
                        "settle_hi": hi,
                        "never": g["never"].mean(),
                        # observations used by then: mean over the runs that
                        # settle only (never-settled runs have none to count)
                        "settle_obs": ok["settling_obs"].mean(),
                        "E_err": ok["E_err"].mean(),
                        "E_ratio": (ok["E_final"] / ok["E_true"]).mean(),
                        "solves": ok["n_solves"].mean(),
                    }
                )
    return pd.DataFrame(rows)


def compute(
    quick: bool = False, out: str | Path | None = None, jobs: int | None = None
) -> pd.DataFrame:
    """Settling step (mean, CI, never-settled fraction) per axis, level and method."""
    q = QUICK if quick else {}
    truth = q.get("truth_mesh", TRUTH)
    mesh = q.get("mesh", MESH)
    ukf_mesh = q.get("ukf_mesh", UKF_MESH)
    steps = q.get("steps", STEPS)
    axes = q.get("axes", AXES)
    jobs = jobs or q.get("jobs", JOBS)
    out = Path(out) if out is not None else None
    common = {
        "truth_mesh": truth,
        "scenarios": (SCENARIO,),
        "steps": steps,
        "prior": PRIOR,
        "estimator_settings": SETTINGS,
    }
    main = _run_axes(
        {
            **common,
            "meshes": (mesh,),
            "estimators": ESTIMATORS,
            "seeds": q.get("seeds", SEEDS),
        },
        axes,
        False,
        out,
        jobs,
    )
    ukf = _run_axes(
        {
            **common,
            "meshes": (ukf_mesh,),
            "estimators": UKF_ESTIMATORS,
            "seeds": q.get("ukf_seeds", UKF_SEEDS),
        },
        axes,
        True,
        out,
        jobs,
    )
    runs = pd.concat([main, ukf], ignore_index=True)
    rng = np.random.default_rng(RNG_SEED)
    table = summarise(runs, axes, mesh, steps, rng)
    table.attrs.update(steps=steps, mesh=mesh, ukf_mesh=ukf_mesh)
    return table


def verdict(table: pd.DataFrame) -> pd.DataFrame:
    """Per axis and level: which estimator (on the main mesh) settles first.

    ``first`` lists every method within 0.05 steps of the lowest mean;
    ``clear`` says whether its CI lies below the runner-up's; ``bayesian``
    whether a Bayesian filter is among the first. ``online_first`` repeats the
    ranking without batch least squares (which refits the whole path at every
    observation, the very fit that defines E_ref); ``online_bayesian`` says
    whether a Bayesian filter leads there. The last columns compare the full
    UKF and the RO-UKF on the UKF's coarse mesh where both ran.
    """
    rows = []
    for (axis, level), g in table.groupby(["axis", "level"], sort=False):
        main = g[~g["method"].str.contains("@")].sort_values("settle", kind="stable")
        first, rest = _leaders(main)
        online, _ = _leaders(main[main["method"].isin(ONLINE)])
        row = {
            "axis": axis,
            "level": level,
            "first": " = ".join(first["method"]),
            "settle": first["settle"].iloc[0],
            "runner_up": rest["method"].iloc[0] if len(rest) else "",
            "runner_up_settle": rest["settle"].iloc[0] if len(rest) else np.nan,
            "clear": bool(
                len(rest) and first["settle_hi"].max() < rest["settle_lo"].min()
            ),
            "bayesian": bool(first["method"].isin(BAYESIAN).any()),
            "online_first": " = ".join(online["method"]),
            "online_settle": online["settle"].iloc[0],
            "online_bayesian": bool(online["method"].isin(BAYESIAN).any()),
        }
        for m in g["method"]:
            if "@" in m:
                row[m] = g.loc[g["method"] == m, "settle"].iloc[0]
        rows.append(row)
    return pd.DataFrame(rows)


def _leaders(ranked: pd.DataFrame) -> tuple[pd.DataFrame, pd.DataFrame]:
    """Rows within 0.05 steps of the lowest mean settling step, and the others."""
    near = ranked["settle"] <= ranked["settle"].min() + 0.05
    return ranked[near], ranked[~near]


def plot(table: pd.DataFrame, path: Path, dpi: int = 110) -> None:
    import matplotlib.pyplot as plt

    steps = table.attrs.get("steps", STEPS)
    titles = {
        "obs_points": "markers M",
        "obs_every": "observe every k-th step",
        "noise": "noise sigma (m)",
    }
    axes_present = list(dict.fromkeys(table["axis"]))
    fig, axs = plt.subplots(
        1, len(axes_present), figsize=(4.2 * len(axes_present), 3.8), sharey=True
    )
    # one colour per estimator; its run on the UKF's coarse mesh is dashed
    bases = list(dict.fromkeys(m.split("@")[0] for m in table["method"]))
    colors = {m: f"C{bases.index(m.split('@')[0])}" for m in table["method"]}
    for ax, axis in zip(np.atleast_1d(axs), axes_present, strict=True):
        sub = table[table["axis"] == axis]
        for method, g in sub.groupby("method", sort=False):
            g = g.sort_values("level")
            ls = "--" if "@" in method else "-"
            ax.plot(
                g["level"], g["settle"], ls, marker="o", color=colors[method],
                label=method,
            )  # fmt: skip
            ax.fill_between(
                g["level"], g["settle_lo"], g["settle_hi"], color=colors[method],
                alpha=0.15, lw=0,
            )  # fmt: skip
        ax.axhline(steps + 1, color="k", lw=0.8, ls=":")
        if axis == "noise":
            ax.set_xscale("log")
        if axis == "obs_points":
            ax.set_xscale("log", base=2)
            ax.invert_xaxis()  # fewer markers = sparser, to the right
        ax.set_xticks(sorted(sub["level"].unique()))
        ax.set_xticklabels([f"{v:g}" for v in sorted(sub["level"].unique())])
        ax.set(xlabel=f"{titles.get(axis, axis)}  (sparser ->)")
    first = np.atleast_1d(axs)[0]
    first.set_ylabel(f"settling step (mean, 95% CI; {steps + 1} = never)")
    first.legend(fontsize=8)
    fig.suptitle("Steps to settle within 5% of E_ref as data get sparser (bend-y)")
    fig.tight_layout()
    fig.savefig(path, dpi=dpi)


if __name__ == "__main__":
    parser = _cli.parser(__doc__, "results/convergence")
    parser.add_argument("--jobs", type=int, default=None)
    args = parser.parse_args()
    table = compute(args.quick, args.out, args.jobs)
    pd.set_option("display.width", 200)
    pd.set_option("display.float_format", "{:.4g}".format)
    verdicts = verdict(table)
    for df in (table, verdicts):
        print(df.assign(level=df["level"].map("{:g}".format)).to_string(index=False))
        print()
    table.to_csv(args.out / "convergence_sparse_data.csv", index=False)
    verdicts.to_csv(args.out / "convergence_verdict.csv", index=False)
    plot(table, args.out / "convergence_sparse_data.png")
