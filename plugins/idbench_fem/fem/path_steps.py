"""Load steps along a path that reuse the previous step's factorization.

For an internal force linear in the region moduli theta (St Venant-Kirchhoff,
neo-Hookean at fixed nu), f_int(u; theta) = sum_r theta_r g_r(u), the tangent
at other parameters is about a scalar multiple of one factored before
(:mod:`idbench_fem.fem.chords`). :class:`PathSteps` gives a Newton model
:meth:`~PathSteps._path_step`: a step that continues the previous one starts
from the extrapolation of the path's last states and iterates chords with the
factorization that step left, refactoring only when they are slow. It also
holds what the model must provide for that (its elements' moduli and
regions, the external force) and what the batched steps share with it
(:attr:`~PathSteps.unit_moduli`, :meth:`~PathSteps.region_weights`,
:attr:`~PathSteps.batch_stats`).
"""

from __future__ import annotations

import functools
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from idbench_fem.fem import chords
from idbench_fem.fem.newton import NewtonSolve
from idbench_fem.fem.pairs import BatchStats
from idbench_fem.fem.predictions import region_weights

FloatArray = NDArray[np.float64]


@dataclass
class _PathStep:
    """What :meth:`PathSteps._path_step` leaves for the next call.

    Attributes
    ----------
    k, path
        Its load step and the states of the path so far, latest first: its
        solution, its start and, if that call also continued one, the
        previous start (up to :data:`PATH_ORDER` + 1 states).
    theta_f, factorizations
        The parameters of the factorization the solver holds and the model's
        count of factorizations then (reused only if nothing refactored since).
    record, chords
        Its chord iterations (the record of
        :func:`~idbench_fem.fem.chords.modified_newton`) and how many chords
        the next step makes before it refactors (None: no limit): the chords
        kept before one raised |r|
        (:func:`~idbench_fem.fem.chords.useful_chords`), or the limit it had
        itself if it still had to refactor.
    """

    k: int
    path: tuple[FloatArray, ...]
    theta_f: FloatArray
    factorizations: int
    record: list[str] = field(default_factory=list)
    chords: int | None = None


PATH_ORDER = 2
"""Degree of the polynomial through the last states that predicts a step's
start along a path (:meth:`PathSteps._path_step`; 2: quadratic, as the
anchor's extrapolated increment of the batched steps). On the liver's
grasp-lift (1,000 nodes, 20 steps) the residual at the prediction is 2.4x
below that at the previous state with a secant (degree 1), 45x with degree 2."""

_EXTRAPOLATION = {1: (2.0, -1.0), 2: (3.0, -3.0, 1.0)}


