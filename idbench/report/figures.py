"""The report's figures, keyed on the model's parameter names.

Every figure works for any model and any number of parameters p: one panel
per parameter and scenario (small multiples) where a figure shows parameter
values, one per scenario where it shows shape errors: the effective value
depends on the deformation, so scenarios are never pooled into one point.
Conventions shared by all figures:

- shape error in mm per grid point (the runs' ``shape_error_mean*`` columns
  times 1000), never the sum over the grid;
- one colour and one marker per series from a colour-blind-safe palette
  (Okabe-Ito, then Paul Tol's "muted"), the same estimator keeping its colour
  in every figure; series that share an x value are offset a little
  horizontally so that equal results stay visible;
- integer ticks on load-step axes;
- bars are 95% intervals over seeds from :func:`idbench.report.intervals.interval`,
  the same numbers as the summary's (none with one seed);
- values the original study reported, if given (``study``: a table with
  columns ``figure``, ``x``, ``y`` and optional ``label``), drawn as hollow
  black stars and labelled "study, read off the paper's figure".
"""

from __future__ import annotations

from typing import Any

import numpy as np
import pandas as pd

from idbench.core.sanitize import printable
from idbench.report.intervals import interval

PALETTE = (
    "#0072B2",  # Okabe-Ito blue
    "#D55E00",  # vermillion
    "#009E73",  # bluish green
    "#CC79A7",  # reddish purple
    "#E69F00",  # orange
    "#56B4E9",  # sky blue
    "#000000",  # black
    "#332288",  # Tol muted: indigo
    "#117733",  # green
    "#882255",  # wine
    "#44AA99",  # teal
    "#999933",  # olive
    "#AA4499",  # purple
    "#DDCC77",  # sand
)
"""Colour-blind-safe colours, in the order series get them."""

MARKERS = "osD^vP<X>hp*"
LINESTYLES = ("-", "--", ":", "-.")
STUDY_LABEL = "study, read off the paper's figure"


def style(index: int) -> dict[str, Any]:
    """Colour and marker of series ``index`` (cycling after 12 x 14)."""
    return {
        "color": PALETTE[index % len(PALETTE)],
        "marker": MARKERS[index % len(MARKERS)],
    }


def _series_names(runs: pd.DataFrame, axes: list[str]) -> list[str]:
    """Series of a figure: the estimator, with the swept axes' values."""
    keys = ["estimator", *axes]
    return sorted({_label(r, axes) for _, r in runs[keys].iterrows()})


def _label(row: Any, axes: list[str]) -> str:
    extra = " ".join(f"{a}={_short(row[a])}" for a in axes)
    return plain(f"{row['estimator']} {extra}".strip())


def plain(text: Any) -> str:
    """A plugin's string as figure text: printable, ``$`` not read as maths."""
    return printable(text).replace("$", r"\$")


def _with_intervals(values: pd.Series, by: pd.Series, metric: str) -> pd.DataFrame:
    """Mean and 95% interval (``mean``, ``lo``, ``hi``) of ``values`` per ``by``."""
    groups = values.groupby(by, sort=True)
    rows = {x: interval(v, metric) for x, v in groups if v.notna().any()}
    return pd.DataFrame.from_dict(rows, orient="index", columns=["mean", "lo", "hi"])


def _yerr(g: pd.DataFrame) -> np.ndarray:
    """Bar lengths (2, n) below and above each mean; 0 without an interval."""
    below = (g["mean"] - g["lo"]).fillna(0.0).clip(lower=0.0)
    above = (g["hi"] - g["mean"]).fillna(0.0).clip(lower=0.0)
    return np.vstack([below.to_numpy(), above.to_numpy()])


def _short(v: Any) -> str:
    return f"{v:g}" if isinstance(v, float | np.floating) else str(v)


