"""The metrics of a map: exact, flat and shifted maps of a known inclusion."""

from __future__ import annotations

import math

import numpy as np
import pytest

from idbench import ParameterField
from idbench.score.maps import cells_of, map_columns, map_scores

P, E0 = 20, 6000.0
INCLUSION = np.arange(8, 12)


def field() -> ParameterField:
    x = np.arange(P, dtype=float) * 0.005  # 5 mm cells
    inside = np.zeros(P)
    inside[INCLUSION] = 1.0
    return ParameterField(
        np.stack([x, 0 * x, 0 * x], 1), np.ones(P),
        np.stack([np.arange(P - 1), np.arange(1, P)], 1), np.ones(P - 1), 0.01,
        truth_inside=inside, truth_centre=np.array([x[INCLUSION].mean(), 0, 0]),
    )  # fmt: skip


def truth() -> np.ndarray:
    out = np.full(P, E0)
    out[INCLUSION] *= 3.0
    return out


def test_the_exact_map_scores_perfectly():
    true = truth()
    s = map_scores(field(), true, 0.1 * true, true)
    assert s["field_error"] == 0.0 and s["field_rms_log"] == 0.0
    assert s["inclusion_dice"] == 1.0 and s["inclusion_centroid_mm"] == 0.0
    assert s["field_cover95"] == 1.0


def test_a_flat_map_at_the_true_mean_has_error_one_and_finds_nothing():
    true = truth()
    flat = np.full(P, math.exp(np.log(true).mean()))
    s = map_scores(field(), flat, 0.01 * flat, true)
    assert s["field_error"] == pytest.approx(1.0)
    assert s["inclusion_dice"] == 0.0 and math.isnan(s["inclusion_centroid_mm"])
    assert s["field_cover95"] == 0.0  # a narrow band around the wrong values


def test_a_shifted_inclusion_is_measured_in_mm_and_by_overlap():
    true = truth()
    shifted = np.roll(true, 2)  # two cells (10 mm) along x
    s = map_scores(field(), shifted, 0.1 * shifted, true)
    assert s["inclusion_centroid_mm"] == pytest.approx(10.0)
    assert s["inclusion_dice"] == pytest.approx(0.5)  # half of the cells overlap
    cols = map_columns(field(), shifted, 0.1 * shifted, true)
    x, inside = cells_of(cols["field_cells"])
    assert x.shape == (P, 3) and inside[INCLUSION].all()
