"""A forward model seen through an observation model: ``observe(state)`` is h(x).

The estimators call ``model.observe(state)`` after stepping to k; with an
observation model other than plain markers, the harness hands them an
:class:`ObservedModel` instead of the bare model. It forwards every member
to the model and remembers, for each state it returned from ``step`` or
``step_many``, the (theta, k) it was solved with, so that ``observe(state)``
can answer with the prediction of step k's frame (a cloud's points differ
from frame to frame; a force depends on theta). A state it did not produce
(an estimator's own mean) is taken at the last stepped k (an error for an
observation that needs theta). It has no ``sensitivity``: estimators then use
finite differences (each an extra forward solve, counted).
"""

from __future__ import annotations

from collections import OrderedDict
from collections.abc import Sequence
from typing import Any

import numpy as np

from idbench.interfaces import FloatArray, ForwardModel

MEMO = 65_536
"""States remembered (a key of 16 bytes and theta each)."""


class ObservedModel:
    """``model`` whose ``observe`` is the observation model's h(x) for each step.

    Parameters
    ----------
    model
        The forward model.
    observation
        The :class:`~idbench.observe.ObservationModel`.
    frames
        The run's frame of each step 1..K (None where a step has none).
    """

    def __init__(
        self, model: ForwardModel, observation: Any, frames: Sequence[Any]
    ) -> None:
        self.model = model
        self.observation = observation
        self.frames = list(frames)
        self._memo: OrderedDict[bytes, tuple[FloatArray, int]] = OrderedDict()
        self._k = 0
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

    def reset(self) -> FloatArray:
        """The model's unloaded state."""
        self._k = 0
        return self.model.reset()

    def step(
        self, theta: FloatArray, k: int, state: FloatArray, *, substeps: int = 1
    ) -> FloatArray:
        """The model's step, remembered for :meth:`observe`."""
        new = self.model.step(theta, k, state, substeps=substeps)
        self._remember(new, theta, k)
        return new

    def step_many(self, thetas: FloatArray, k: int, states: FloatArray) -> FloatArray:
        """The model's ``step_many`` (or r calls of ``step``), remembered."""
        many = getattr(self.model, "step_many", None)
        if many is None:
            new = np.stack([self.model.step(t, k, s) for t, s in zip(thetas, states, strict=True)])
        else:
            new = np.asarray(many(thetas, k, states))
        for t, s in zip(thetas, new, strict=True):
            self._remember(s, t, k)
        return new

    def observe(self, state: FloatArray) -> FloatArray:
        """h(x): the prediction of the frame of the step ``state`` was solved at."""
        theta, k = self._memo.get(_key(state), (None, self._k))
        frame = self._frame(k)
        if frame is None:  # the unloaded state (a filter asks for the size)
            return np.zeros(self._size)
        if theta is None:
            theta = np.full(self.parameters.p, np.nan)
        return np.asarray(
            self.observation.predict(self.model, frame, theta, k, state), dtype=float
        )

    def _frame(self, k: int) -> Any:
        return self.frames[k - 1] if 1 <= k <= len(self.frames) else None

    def _remember(self, state: FloatArray, theta: FloatArray, k: int) -> None:
        self._k = k
        self._memo[_key(state)] = (np.array(theta, dtype=float), k)
        if len(self._memo) > MEMO:
            self._memo.popitem(last=False)


def _key(state: FloatArray) -> bytes:
    import hashlib

    return hashlib.blake2b(
        np.ascontiguousarray(state, dtype=float).tobytes(), digest_size=16
    ).digest()