def _resolution_x(runs: pd.DataFrame) -> tuple[pd.Series, bool]:
    """The x of resolution figures: model nodes, or mesh order without them."""
    if "model_nodes" not in runs:
        nodes = pd.Series(np.nan, index=runs.index)
    else:
        nodes = pd.to_numeric(runs["model_nodes"], errors="coerce")
    if nodes.notna().all():
        return nodes.astype(float), True
    order = {m: i for i, m in enumerate(dict.fromkeys(runs["mesh"]))}
    return runs["mesh"].map(order).astype(float), False


def _offset(x: np.ndarray, i: int, n: int, log: bool) -> np.ndarray:
    """Spread n series sharing x values: +-4% on a log axis, +-0.15 linear."""
    shift = (i - (n - 1) / 2) * (0.08 / max(n - 1, 1) if n > 1 else 0.0)
    return x * np.exp(shift) if log else x + 2 * shift


def _scenarios(ok: pd.DataFrame) -> list[Any]:
    """The scenarios of ``ok`` in order ([None]: no scenario column)."""
    return sorted(ok["scenario"].unique()) if "scenario" in ok else [None]


def _of(df: pd.DataFrame, scen: Any) -> pd.DataFrame:
    """The rows of scenario ``scen`` (all rows for None)."""
    return df if scen is None else df[df["scenario"] == scen]


def _titled(text: str, scen: Any, scenarios: list[Any]) -> str:
    """``text``, naming the scenario where a figure has more than one."""
    return f"{text}, {plain(scen)}" if len(scenarios) > 1 else text


