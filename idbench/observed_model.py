"""A forward model seen through an observation model: ``observe(state)`` is h(x).

The estimators call ``model.observe(state)`` after stepping to k; with an
observation model other than plain markers, the harness hands them an
:class:`ObservedModel` instead of the bare model. Its state is the model's
state with the parameters and the load step it was solved with appended,
``[u (n,), theta (p,), k]``: ``step`` and ``step_many`` solve the model
from ``u`` and append them, ``observe`` answers with the prediction of step
k's frame for ``u`` at ``theta`` (a cloud's points differ from frame to
frame; a force depends on theta even where u does not, as under displacement
control). The appended entries are carried by the filters like any state
entry and overwritten at every step. It has no ``sensitivity``: estimators
that need one use finite differences (each an extra forward solve, counted).
:func:`model_state` recovers ``u`` (the harness does, for the shape error).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from idbench.interfaces import FloatArray, ForwardModel


class ObservedModel:
    """``model`` whose ``observe`` is the observation model's h(x) for each step.

    Parameters
    ----------
    model
        The forward model.
    observation
        The :class:`~idbench.observe.ObservationModel`.
    frames
        The run's frame of each step 1..K.
    """

    def __init__(
        self, model: ForwardModel, observation: Any, frames: Sequence[Any]
    ) -> None:
        self.model = model
        self.observation = observation
        self.frames = list(frames)
        self._n = int(np.asarray(model.reset()).size)
        self._p = model.parameters.p
        self._size = next(
            (len(observation.values(f)) for f in self.frames if f is not None), 0
        )

    def __getattr__(self, name: str) -> Any:
        if name in ("sensitivity", "model", "__setstate__"):
            raise AttributeError(name)
        return getattr(self.model, name)

    @property
    def parameters(self) -> Any:
        """The model's parameters."""
        return self.model.parameters

    @property
    def n_steps(self) -> int:
        """The model's load steps."""
        return self.model.n_steps

    @property
    def n_state(self) -> int:
        """State size: the model's, plus p parameters and the step."""
        return self._n + self._p + 1

    def reset(self) -> FloatArray:
        """The model's unloaded state, with theta 0 and step 0 appended."""
        return np.concatenate([self.model.reset(), np.zeros(self._p + 1)])

    def step(
        self, theta: FloatArray, k: int, state: FloatArray, *, substeps: int = 1
    ) -> FloatArray:
        """The model's step from ``state``'s u, with theta and k appended."""
        u = np.asarray(state, dtype=float)[: self._n]
        new = self.model.step(theta, k, u, substeps=substeps)
        return np.concatenate([new, np.asarray(theta, dtype=float), [float(k)]])

    def step_many(self, thetas: FloatArray, k: int, states: FloatArray) -> FloatArray:
        """The model's ``step_many`` (or r calls of ``step``), theta and k appended."""
        u = np.asarray(states, dtype=float)[:, : self._n]
        many = getattr(self.model, "step_many", None)
        if many is None:
            new = np.stack(
                [self.model.step(t, k, s) for t, s in zip(thetas, u, strict=True)]
            )
        else:
            new = np.asarray(many(np.asarray(thetas), k, np.ascontiguousarray(u)))
        ks = np.full((len(new), 1), float(k))
        return np.concatenate([new, np.asarray(thetas, dtype=float), ks], axis=1)

    def observe(self, state: FloatArray) -> FloatArray:
        """h(x): the prediction of step k's frame for ``state`` = [u, theta, k]."""
        state = np.asarray(state, dtype=float)
        k = round(float(state[-1]))
        if not 1 <= k <= len(self.frames):  # the unloaded state: only its size
            return np.zeros(self._size)
        u = state[: self._n]
        theta = state[self._n : self._n + self._p]
        prediction = self.observation.predict(
            self.model, self.frames[k - 1], theta, k, u
        )
        return np.asarray(prediction, dtype=float)

    def grid(self, state: FloatArray) -> FloatArray:
        """The model's shape-error points at ``state``'s u."""
        return self.model.grid(np.asarray(state, dtype=float)[: self._n])


def model_state(state: FloatArray, n: int) -> FloatArray:
    """The model's own state (n,) of a state an estimator kept (maybe extended)."""
    return np.asarray(state)[:n]
