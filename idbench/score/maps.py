r"""How good a map is: the metrics of an estimated parameter field.

A field's parameters are one value per cell (:class:`idbench.ParameterField`);
an estimate gives each cell a mean theta and a std. The true values are the
cells' own, as the model defines them (a mean of a finer truth over each
cell, say). In x = ln theta, with cell volumes V_c:

- **field error**: the relative L2 error of the map,
  :math:`\sqrt{\sum_c V_c (\hat x_c - x_c)^2 / \sum_c V_c (x_c - \bar x)^2}`,
  relative to the truth's own variation about its mean :math:`\bar x`
  (0: exact; 1: as far off as the uniform map at the true mean). NaN for a
  uniform truth; ``field_rms_log`` is the numerator's RMS alone.
- **the inclusion found**: the map thresholded at half its maximum contrast,
  the cells with :math:`\hat x_c \ge b + (\max_c \hat x_c - b)/2`, b the
  map's volume-weighted median (its background); nothing is found when the
  maximum is less than :data:`MIN_CONTRAST` times the background. Its
  **centroid distance** (mm) is from the found cells' volume-weighted
  centroid to the truth's inclusion centroid; its **Dice** overlap,
  :math:`2 |A \cap B| / (|A| + |B|)` by volume, with B the truth's
  inclusion (each cell's volume fraction inside it, measured on the truth
  mesh): the found cells are judged against the inclusion's true shape.
- **coverage**: the fraction of cells whose true x_c lies in the estimate's
  95% band :math:`\hat x_c \pm 1.96\, \sigma_c` (sigma_c = std / theta, the
  log-std the filters report through their log transform).

Without an inclusion in the truth (``truth_inside`` None) the inclusion
metrics are NaN.
"""

from __future__ import annotations

import json
import math
from typing import Any

import numpy as np

from idbench.core.field import FloatArray, ParameterField

MIN_CONTRAST = 1.2
"""A map whose maximum is below this times its background shows no inclusion."""
Z95 = 1.959963984540054

COLUMNS = ("field_error", "field_rms_log", "inclusion_centroid_mm", "inclusion_dice",
           "field_cover95", "field_cells")  # fmt: skip
"""The runs-table columns of a field run (:func:`map_columns`)."""


def weighted_median(x: FloatArray, w: FloatArray) -> float:
    """The median of x (p,) with weights w (p,)."""
    order = np.argsort(x)
    c = np.cumsum(w[order])
    return float(x[order][np.searchsorted(c, 0.5 * c[-1])])


def found_cells(field: ParameterField, log_mean: FloatArray) -> FloatArray:
    """The map thresholded at half its maximum contrast: a mask (p,) of cells."""
    b = weighted_median(log_mean, field.volumes)
    top = float(np.max(log_mean))
    if top - b < math.log(MIN_CONTRAST):
        return np.zeros(field.p, dtype=bool)
    return np.asarray(log_mean >= b + 0.5 * (top - b))


def map_scores(
    field: ParameterField, mean: FloatArray, std: FloatArray, true: FloatArray
) -> dict[str, float]:
    """Field error, inclusion centroid and Dice, coverage (see the module).

    Parameters
    ----------
    field
        The cells.
    mean, std, true
        (p,) the estimate's mean and std and the true values, natural units.
    """
    V = field.volumes
    x_hat = np.log(np.asarray(mean, dtype=float))
    x = np.log(np.asarray(true, dtype=float))
    err2 = float(np.sum(V * (x_hat - x) ** 2))
    spread = float(np.sum(V * (x - np.sum(V * x) / V.sum()) ** 2))
    sigma = np.asarray(std, dtype=float) / np.asarray(mean, dtype=float)
    with np.errstate(invalid="ignore"):
        inside_band = np.abs(x_hat - x) <= Z95 * sigma
    out = {
        "field_error": math.sqrt(err2 / spread) if spread > 0 else math.nan,
        "field_rms_log": math.sqrt(err2 / V.sum()),
        "field_cover95": (
            float(np.mean(inside_band)) if np.all(np.isfinite(sigma)) else math.nan
        ),
        "inclusion_centroid_mm": math.nan,
        "inclusion_dice": math.nan,
    }
    if field.truth_inside is None or field.truth_centre is None:
        return out
    found = found_cells(field, x_hat)
    truth = field.truth_inside * V
    both = float(np.sum(truth[found]))
    out["inclusion_dice"] = 2 * both / (float(V[found].sum()) + float(truth.sum()))
    if found.any():
        centre = (field.centroids[found] * V[found, None]).sum(axis=0) / V[found].sum()
        distance = float(np.linalg.norm(centre - field.truth_centre))
        out["inclusion_centroid_mm"] = 1000.0 * distance
    return out


def map_columns(
    field: ParameterField, mean: FloatArray, std: FloatArray, true: FloatArray
) -> dict[str, Any]:
    """A field run's columns: :func:`map_scores` and ``field_cells``.

    ``field_cells`` is JSON of what a report needs to draw the map without
    the model: each cell's centroid (``x``, model unit, rounded to 1e-5) and
    volume fraction inside the truth's inclusion (``inside``, or null).
    """
    out: dict[str, Any] = dict(map_scores(field, mean, std, true))
    inside = field.truth_inside
    out["field_cells"] = json.dumps({
        "x": np.round(field.centroids, 5).tolist(),
        "inside": None if inside is None else np.round(inside, 3).tolist(),
    })  # fmt: skip
    return out


def cells_of(row_value: str) -> tuple[FloatArray, FloatArray | None]:
    """The centroids (p, d) and inclusion fractions (p,) of a ``field_cells`` value."""
    data = json.loads(row_value)
    inside = data.get("inside")
    return (np.asarray(data["x"], dtype=float),
            None if inside is None else np.asarray(inside, dtype=float))  # fmt: skip