def _panels(n: int, width: float = 4.6, height: float = 3.6) -> tuple[Any, Any]:
    import matplotlib.pyplot as plt

    cols = min(n, 3)
    rows = -(-n // cols)
    fig, axs = plt.subplots(
        rows, cols, figsize=(width * cols + 1.8, height * rows), squeeze=False
    )
    for ax in axs.flat[n:]:
        ax.set_visible(False)
    return fig, list(axs.flat[:n])


def _study(study: pd.DataFrame | None, figure: str, ax: Any) -> None:
    if study is None or study.empty or "figure" not in study:
        return
    d = study[study["figure"] == figure]
    if d.empty:
        return
    ax.plot(d["x"], d["y"], "*", ms=12, mfc="none", mec="k", mew=1.2, label=STUDY_LABEL)


def _legend(fig: Any, axs: list[Any]) -> None:
    """One legend for the figure, right of the panels, without duplicates."""
    seen: dict[str, Any] = {}
    for ax in axs:
        for h, lab in zip(*ax.get_legend_handles_labels(), strict=True):
            seen.setdefault(lab, h)
    if seen:
        fig.legend(
            list(seen.values()),
            list(seen.keys()),
            loc="center left",
            bbox_to_anchor=(1.0, 0.5),
            fontsize="small",
            frameon=False,
        )
    fig.tight_layout()


def parameters_vs_resolution(
    ok: pd.DataFrame,
    names: list[str],
    axes: list[str],
    study: pd.DataFrame | None = None,
) -> Any:
    """Identified parameters against model resolution.

    One panel per parameter and scenario (the effective value depends on the
    deformation: scenarios are never pooled); one series per estimator and
    swept setting. y is ``x_final / x_true`` where the true value is known
    (1 = the truth), else ``x_final``; markers are means over seeds, bars their 95% t
    intervals.
    """
    scenarios = _scenarios(ok)
    cases = [(scen, name) for scen in scenarios for name in names]
    fig, panels = _panels(len(cases))
    x_all, log = _resolution_x(ok)
    series = _series_names(ok, axes)
    for ax, (scen, name) in zip(panels, cases, strict=True):
        ratio = f"{name}_true" in ok
        y = ok[f"{name}_final"] / ok[f"{name}_true"] if ratio else ok[f"{name}_final"]
        df = ok.assign(_x=x_all, _y=y, _s=[_label(r, axes) for _, r in ok.iterrows()])
        df = _of(df, scen)
        metric = f"{name}_ratio" if ratio else f"{name}_final"
        for i, s in enumerate(series):
            d = df[df["_s"] == s]
            _interval_series(ax, d["_y"], d["_x"], metric, log, series, i)
        if ratio:
            ax.axhline(1.0, color="0.4", ls="--", lw=1, label="true value")
        _study(study, "stiffness_vs_resolution", ax)
        ax.set(
            xlabel="model nodes" if log else "model mesh",
            ylabel=f"identified {name} / true {name}"
            if ratio
            else f"identified {name}",
            title=_titled(f"{name} against resolution", scen, scenarios),
        )
        _resolution_axis(ax, df, df["_x"], log)
    _legend(fig, panels)
    return fig


def _interval_series(
    ax: Any,
    y: pd.Series,
    x: pd.Series,
    metric: str,
    log: bool,
    series: list[str],
    i: int,
) -> None:
    """Series ``series[i]``: the means of ``y`` per x, with their 95% intervals.

    Each series is offset a little along x (:func:`_offset`) so that the bars
    of the series do not overlap; nothing is drawn for an empty series.
    """
    g = _with_intervals(y, x, metric)
    if g.empty:
        return
    xs = _offset(g.index.to_numpy(dtype=float), i, len(series), log)
    ax.errorbar(
        xs, g["mean"], yerr=_yerr(g), lw=1.2, ms=6, capsize=3, label=series[i],
        **style(i),
    )  # fmt: skip


def _resolution_axis(ax: Any, ok: pd.DataFrame, x: pd.Series, log: bool) -> None:
    if log:
        ax.set_xscale("log")
        ticks = sorted(set(x.dropna()))
        ax.set_xticks(ticks, [f"{t:.0f}" for t in ticks])
        ax.minorticks_off()
    else:
        meshes = list(dict.fromkeys(ok["mesh"]))
        ax.set_xticks(range(len(meshes)), meshes)


def shape_error_vs_resolution(
    ok: pd.DataFrame, axes: list[str], study: pd.DataFrame | None = None
) -> Any:
    """Shape error at the last step (mm per grid point) against resolution.

    One panel per scenario: the model run with the true values and no
    assimilation ("direct", black squares) and each estimator's series
    (means over seeds, bars their 95% t intervals).
    """
    scenarios = sorted(ok["scenario"].unique()) if "scenario" in ok else [None]
    fig, panels = _panels(len(scenarios))
    x_all, log = _resolution_x(ok)
    series = _series_names(ok, axes)
    df = ok.assign(_x=x_all, _s=[_label(r, axes) for _, r in ok.iterrows()])
    for ax, scen in zip(panels, scenarios, strict=True):
        d = df if scen is None else df[df["scenario"] == scen]
        if "shape_error_direct_mean" in d:
            direct = 1000 * d.groupby("_x")["shape_error_direct_mean"].mean()
            ax.plot(
                direct.index, direct.to_numpy(), "ks--", mfc="none",
                label="direct (true values, no assimilation)",
            )  # fmt: skip
        for i, s in enumerate(series):
            e = d[d["_s"] == s]
            mm = 1000 * e["shape_error_mean_final"]
            _interval_series(ax, mm, e["_x"], "shape_error_mm", log, series, i)
        _study(study, "shape_error", ax)
        ax.set(
            xlabel="model nodes" if log else "model mesh",
            ylabel="shape error at the last step (mm per grid point)",
            title="Shape error" + (f", {scen}" if scen else ""),
        )
        ax.set_ylim(bottom=0)
        _resolution_axis(ax, d, d["_x"], log)
    _legend(fig, panels)
    return fig


def estimates_vs_step(
    ok: pd.DataFrame, traces: pd.DataFrame, names: list[str], axes: list[str]
) -> Any:
    """Estimates along the load path (first seed), one panel per parameter and scenario.

    Colour and marker: the estimator (with swept axes); line style: the mesh.
    y is the estimate over the true value where it is known.
    """
    from matplotlib.lines import Line2D
    from matplotlib.ticker import MaxNLocator

    keys = ["run_id", "mesh", "estimator", "seed", *axes]
    scenarios = _scenarios(ok)
    if scenarios != [None]:
        keys.append("scenario")
    trues = [f"{n}_true" for n in names if f"{n}_true" in ok]
    tr = traces.merge(ok[[*keys, *trues]], on="run_id")
    tr = tr[tr["seed"] == tr["seed"].min()]
    series = _series_names(ok, axes)
    meshes = list(dict.fromkeys(ok.sort_values("model_nodes")["mesh"]))
    cases = [(scen, name) for scen in scenarios for name in names]
    fig, panels = _panels(len(cases), width=5.2)
    group = ["mesh", "estimator", *axes]
    for ax, (scen, name) in zip(panels, cases, strict=True):
        ratio = f"{name}_true" in tr
        for key, df in _of(tr, scen).groupby(group, sort=True):
            row = dict(zip(group, key, strict=True))
            i = series.index(_label(row, axes))
            y = df[name] / df[f"{name}_true"] if ratio else df[name]
            ax.plot(
                df["step"], y, lw=1.1, ms=4, markevery=max(1, len(df) // 6),
                ls=LINESTYLES[meshes.index(row["mesh"]) % len(LINESTYLES)],
                **style(i),
            )  # fmt: skip
        if ratio:
            ax.axhline(1.0, color="0.4", ls="--", lw=1)
        ax.xaxis.set_major_locator(MaxNLocator(integer=True))
        ax.set(
            xlabel="load step",
            ylabel=f"estimate of {name} / true {name}" if ratio else name,
            title=_titled(
                f"{name} along the load path (seed {tr['seed'].min()})",
                scen, scenarios,
            ),
        )
    for i, s in enumerate(series):
        panels[0].plot([], [], lw=1.1, label=s, **style(i))
    for j, m in enumerate(meshes):
        panels[0].add_line(
            Line2D([], [], color="0.3", ls=LINESTYLES[j % 4], label=f"mesh {m}")
        )
    _legend(fig, panels)
    return fig


def uncertainty_vs_resolution(
    ok: pd.DataFrame, names: list[str], axes: list[str]
) -> Any:
    """Coverage of the 95% intervals and mean NEES against resolution.

    Per scenario, one panel per parameter: the share of seeds whose reported
    95% interval holds the true value (filled markers, solid lines) and the
    reference value (hollow markers, dotted lines), with the nominal 0.95; and
    a panel of the mean NEES against the true value (log scale) with the
    calibrated value p. Estimators without a std have no points.
    """
    scenarios = _scenarios(ok)
    cases = [(scen, name) for scen in scenarios for name in [*names, None]]
    fig, panels = _panels(len(cases))
    x_all, log = _resolution_x(ok)
    series = _series_names(ok, axes)
    df = ok.assign(_x=x_all, _s=[_label(r, axes) for _, r in ok.iterrows()])
    for ax, (scen, name) in zip(panels, cases, strict=True):
        if name is None:
            _nees_panel(ax, _of(df, scen), series, len(names), log)
            ax.set_title(_titled("NEES (mean over seeds)", scen, scenarios))
            _resolution_axis(ax, ok, x_all, log)
            continue
        for i, s in enumerate(series):
            d = _of(df, scen)
            d = d[d["_s"] == s]
            for what, filled, ls in (("true", True, "-"), ("ref", False, ":")):
                col = f"{name}_cover95_{what}"
                if col not in d:
                    continue
                g = d.groupby("_x")[col].mean().dropna()
                if g.empty:
                    continue
                st = style(i)
                ax.plot(
                    _offset(g.index.to_numpy(), i, len(series), log), g.to_numpy(),
                    ls=ls, lw=1.2, ms=6, mfc=st["color"] if filled else "none",
                    label=s if filled else None, **st,
                )  # fmt: skip
        ax.axhline(0.95, color="0.4", ls="--", lw=1, label="nominal 0.95")
        ax.set(
            xlabel="model nodes" if log else "model mesh",
            ylabel="share of seeds covered by the 95% interval",
            title=_titled(
                f"{name}: covers true (filled) / ref (hollow)", scen, scenarios
            ),
            ylim=(-0.05, 1.05),
        )
        _resolution_axis(ax, ok, x_all, log)
    _legend(fig, panels)
    return fig


def _nees_panel(
    ax: Any, df: pd.DataFrame, series: list[str], p: int, log: bool
) -> None:
    """The mean NEES against the true value per series, with the calibrated p."""
    for i, s in enumerate(series):
        g = df[df["_s"] == s].groupby("_x")["nees_true"].mean().dropna()
        g = g[g > 0]
        if g.empty:
            continue
        ax.plot(
            _offset(g.index.to_numpy(), i, len(series), log), g.to_numpy(),
            lw=1.2, ms=6, label=s, **style(i),
        )  # fmt: skip
    ax.axhline(p, color="0.4", ls="-.", lw=1, label="calibrated NEES = p")
    ax.set(
        yscale="log",
        xlabel="model nodes" if log else "model mesh",
        ylabel="mean NEES against the true value",
    )


def frontier_figure(table: pd.DataFrame, budgets_hz: tuple[int, ...] = (30, 60)) -> Any:
    """Shape error (mm per grid point) against wall time per step, log-log.

    From :func:`idbench.report.write.frontier`: one marker per (mesh, estimator),
    labelled with its node count; one colour per estimator, one marker shape
    per scenario; vertical lines at the real-time budgets; the Pareto front of
    each scenario as a step line. Without rows (no run ok) the figure says so.
    """
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7.5, 4.8))
    err = "shape_error_mean_final"
    if table.empty or err not in table:
        ax.text(0.5, 0.5, "no run finished ok: nothing to place", ha="center",
                va="center", transform=ax.transAxes)  # fmt: skip
        ax.set(title="Real-time frontier", xticks=[], yticks=[])
        return fig
    table = table.assign(_err=1000 * table[err])
    scenarios = sorted(table["scenario"].unique()) if "scenario" in table else [None]
    estimators = sorted(table["estimator"].unique())
    for i, est in enumerate(estimators):
        df = table[table["estimator"] == est]
        for j, scen in enumerate(scenarios):
            d = df if scen is None else df[df["scenario"] == scen]
            ax.plot(
                d["wall_s_step"], d["_err"], MARKERS[j % len(MARKERS)],
                color=PALETTE[i % len(PALETTE)], ms=7, mfc="none", mew=1.5,
                label=plain(est if len(scenarios) == 1 else f"{est} {scen}"),
            )  # fmt: skip
            for _, row in d.iterrows():
                if np.isfinite(row.get("model_nodes", np.nan)):
                    ax.annotate(
                        f"{row['model_nodes']:.0f}", (row["wall_s_step"], row["_err"]),
                        xytext=(5, 3 + 7 * (i % 3)), textcoords="offset points",
                        fontsize="x-small", color=PALETTE[i % len(PALETTE)],
                    )  # fmt: skip
    for j, scen in enumerate(scenarios):
        d = table if scen is None else table[table["scenario"] == scen]
        front = d[d["pareto"]].sort_values("wall_s_step")
        ax.plot(
            front["wall_s_step"], front["_err"], "k-", drawstyle="steps-post",
            lw=0.8, alpha=0.6, label="Pareto front" if j == 0 else None,
        )  # fmt: skip
    for hz, ls in zip(budgets_hz, ("--", ":"), strict=False):
        ax.axvline(1.0 / hz, color="grey", ls=ls, lw=1, label=f"{hz} Hz budget")
    ax.set(
        xscale="log",
        yscale="log",
        xlabel="wall time per step (s)",
        ylabel="shape error at the last step (mm per grid point)",
        title="Real-time frontier: accuracy against cost per step",
    )
    ax.legend(fontsize="x-small", loc="center left", bbox_to_anchor=(1.0, 0.5))
    fig.tight_layout()
    return fig