class PathSteps(NewtonSolve):
    """Mixin: :meth:`_path_step` for a Newton model whose force is linear in theta.

    The model provides, besides :class:`~idbench_fem.fem.newton.NewtonSolve`'s
    needs, ``element_regions`` (each element's parameter, (T,)),
    ``external_force(k)`` and ``element_moduli(theta, k)`` (the elements'
    moduli, linear in theta); it may override :meth:`prescribe` and
    :meth:`_path_reference`.
    """

    element_regions: NDArray[np.int64]
    _batch_stats: BatchStats | None = None
    _last_path_step: _PathStep | None = None
    RUN_CACHES = (*NewtonSolve.RUN_CACHES, "_batch_stats", "_last_path_step")

    def external_force(self, k: int) -> FloatArray:  # pragma: no cover
        """External force on the free dofs at load step ``k``, (n_state,)."""
        raise NotImplementedError

    def element_moduli(  # pragma: no cover
        self, theta: FloatArray, k: int | None
    ) -> FloatArray:
        """The elements' moduli (T,) at ``theta``, checked (a failure at step k)."""
        raise NotImplementedError

    def _path_reference(
        self, k: int, u: FloatArray, modulus: FloatArray, f_ext: FloatArray
    ) -> float:
        """|r| at ``u`` (converged at step k - 1) for step k: the load increment.

        A model that prescribes displacements (no load increment) evaluates it.
        """
        return float(np.linalg.norm(f_ext - self.external_force(k - 1)))

    def prescribe(self, k: int, fraction: float = 1.0) -> None:
        """Set any prescribed displacements to step k's (none here)."""

    @functools.cached_property
    def unit_moduli(self) -> FloatArray:
        """The elements' moduli at theta = 1, (T,).

        f_int(u; theta) = sum_r theta_r g_r(u), g_r evaluated at these moduli.
        """
        return self.element_moduli(np.ones(self.parameters.p), None)

    def region_weights(self) -> FloatArray:
        """Stiffness fraction of each parameter region, (p,).

        See :func:`~idbench_fem.fem.predictions.region_weights`; they scale a
        factorization to other parameters (:mod:`idbench_fem.fem.chords`).
        """
        return region_weights(
            self.element_regions, self._asm.volumes, self.unit_moduli,
            self.parameters.p,
        )  # fmt: skip

    @property
    def batch_stats(self) -> BatchStats:
        """Chord iterations and pairs of the path and batched steps so far."""
        if self._batch_stats is None:
            self._batch_stats = BatchStats()
        return self._batch_stats

    def _path_step(
        self, theta: FloatArray, k: int, state: FloatArray, modulus: FloatArray
    ) -> FloatArray:
        """One load step along a path, reusing the last step's factorization.

        The rule (:data:`~idbench_fem.fem.chords.CHORD_LIMITS` for when to
        refactor): when this call continues the previous one on this model
        (step k after k - 1, from the state that call returned, bitwise) and
        the solver still holds the factorization that call left (no
        factorization since), the step starts from the extrapolation of the
        path's last states (quadratic, :data:`PATH_ORDER`, or a secant after
        one step; from ``state`` if the prediction inverts an element or has a
        residual above the load increment, which is the residual at
        ``state``; evaluated there when the model prescribes displacements,
        :meth:`_path_reference`) and iterates chords with that factorization
        (refactoring after as many chords as paid on the step before, if one
        there raised |r|), scaled to ``theta`` (:mod:`idbench_fem.fem.chords`);
        a chord that cuts |r| by less than SLOW, or MAX_MODIFIED chords in a
        row, refactor at the iterate.
        Otherwise it is the model's plain Newton from ``state``. Either way
        the result meets the same residual test, so it equals a fresh solve
        to the Newton tolerance (not bitwise), and the same calls on a fresh
        model give the same numbers (the cache is this instance's and keyed
        on its own last call).
        """
        u = np.array(state, dtype=np.float64)
        f_ext = self.external_force(k)
        prev = self._last_path_step
        self._last_path_step = None
        out = None
        record: list[str] = []
        continues = (
            prev is not None and prev.k == k - 1 and np.array_equal(prev.path[0], u)
        )
        reuse = prev is not None and prev.factorizations == self.factorizations
        if continues and reuse and prev is not None:
            asm = self._asm
            tol = max(self.rtol * float(np.linalg.norm(f_ext)), self.atol)
            coef = _EXTRAPOLATION[min(PATH_ORDER, len(prev.path) - 1)]
            guess = np.sum([c * x for c, x in zip(coef, prev.path, strict=False)], 0)
            kin = asm.kinematics(guess, modulus)
            res = asm.forces(kin) - f_ext
            # the residual at ``state`` (converged at step k - 1) is the load
            # increment to the tolerance: evaluated only if the guess is worse
            step_load = self._path_reference(k, u, modulus, f_ext)
            if np.all(kin.det > 0) and np.linalg.norm(res) < step_load:
                u = guess
            else:
                kin = asm.kinematics(u, modulus)
                res = asm.forces(kin) - f_ext
            if np.all(kin.det > 0):
                self.last_residuals = [float(np.linalg.norm(res))]
                out, theta_f = chords.modified_newton(
                    self, theta, modulus, f_ext, u, kin, res, tol, k,
                    prev.theta_f, self.region_weights(), prev.chords, record,
                )  # fmt: skip
                self.last_update_factored = False
        if out is None:
            out, _ = self._newton(modulus, f_ext, np.array(state, dtype=np.float64), k)
            theta_f = theta
        assert theta_f is not None
        path: tuple[FloatArray, ...] = (out.copy(), np.array(state, dtype=np.float64))
        if continues and prev is not None:
            path += prev.path[1:PATH_ORDER]
        limit = chords.useful_chords(record)
        if limit is None and continues and prev is not None and "F" in record:
            limit = prev.chords  # the limit held and a refactorization was due
        self._last_path_step = _PathStep(
            k, path, np.array(theta_f, dtype=np.float64), self.factorizations,
            record, limit,
        )  # fmt: skip
        return out
