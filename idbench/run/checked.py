"""The model an estimator is handed, checked: a model's fault names the model.

An estimator calls its model's ``step``, ``step_many`` and ``observe``; when
the model returns the wrong shape the estimator is the one that trips over
it, with a message about broadcasting. :class:`CheckedModel` stands between
them (a :class:`~idbench.core.view.ModelView`: everything else passes
through) and checks each answer against what the model said before the run:

- ``step`` a state of ``reset()``'s shape, ``step_many`` one such row per
  pair: else :class:`~idbench.core.interfaces.ModelError`, naming the
  model, its plugin and the step;
- ``step`` a finite state: else :class:`~idbench.core.interfaces.ModelFailure`
  naming the model (a solve that failed: the estimators retry it, then the
  run is ``diverged``);
- ``observe`` as many values as the truth observed (or as its first call).

A fault is also kept (:attr:`CheckedModel.fault`), so the harness raises it
after the estimator's call even if the estimator caught it.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from idbench.core.capabilities import step_many_of
from idbench.core.interfaces import (
    FloatArray,
    ForwardModel,
    ModelError,
    ModelFailure,
)
from idbench.core.view import ModelView, lacks


class _CheckedStepMany:
    """The wrapped model's ``step_many``, if it has one, its answer's shape checked."""

    def __get__(self, view: CheckedModel | None, owner: type | None = None) -> Any:
        if view is None:
            return self
        many = step_many_of(view.model)
        if many is None:
            raise lacks(view, "step_many")

        def checked(thetas: FloatArray, k: int, states: FloatArray) -> FloatArray:
            new = many(thetas, k, states)
            shape = np.shape(new)
            if shape != (len(thetas), view.n):
                raise view.fault_of(
                    f"returned states of shape {shape} from step_many() at step "
                    f"{k}; expected ({len(thetas)}, {view.n}), one state a pair",
                    k,
                )
            return new

        return checked


class CheckedModel(ModelView):
    """``model``, its answers' shapes checked (see the module).

    Parameters
    ----------
    model
        The model an estimator is given.
    who
        How to name it: ``model 'NAME' (plugin 'PLUGIN') on mesh 'MESH'``.
    m
        The observation size it must give (None: its first ``observe``'s).
    """

    def __init__(self, model: ForwardModel, who: str, m: int | None = None) -> None:
        super().__init__(model)
        self.who = who
        self.n = int(np.asarray(model.reset()).size)
        self.m = m
        self.fault: ModelError | None = None

    def fault_of(self, message: str, step: int | None) -> ModelError:
        """Keep and return the :class:`ModelError` of ``message``, naming the model."""
        self.fault = ModelError(f"{self.who} {message}", step=step)
        return self.fault

    def step(
        self, theta: FloatArray, k: int, state: FloatArray, *, substeps: int = 1
    ) -> FloatArray:
        """The model's step, of ``reset()``'s shape and finite."""
        new = self.model.step(theta, k, state, substeps=substeps)
        u = np.asarray(new, dtype=float)
        if u.shape != (self.n,):
            raise self.fault_of(
                f"returned a state of shape {u.shape} from step() at step {k}; "
                f"expected ({self.n},), the shape of its reset()",
                k,
            )
        if not np.all(np.isfinite(u)):
            raise ModelFailure(
                f"{self.who} returned a non-finite state from step() at step {k}",
                step=k,
            )
        return new

    step_many = _CheckedStepMany()
    """The model's ``step_many`` (where it has one): a state of ``reset()``'s
    shape per pair."""

    def observe(self, state: FloatArray) -> FloatArray:
        """The model's observation, of the run's size."""
        y = self.model.observe(state)
        size = int(np.size(y))
        if self.m is None:
            self.m = size
        elif size != self.m:
            raise self.fault_of(
                f"returned {size} values from observe(); expected {self.m}, as "
                "many as the truth observed",
                None,
            )
        return y
