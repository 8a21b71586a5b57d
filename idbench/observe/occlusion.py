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

from idbench.core.interfaces import FloatArray, ForwardModel, Observation

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
    if getattr(estimator, "handles_nan", False):
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


class MaskedModel:
    """``model`` whose observation is restricted to the visible entries ``mask``.

    ``observe`` returns ``h(x)[mask]``, ``sensitivity`` (if the model has it)
    ``J[mask, :]`` and ``observation_cov`` (a corrected model's Sigma, if it
    has it) ``Sigma[mask][:, mask]``; everything else is the model's own.

    Parameters
    ----------
    model
        The forward model.
    mask
        Boolean (m,), True for the entries observed.
    """

    def __init__(self, model: ForwardModel, mask: BoolArray) -> None:
        self._model = model
        self._mask = np.asarray(mask, dtype=bool)

    def __getattr__(self, name: str) -> Any:
        if name in ("_model", "_mask") or name.startswith("__"):
            raise AttributeError(name)
        value = getattr(self._model, name)
        if name == "sensitivity":
            return self._rows(value)
        if name == "observation_cov":
            return self._block(value)
        return value

    @property
    def mask(self) -> BoolArray:
        """The visible entries (m,) of the model's observation."""
        return self._mask

    @property
    def parameters(self) -> Any:
        """The model's parameters."""
        return self._model.parameters

    @property
    def n_steps(self) -> int:
        """The model's load steps."""
        return self._model.n_steps

    def observe(self, state: FloatArray) -> FloatArray:
        """h(x)[mask]: the model's observation of ``state``, visible entries."""
        return np.asarray(self._model.observe(state), dtype=float)[self._mask]

    def _rows(self, sensitivity: Callable[..., Any]) -> Callable[..., FloatArray]:
        mask = self._mask

        def rows(theta: FloatArray, k: int, state: FloatArray) -> FloatArray:
            """The model's sensitivity (m, p), rows of the visible entries."""
            return np.asarray(sensitivity(theta, k, state), dtype=float)[mask]

        return rows

    def _block(self, cov: Callable[..., Any]) -> Callable[..., FloatArray]:
        mask = self._mask

        def block(state: FloatArray) -> FloatArray:
            """The model's Sigma (m, m), rows and columns of the visible entries."""
            return np.asarray(cov(state), dtype=float)[np.ix_(mask, mask)]

        return block
