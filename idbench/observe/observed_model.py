"""A forward model seen through an observation model: ``observe(state)`` is h(x).

The estimators call ``model.observe(state)`` after stepping to k; with an
observation model other than plain markers, the harness hands them an
:class:`ObservedModel` instead of the bare model. Its state is the model's
state with the load step it was solved with appended, ``[u (n,), k]``, and,
for the blocks whose prediction needs theta itself (``needs_theta``, e.g.
``force``: a force depends on theta even where u does not, as under
displacement control), their prediction computed when the step is solved
(theta known) carried in between: ``[u, carried (c,), k]``. ``step`` and
``step_many`` solve the model from ``u`` and append them; ``observe``
answers with the prediction of step k's frame (a cloud's points differ from
frame to frame): the carried values, and the other blocks' predictions for
``u``. The appended entries are carried by the filters like any state entry
and overwritten at every step; with a linear approximation error
(:attr:`ObservedModel.offsets`) theta itself is carried too, before k. It
has no ``sensitivity``: estimators that
need one use finite differences (each an extra forward solve, counted).
:func:`model_state` recovers ``u`` (the harness does, for the shape error).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from idbench.core.capabilities import (
    adjoint_of,
    needs_theta_of,
    observation_cov_of,
    observation_member,
    step_many_of,
)
from idbench.core.interfaces import FloatArray, ForwardModel
from idbench.core.view import Absent, ModelView, lacks
from idbench.observe import kinds as observe
from idbench.observe.offsets import Offsets


class ObservedModel(ModelView):
    """``model`` whose ``observe`` is the observation model's h(x) for each step.

    It has no ``sensitivity`` (nor ``marker_points`` and ``target_points``:
    its ``observe`` is not the markers') and always a ``step_many``; the rest
    of the protocol and of the optional members is the model's own
    (:class:`~idbench.core.view.ModelView`).

    Parameters
    ----------
    model
        The forward model.
    observation
        The :class:`~idbench.core.observation_model.ObservationModel`.
    frames
        The run's frame of each step 1..K.
    """

    def __init__(
        self, model: ForwardModel, observation: Any, frames: Sequence[Any]
    ) -> None:
        super().__init__(model)
        self.observation = observation
        self.frames = list(frames)
        self._n = int(np.asarray(model.reset()).size)
        self._combined = isinstance(observation, observe.Combined)
        self._blocks = [b for _, b in observe.leaves(observation)]
        self._carried = [needs_theta_of(b) for b in self._blocks]
        first = next((f for f in self.frames if f is not None), None)
        parts = self._parts(first) if first is not None else []
        self._sizes = [
            len(b.values(f)) for b, f in zip(self._blocks, parts, strict=True)
        ]
        self._c = sum(n for n, c in zip(self._sizes, self._carried, strict=True) if c)
        self._size = sum(self._sizes)
        self.offsets: Offsets | None = None
        """Added to step k's h(x) when set: an approximation error per frame
        (a run's correction, :class:`~idbench.observe.offsets.Offsets`); a
        linear one carries theta in the state; None: no offset."""

    sensitivity = Absent()
    """None: estimators that need one use finite differences."""
    marker_points = Absent()
    """None: its ``observe`` is h(x), not the markers' displacements."""
    target_points = Absent()
    """None (a pair with ``marker_points``)."""

    @property
    def n_state(self) -> int:
        """State size: the model's, plus the carried values and the step."""
        return self._n + self._c + self._p + 1

    @property
    def _p(self) -> int:
        """Theta's entries carried (a linear offset's), else 0."""
        linear = self.offsets is not None and self.offsets.linear
        return self.parameters.p if linear else 0

    def reset(self) -> FloatArray:
        """The model's unloaded state, with zeros carried and step 0 appended."""
        return np.concatenate([self.model.reset(), np.zeros(self._c + self._p + 1)])

    def step(
        self, theta: FloatArray, k: int, state: FloatArray, *, substeps: int = 1
    ) -> FloatArray:
        """The model's step from ``state``'s u, the carried values and k appended."""
        u = np.asarray(state, dtype=float)[: self._n]
        new = np.asarray(self.model.step(theta, k, u, substeps=substeps), float)
        return np.concatenate([new, self._carry(theta, k, new), self._theta(theta),
                               [float(k)]])  # fmt: skip

    def step_many(self, thetas: FloatArray, k: int, states: FloatArray) -> FloatArray:
        """The model's ``step_many`` (or r ``step`` calls), with what ``step`` adds."""
        u = np.asarray(states, dtype=float)[:, : self._n]
        many = step_many_of(self.model)
        if many is None:
            new = np.stack(
                [self.model.step(t, k, s) for t, s in zip(thetas, u, strict=True)]
            )
        else:
            new = np.asarray(many(np.asarray(thetas), k, np.ascontiguousarray(u)))
        carried = np.stack(
            [self._carry(t, k, s) for t, s in zip(thetas, new, strict=True)]
        )
        ks = np.full((len(new), 1), float(k))
        kept = np.stack([self._theta(t) for t in thetas]).reshape(len(new), -1)
        return np.concatenate([new, carried.reshape(len(new), -1), kept, ks], axis=1)

    def _theta(self, theta: FloatArray) -> FloatArray:
        """Theta as the state carries it (for a linear offset), else nothing."""
        return np.asarray(theta, dtype=float)[: self._p]

    def observe(self, state: FloatArray) -> FloatArray:
        """h(x): step k's frame predicted for ``state`` = [u, carried, (theta), k]."""
        state = np.asarray(state, dtype=float)
        k = round(float(state[-1]))
        if not 1 <= k <= len(self.frames):  # the unloaded state: only its size
            return np.zeros(self._size)
        u = state[: self._n]
        carried = state[self._n : self._n + self._c]
        nan = np.full(self.parameters.p, np.nan)  # what does not need theta
        out, at = [], 0
        parts = self._parts(self.frames[k - 1])
        for block, frame, carry, n in zip(
            self._blocks, parts, self._carried, self._sizes, strict=True
        ):
            if carry:
                out.append(carried[at : at + n])
                at += n
            else:
                out.append(
                    np.asarray(block.predict(self.model, frame, nan, k, u), float)
                )
        h = np.concatenate(out) if out else np.zeros(0)
        if self.offsets is None:
            return h
        at = self._n + self._c
        return h + self.offsets.at(k, state[at : at + self._p] if self._p else None)

    def _parts(self, frame: Any) -> list[Any]:
        """The frame of each block."""
        return self.observation.split(frame) if self._combined else [frame]

    def _carry(self, theta: FloatArray, k: int, u: FloatArray) -> FloatArray:
        """The predictions of the blocks that need theta, at (theta, k, u)."""
        if not self._c or not 1 <= k <= len(self.frames):
            return np.zeros(self._c)
        parts = self._parts(self.frames[k - 1])
        return np.concatenate([
            np.asarray(b.predict(self.model, f, np.asarray(theta, float), k, u), float)
            for b, f, c in zip(self._blocks, parts, self._carried, strict=True)
            if c
        ])  # fmt: skip

    def observation_jacobian(
        self, theta: FloatArray, k: int, state: FloatArray
    ) -> tuple[Any, FloatArray]:
        """(H_u, H_theta) of step k's prediction at ``state``, rows block by block.

        H_u (m, n) is in the model's own state u (``state``'s first n
        entries, not the carried ones): each block's ``linearize``
        (:data:`idbench.core.members.OBSERVATION_OPTIONAL`).

        Raises
        ------
        ValueError
            A block that cannot linearize (naming it).
        """
        import scipy.sparse as sp

        u = np.asarray(state, dtype=float)[: self._n]
        th = np.asarray(theta, dtype=float)
        hu, ht = [], []
        parts = self._parts(self.frames[k - 1])
        for block, frame in zip(self._blocks, parts, strict=True):
            linearize = observation_member(block, "linearize")
            if linearize is None:
                raise ValueError(
                    f"observation {type(block).__name__} cannot be linearized"
                )
            a, b = linearize(self.model, frame, th, k, u)
            hu.append(sp.csr_matrix(a))
            ht.append(np.asarray(b, dtype=float).reshape(a.shape[0], th.size))
        h_theta = np.vstack(ht)
        if self.offsets is not None:  # a linear offset's own slope
            h_theta = h_theta + self.offsets.jacobian(k, th)
        return sp.vstack(hu).tocsr(), h_theta

    def observation_points(self, k: int) -> FloatArray:
        """(m, d): where each value of step k is (the blocks' ``positions``).

        A block without ``positions`` gives NaN rows (not local).
        """
        out = []
        parts = self._parts(self.frames[k - 1])
        for block, frame, n in zip(self._blocks, parts, self._sizes, strict=True):
            positions = observation_member(block, "positions")
            if positions is None:
                out.append(np.full((n, 3), np.nan))
            else:
                out.append(np.asarray(positions(self.model, frame, k), dtype=float))
        return np.vstack(out)

    @property
    def equilibrium_jvp(self) -> Any:
        """The model's (du/dtheta) v at a state's u (absent if the model has none)."""
        adjoint, n = self._adjoint("equilibrium_jvp"), self._n

        def jvp(theta: FloatArray, k: int, state: FloatArray, v: FloatArray) -> Any:
            """(du/dtheta) v, in the model's own state u."""
            return adjoint.equilibrium_jvp(theta, k, np.asarray(state)[:n], v)

        return jvp

    @property
    def equilibrium_vjp(self) -> Any:
        """The model's w^T (du/dtheta) at a state's u (absent if it has none)."""
        adjoint, n = self._adjoint("equilibrium_vjp"), self._n

        def vjp(theta: FloatArray, k: int, state: FloatArray, w: FloatArray) -> Any:
            """w^T (du/dtheta), w in the model's own state u."""
            return adjoint.equilibrium_vjp(theta, k, np.asarray(state)[:n], w)

        return vjp

    @property
    def observation_cov(self) -> Any:
        """Sigma_k (m, m) of a state's frame (the offsets'; else the model's own)."""
        covs = None if self.offsets is None else self.offsets.covs
        if covs is None:
            own = observation_cov_of(self.model)
            if own is None:
                raise lacks(self, "observation_cov")
            return own

        def cov(state: FloatArray) -> FloatArray:
            """Step k's Sigma_k, k the state's last entry (zeros at rest)."""
            k = round(float(np.asarray(state)[-1]))
            if not 1 <= k <= len(covs):
                return np.zeros((self._size, self._size))
            return covs[k - 1]

        return cov

    def _adjoint(self, name: str) -> Any:
        found = adjoint_of(self.model)
        if found is None:
            raise lacks(self, name)
        return found

    def grid(self, state: FloatArray) -> FloatArray:
        """The model's shape-error points at ``state``'s u."""
        return self.model.grid(np.asarray(state, dtype=float)[: self._n])


def model_state(state: FloatArray, n: int) -> FloatArray:
    """The model's own state (n,) of a state an estimator kept (maybe extended)."""
    return np.asarray(state)[:n]
