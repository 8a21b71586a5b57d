r"""Chord iterations on a held factorization: plain, or Anderson-accelerated.

A pair (theta, u) of a load step converges by chord (modified Newton)
iterations u <- u - K_f^-1 r(u) / s with the last factorization K_f, s its
scale to theta: for an internal force linear in the region moduli,
K(u; theta) is about s K(u_f; theta_f) with
s = prod_r (theta_r / theta_{f,r})^{w_r}, w the regions' stiffness
fractions (:func:`~idbench_fem.fem.predictions.region_weights`). Each
iteration tests the *true* residual r(u) = f_int(u; theta) - f_ext against
the tolerance of the model's ``step`` and backtracks while an element would
invert (det F > 0); when chords are slow (:data:`CHORD_LIMITS`) the tangent
is refactored at the iterate, and that factorization serves what follows.

:func:`modified_newton` iterates plain chords; :func:`accelerated_chords`
combines the last iterates (Anderson: GMRES preconditioned by K_f on a
linear residual, :data:`ANDERSON`). Both work on any :class:`Factored`
system (the models of :mod:`idbench_fem.fem.batched`) and raise
:class:`idbench.ModelFailure` when they do not converge.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any, Protocol

import numpy as np
from numpy.typing import NDArray

from idbench import ModelFailure
from idbench_fem.fem.newton import backtrack
from idbench_fem.fem.pairs import BatchStats

if TYPE_CHECKING:
    from idbench_fem.fem.svk_assembly import Kinematics

FloatArray = NDArray[np.float64]


class Factored(Protocol):
    """What the chord iterations use of a model (a Newton one, with batched steps).

    ``assembler`` (``kinematics``, ``forces``, ``compiled``), ``factor`` the
    tangent at some kinematics, ``solve`` with the factorization held,
    ``count`` Newton iterations and linear solves, ``batch_stats`` (chord
    iterations are added to its ``modified``) and ``max_iterations`` (of
    factorizations before a failure): what
    :class:`~idbench_fem.fem.newton.NewtonSolve` and
    :class:`~idbench_fem.fem.batched.BatchedSteps` give a model.
    """

    max_iterations: int

    @property
    def assembler(self) -> Any:
        """The model's assembler."""

    @property
    def batch_stats(self) -> BatchStats:
        """The batched steps' work counters."""

    def factor(self, kin: Any, modulus: FloatArray, k: int) -> None:
        """Factor the tangent at ``kin`` (ModelFailure at step k if it fails)."""

    def solve(self, rhs: FloatArray) -> FloatArray:
        """K_f^-1 ``rhs`` with the factorization held."""

    def count(
        self, forward_solves: int = 0, newton_its: int = 0, linear_solves: int = 0
    ) -> None:
        """Add to the model's work counters."""


CHORD_LIMITS = {False: (0.1, 6), True: (0.5, 15)}
"""(SLOW, MAX_MODIFIED) by whether the assembler's residuals are compiled.

A chord iteration is refactored away when it reduces |r| by less than a
factor SLOW, or after MAX_MODIFIED in a row. It costs a residual and a
back-substitution: with numpy kernels about a quarter of a Newton iteration
at 500 nodes (kernel and factorization), and a rate slower than 0.1 does not
pay; with the compiled kernel (:mod:`idbench_fem.fem.kernels`) about a
fifteenth, and chords pay down to 0.5. Measured on the RO-UKF path with p = 4
(benchmarks/filters.py, one process): numpy 3.38 forward steps a step with
(0.1, 6), 4.14 with (0.5, 15); compiled 2.62 with (0.1, 6) and 6.3
factorizations a step, 2.1-2.3 with (0.4-0.6, 15-30) and 3.2-3.4.
"""


ANDERSON = {"depth": 12, "most": 16}
"""The accelerated chords of the sigma points (:func:`accelerated_chords`):
``depth``, the past iterations whose differences the Anderson step combines;
``most``, the iterations with one factorization before the tangent is
refactored at the iterate. Measured on the RO-UKF path (benchmarks/organs.py,
one process; the work a step, factorizations, back-substitutions and
residuals, at their unit costs measured alone at load 0.4): kidney p = 2 at
2,000 nodes 48 ms a step (0.4 factorizations, 32 solves) against 79 with the
chords of :func:`modified_newton` (2.3, 25); most 12: 52, 25: 59; depth 4:
54-62. Liver p = 4 slabs at 1,000 nodes 45 (3.55 factorizations, 45 solves)
against 42 (4.05, 32); most 25: 41 (0.9, 70), 12: 44. A nodal regional
scaling of the preconditioner instead of the scalar s raised the residual
at the first iteration (kidney 81 ms)."""


