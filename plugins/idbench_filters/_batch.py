"""Advance many sigma points: the model's ``step_many`` when it has one."""

from __future__ import annotations

import numpy as np

from idbench import ForwardModel, ModelFailure
from idbench_filters._common import FloatArray, advance


def advance_many(
    model: ForwardModel, thetas: FloatArray, k: int, states: FloatArray
) -> FloatArray:
    """Advance r parameter/state pairs one load step: (r, p), (r, n) -> (r, n).

    Calls ``model.step_many`` (see :class:`idbench.BatchModel`) when the model
    has it; if that raises :class:`idbench.ModelFailure` or gives a non-finite
    row, or the model has no ``step_many``, every pair goes through
    :func:`~idbench_filters._common.advance` (``step`` with its sub-step
    retry), exactly as without batching.
    """
    step_many = getattr(model, "step_many", None)
    if step_many is not None:
        try:
            out = np.asarray(step_many(thetas, k, states), dtype=float)
            if np.all(np.isfinite(out)):
                return out
        except ModelFailure:
            pass
    return np.stack(
        [advance(model, thetas[i], k, states[i]) for i in range(len(thetas))]
    )
