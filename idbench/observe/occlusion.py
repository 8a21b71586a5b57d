"""Occluded observations: NaN entries, and what an estimator sees of them.

A tracker loses markers behind instruments: a recording's marker tracks hold
NaN where a marker was occluded (:mod:`idbench.store.recording`). An
:class:`~idbench.core.interfaces.Observation` with NaN entries is assimilated with
its visible entries only: with the boolean mask v of the non-NaN values,
``y <- y[v]``, ``R <- R[v, v]`` (the noise std of each value, when it has one
per value), ``h(x) <- h(x)[v]``, the sensitivity ``J <- J[v, :]`` and a
corrected model's ``Sigma <- Sigma[v, v]``. For a Gaussian update this is
exact: it is the same analysis as on a model and an observation with those
entries removed.

:class:`idbench.Filter` applies it once for every estimator built on it
(:func:`visible`, :func:`restrict`, :class:`MaskedModel`); an observation all
NaN is no observation. An estimator on the bare protocol receives the NaN
observation only if it declares ``handles_nan = True``; otherwise a run whose
observations have NaN entries is refused in one line
(:func:`refusal`).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

import numpy as np
from numpy.typing import NDArray

from idbench.core.capabilities import (
    handles_nan,
    observation_cov_of,
    observation_jacobian_of,
    observation_points_of,
    sensitivity_of,
)
from idbench.core.interfaces import FloatArray, ForwardModel, Observation
from idbench.core.view import Absent, ModelView, lacks

BoolArray = NDArray[np.bool_]


def visible(observation: Observation) -> BoolArray | None:
    """The mask (m,) of the observation's non-NaN values; None if all are."""
    values = np.asarray(observation.values, dtype=float)
    seen = ~np.isnan(values)
    return None if seen.all() else seen


def restrict(observation: Observation, mask: BoolArray) -> Observation:
    """The observation of the values where ``mask`` is True (and their noise std)."""
    std = observation.noise_std
    if np.ndim(std) != 0:
        std = np.asarray(std, dtype=float)[mask]
    values = np.asarray(observation.values, dtype=float)[mask]
    return Observation(values, std, observation.step)


def occluded_steps(stream: Sequence[Observation | None]) -> list[int]:
    """The steps whose observation has at least one NaN value."""
    return [
        o.step
        for o in stream
        if o is not None and np.isnan(np.asarray(o.values, dtype=float)).any()
    ]


def refusal(name: str, estimator: Any, stream: Sequence[Observation | None]) -> str:
    """Why ``estimator`` cannot run on ``stream`` ('' if it can).

    It can unless some observation has NaN entries and the estimator neither
    masks them (:class:`idbench.Filter`) nor declares ``handles_nan = True``.
    """
    if handles_nan(estimator):
        return ""
    steps = occluded_steps(stream)
    if not steps:
        return ""
    shown = ", ".join(str(k) for k in steps[:5]) + (", ..." if len(steps) > 5 else "")
    return (
        f"estimator {name!r} cannot take occluded (NaN) observation entries "
        f"(steps {shown}): build it on idbench.Filter, which assimilates the "
        "visible entries only, or declare handles_nan = True"
    )


class MaskedModel(ModelView):
    """``model`` whose observation is restricted to the visible entries ``mask``.

    ``observe`` returns ``h(x)[mask]``, ``sensitivity`` (if the model has it)
    ``J[mask, :]`` and ``observation_cov`` (a corrected model's Sigma, if it
    has it) ``Sigma[mask][:, mask]``; it has no ``marker_points`` (nor
    ``target_points``); the rest of the protocol and of the
    optional members is the model's own (:class:`~idbench.core.view.ModelView`).

    Parameters
    ----------
    model
        The forward model.
    mask
        Boolean (m,), True for the entries observed.
    """

    def __init__(self, model: ForwardModel, mask: BoolArray) -> None:
        super().__init__(model)
        self._mask = np.asarray(mask, dtype=bool)

    @property
    def mask(self) -> BoolArray:
        """The visible entries (m,) of the model's observation."""
        return self._mask

    def observe(self, state: FloatArray) -> FloatArray:
        """h(x)[mask]: the model's observation of ``state``, visible entries."""
        return np.asarray(self.model.observe(state), dtype=float)[self._mask]

    marker_points = Absent()
    """None: its ``observe`` holds the visible markers' entries only."""
    target_points = Absent()
    """None (a pair with ``marker_points``)."""

    @property
    def sensitivity(self) -> Callable[[FloatArray, int, FloatArray], FloatArray]:
        """The model's sensitivity (m, p), rows of the visible entries."""
        sensitivity = sensitivity_of(self.model)
        if sensitivity is None:
            raise lacks(self, "sensitivity")
        mask = self._mask

        def rows(theta: FloatArray, k: int, state: FloatArray) -> FloatArray:
            """The model's sensitivity (m, p), rows of the visible entries."""
            return np.asarray(sensitivity(theta, k, state), dtype=float)[mask]

        return rows

    @property
    def observation_jacobian(self) -> Callable[..., tuple[Any, FloatArray]]:
        """The model's (H_u, H_theta), rows of the visible entries."""
        jacobian = observation_jacobian_of(self.model)
        if jacobian is None:
            raise lacks(self, "observation_jacobian")
        mask = self._mask

        def rows(theta: FloatArray, k: int, state: FloatArray) -> Any:
            """The model's (H_u, H_theta), rows of the visible entries."""
            hu, ht = jacobian(theta, k, state)
            return hu[mask], np.asarray(ht)[mask]

        return rows

    @property
    def observation_points(self) -> Callable[[int], FloatArray]:
        """The model's observation points, rows of the visible entries."""
        points = observation_points_of(self.model)
        if points is None:
            raise lacks(self, "observation_points")
        mask = self._mask

        def rows(k: int) -> FloatArray:
            """The model's observation points, rows of the visible entries."""
            return np.asarray(points(k), dtype=float)[mask]

        return rows

    @property
    def observation_cov(self) -> Callable[[FloatArray], FloatArray]:
        """The model's Sigma (m, m), rows and columns of the visible entries."""
        cov = observation_cov_of(self.model)
        if cov is None:
            raise lacks(self, "observation_cov")
        mask = self._mask

        def block(state: FloatArray) -> FloatArray:
            """The model's Sigma (m, m), rows and columns of the visible entries."""
            return np.asarray(cov(state), dtype=float)[np.ix_(mask, mask)]

        return block
