"""Figures of identified parameters never pool scenarios.

Two scenarios whose effective E differs (a grasp at 0.45 of E_true, a push
at 0.25) get a panel each, with their own means, in every figure that shows
parameter values; pooled, they would be one point at 0.35.
"""

from __future__ import annotations

import matplotlib

matplotlib.use("Agg")

import numpy as np
import pandas as pd
import pytest

from idbench.report import figures

RATIO = {"grasp": 0.45, "push": 0.25}


def runs() -> tuple[pd.DataFrame, pd.DataFrame]:
    rows, traces = [], []
    for scen, r in RATIO.items():
        for mesh, nodes in (("m1", 100), ("m2", 400)):
            for seed in range(3):
                run_id = f"{scen}-{mesh}-{seed}"
                e = 5000.0 * (r + 0.001 * seed)
                rows.append({
                    "run_id": run_id, "scenario": scen, "mesh": mesh,
                    "model_nodes": nodes, "estimator": "rls", "seed": seed,
                    "E_final": e, "E_true": 5000.0, "E_cover95_true": 1.0,
                    "nees_true": 1.0,
                })  # fmt: skip
                traces += [{"run_id": run_id, "step": k, "E": e} for k in (1, 2)]
    return pd.DataFrame(rows), pd.DataFrame(traces)


def _means(ax) -> list[float]:
    ys = [np.asarray(line.get_ydata(), dtype=float) for line in ax.lines]
    return sorted({round(float(v), 3) for y in ys for v in y if v != 1.0})


def test_parameters_against_resolution_has_a_panel_per_scenario() -> None:
    ok, _ = runs()
    fig = figures.parameters_vs_resolution(ok, ["E"], [])
    axes = [ax for ax in fig.axes if ax.get_visible() and ax.get_title()]
    assert [ax.get_title() for ax in axes] == [
        "E against resolution, grasp", "E against resolution, push"
    ]
    for ax, r in zip(axes, RATIO.values(), strict=True):
        (bars,) = ax.containers  # one series: its means and 95% bars
        means = np.asarray(bars.lines[0].get_ydata(), dtype=float)
        np.testing.assert_allclose(means, [r + 0.001] * 2, atol=1e-9)


def test_estimates_against_step_has_a_panel_per_scenario() -> None:
    ok, traces = runs()
    fig = figures.estimates_vs_step(ok, traces, ["E"], [])
    axes = [ax for ax in fig.axes if ax.get_visible() and ax.get_title()]
    assert len(axes) == 2 and all("grasp" in axes[0].get_title() for _ in [0])
    for ax, r in zip(axes, RATIO.values(), strict=True):
        assert _means(ax) == pytest.approx([r], abs=1e-3)


def test_uncertainty_has_panels_per_scenario() -> None:
    ok, _ = runs()
    fig = figures.uncertainty_vs_resolution(ok, ["E"], [])
    titles = [ax.get_title() for ax in fig.axes if ax.get_visible()]
    assert sum("grasp" in t for t in titles) == 2
    assert sum("push" in t for t in titles) == 2