def modified_newton(
    system: Factored,
    theta: FloatArray,
    modulus: FloatArray,
    f_ext: FloatArray,
    u: FloatArray,
    kin: Kinematics | None,
    res: FloatArray,
    tol: float,
    k: int,
    theta_f: FloatArray | None,
    weights: FloatArray,
    first_chords: int | None = None,
    record: list[str] | None = None,
) -> tuple[FloatArray, FloatArray | None]:
    """Chord iterations with the factored tangent, refactoring when they are slow.

    ``kin`` and ``res`` are the kinematics (None: computed when needed) and the
    residual at the start ``u``; ``theta_f`` is the theta of the factorization
    held (None: none, the first iteration factors). Returns the converged state
    and the theta of the factorization now held. ``first_chords``: refactor
    after that many chords with the given factorization, before any test
    says so (0: at once). ``record`` gets "c" for each chord kept, "x" for
    one discarded (it raised |r|) and "F" for each factorization.
    """
    asm = system.assembler
    stats = system.batch_stats
    slow, most = CHORD_LIMITS[asm.compiled]
    norm = float(np.linalg.norm(res))
    if norm <= tol:
        return u, theta_f
    first = norm
    refactor = theta_f is None or first_chords == 0
    modified = full = in_row = 0
    log = [] if record is None else record
    while True:
        if refactor:
            if kin is None:
                kin = asm.kinematics(u, modulus)
            system.factor(kin, modulus, k)
            log.append("F")
            theta_f = theta
            scale = 1.0
            full += 1
            in_row = 0
        else:
            assert theta_f is not None  # refactor starts True without one
            in_row += 1
            scale = float(np.exp(weights @ np.log(theta / theta_f)))
            modified += 1
        du = system.solve(-res) / scale
        system.count(newton_its=1, linear_solves=1)
        u_new, kin_new, res_new, norm_new = updated(asm, u, du, modulus, f_ext, k)
        if norm_new <= tol:
            stats.modified += modified
            return u_new, theta_f
        if full >= system.max_iterations:
            stats.modified += modified
            raise ModelFailure(
                f"batched Newton did not converge ({full} full, {modified} modified "
                f"iterations): |r| = {norm_new:.3e} > tol {tol:.3e} "
                f"(first |r| = {first:.3e})",
                step=k,
            )
        if norm_new > norm and not refactor:
            log.append("x")
            refactor = True  # the chord step made it worse: discard it, refactor
            continue
        if not refactor:
            log.append("c")
        refactor = norm_new > slow * norm or in_row >= most
        if first_chords is not None and full == 0 and in_row >= first_chords:
            refactor = True
        u, kin, res, norm = u_new, kin_new, res_new, norm_new


def accelerated_chords(
    system: Factored,
    theta: FloatArray,
    modulus: FloatArray,
    f_ext: FloatArray,
    u: FloatArray,
    kin: Kinematics | None,
    res: FloatArray,
    tol: float,
    k: int,
    theta_f: FloatArray | None,
    weights: FloatArray,
) -> tuple[FloatArray, FloatArray | None]:
    """Chord iterations with the held factorization, Anderson-accelerated.

    The chord map u -> u + f(u), f(u) = -K_f^-1 r(u) / s (K_f the held
    factorization, s its scale to theta as in :func:`modified_newton`), is
    a fixed-point iteration whose rate is that of the modes K_f misses (a
    region softer or stiffer than at the factorization, a soft mode of the
    grasp): the chords creep. Anderson's step combines the last
    ``ANDERSON["depth"]`` iterates: with F_j = f(u_j), dF and dU the
    differences of successive F and u, gamma = argmin |F_j - dF gamma| and
    u_{j+1} = u_j + F_j - (dU + dF) gamma, which on a linear residual is
    GMRES preconditioned by K_f (a Krylov acceleration at the cost of a
    chord: one residual and one back-substitution, no tangent). An
    iteration that raises |r| is discarded, and it and
    ``ANDERSON["most"]`` iterations without convergence refactor the
    tangent at the (best) iterate and restart the history; that
    factorization serves the later pairs and the next call. With no
    factorization held this is :func:`modified_newton` (which factors
    first). Same convergence test, backtracking (det F > 0) and failures as
    :func:`modified_newton`; returns the state and the theta of the
    factorization now held.
    """
    if theta_f is None:
        return modified_newton(
            system, theta, modulus, f_ext, u, kin, res, tol, k, theta_f, weights
        )
    asm = system.assembler
    norm = first = float(np.linalg.norm(res))
    if norm <= tol:
        return u, theta_f
    depth, most = ANDERSON["depth"], ANDERSON["most"]
    scale = float(np.exp(weights @ np.log(theta / theta_f)))
    f = -system.solve(res) / scale
    system.count(linear_solves=1)
    dU: list[FloatArray] = []
    dF: list[FloatArray] = []
    its = total = full = 0
    fresh = False  # the last iterate was a Newton step (just refactored)
    while True:
        its += 1
        total += 1
        system.count(newton_its=1)
        step = f
        if dF:
            Fm = np.stack(dF, axis=1)
            step = f - (np.stack(dU, axis=1) + Fm) @ mixing(Fm, f)
        u_new, kin_new, res_new, norm_new = updated(asm, u, step, modulus, f_ext, k)
        if norm_new <= tol:
            system.batch_stats.modified += total - full
            return u_new, theta_f
        if full >= system.max_iterations:
            system.batch_stats.modified += total - full
            raise ModelFailure(
                f"batched Newton did not converge ({full} factorizations, {total} "
                f"accelerated chords): |r| = {norm_new:.3e} > tol {tol:.3e} "
                f"(first |r| = {first:.3e})",
                step=k,
            )
        if norm_new > norm or its >= most:
            if norm_new > norm and not fresh:  # discard the chord that raised |r|
                u_new, kin_new, res_new, norm_new = u, kin, res, norm
            if kin_new is None:
                kin_new = asm.kinematics(u_new, modulus)
            system.factor(kin_new, modulus, k)
            theta_f, scale, its = theta, 1.0, 0
            full += 1
            fresh = True
            dU.clear()
            dF.clear()
            f_new = -system.solve(res_new)
        else:
            fresh = False
            f_new = -system.solve(res_new) / scale
            dU.append(u_new - u)
            dF.append(f_new - f)
            if len(dU) > depth:
                dU.pop(0)
                dF.pop(0)
        system.count(linear_solves=1)
        u, kin, res, norm, f = u_new, kin_new, res_new, norm_new, f_new


def updated(
    asm: Any,
    u: FloatArray,
    du: FloatArray,
    modulus: FloatArray,
    f_ext: FloatArray,
    k: int,
) -> tuple[FloatArray, Kinematics, FloatArray, float]:
    """The backtracked update of a pair and its residual: u, kinematics, r, |r|.

    Raises
    ------
    ModelFailure
        As :func:`~idbench_fem.fem.newton.backtrack`, or for a non-finite residual.
    """
    u_new, kin_new = backtrack(asm, u, du, modulus, k)
    res_new = asm.forces(kin_new) - f_ext
    norm_new = float(np.linalg.norm(res_new))
    if not np.isfinite(norm_new):
        raise ModelFailure("non-finite residual in a batched step", step=k)
    return u_new, kin_new, res_new, norm_new


def mixing(Fm: FloatArray, f: FloatArray) -> FloatArray:
    """Anderson's gamma = argmin |f - Fm gamma|, Fm (n, m) with m small.

    By the normal equations, columns scaled to unit norm and a 1e-10
    ridge (a tenth of the cost of an SVD least squares at n = 2,700, where
    that costs more than the back-substitution); least squares if singular.
    """
    scale = np.linalg.norm(Fm, axis=0)
    scale[scale == 0] = 1.0
    A = Fm / scale
    G = A.T @ A + 1e-10 * np.eye(A.shape[1])
    try:
        return np.asarray(np.linalg.solve(G, A.T @ f) / scale)
    except np.linalg.LinAlgError:
        return np.asarray(np.linalg.lstsq(A, f, rcond=None)[0] / scale)


def useful_chords(record: list[str]) -> int | None:
    """Chords that paid on the previous path step before one raised |r|.

    From a :func:`modified_newton` record: when its chords with the
    factorization it was given ran into a discarded one (``"x"``) before any
    refactorization, the number kept before it (the next step refactors
    after as many, saving the wasted chord); else None (no limit).
    """
    n = 0
    for event in record:
        if event == "c":
            n += 1
        elif event == "x":
            return n
        else:
            return None
    return None
