"""Newton's method for one quasi-static load, shared by the beam and the solid.

The models keep their own assembly (a ``kinematics(u, modulus)`` / ``forces``
/ ``tangent_data`` assembler); this mixin builds the sparse pattern and the
linear solver on first use and owns the iteration: the residual test against
``max(rtol |f_ext|, atol)``, the divergence and iteration-limit checks, the
factorization (or a chord step, see :data:`CHORD_RATIO`) and solve, and the
halving of the update while an element would invert (det F <= 0).
"""

from __future__ import annotations

import copy
import functools
from typing import Any

import numpy as np
import scipy.sparse as sp
from numpy.typing import NDArray

from idbench import Cost, ModelFailure, ParameterSpec
from idbench_fem.fem.solver import SolverError, make_solver

FloatArray = NDArray[np.float64]

BACKTRACKS = 8
"""Halvings of a Newton update tried before an inversion is a failure."""


class InvertedElements(ModelFailure):
    """Every backtrack of a Newton update inverted an element (det F <= 0)."""


def backtrack(
    asm: Any, u: NDArray[np.float64], du: NDArray[np.float64], modulus: Any, k: int
) -> tuple[NDArray[np.float64], Any]:
    """``u + du``, ``du`` halved up to :data:`BACKTRACKS` times until no tet inverts.

    Returns the new displacement and its kinematics (``asm.kinematics``).

    Raises
    ------
    ModelFailure
        For a non-finite update; :class:`InvertedElements` when every
        backtrack inverts an element.
    """
    if not np.all(np.isfinite(du)):
        raise ModelFailure("non-finite Newton update", step=k)
    for _ in range(BACKTRACKS + 1):
        u_new = u + du
        kin = asm.kinematics(u_new, modulus)
        if np.all(kin.det > 0):
            return u_new, kin
        du = 0.5 * du
    raise InvertedElements("inverted element (det F <= 0) in every backtrack", step=k)


CHORD_RATIO = 1e-2
"""An update that cut the residual at least this much keeps its factorization
for the next iteration (a chord step: residual assembly and one solve, no
tangent, no factorization); a weaker cut refactors. Near the solution the
tangent hardly changes, so chords converge almost as fast as Newton steps at a
fraction of their cost (the factorization is 70-85% of a Newton iteration
from 4,000 nodes up). The tolerance test is on the true residual either way."""


ASSEMBLY_BUFFERS = ("_block_work", "_blocks", "_u_full")
"""The assemblers' work arrays, written by every assembly (not frozen)."""


def checked_theta(theta: FloatArray, p: int, k: int | None) -> FloatArray:
    """Theta as a flat (p,) array, checked.

    Raises
    ------
    ValueError
        For a shape other than (p,).
    ModelFailure
        At step k, for a parameter that is not positive and finite.
    """
    th = np.asarray(theta, dtype=np.float64).reshape(-1)
    if th.shape != (p,):
        raise ValueError(f"theta has shape {th.shape}, expected ({p},)")
    if not np.all(np.isfinite(th)) or np.any(th <= 0):
        raise ModelFailure(
            f"parameters {th.tolist()} are not positive and finite", step=k
        )
    return th


def checked_state(
    state: FloatArray, k: int, substeps: int, n_steps: int, n_state: int
) -> FloatArray:
    """A step's start ``state`` as a new float array, the step's arguments checked.

    Raises
    ------
    ValueError
        For a load step k outside 1..n_steps, ``substeps`` below 1, or a
        state of a shape other than (n_state,).
    """
    if not 1 <= k <= n_steps:
        raise ValueError(f"load step k = {k}: must be in 1..{n_steps}")
    if substeps < 1:
        raise ValueError(f"substeps = {substeps}: must be >= 1")
    u = np.array(state, dtype=np.float64)
    if u.shape != (n_state,):
        raise ValueError(f"state has shape {u.shape}, expected ({n_state},)")
    return u


def freeze(obj: Any, keep: tuple[str, ...] = ()) -> None:
    """Make the arrays ``obj`` holds directly read-only (but those in ``keep``).

    Also the arrays of the scipy sparse matrices it holds. The models'
    constants are shared by the copies their runs get (:meth:`NewtonSolve.__copy__`):
    a plugin that writes into one gets a ValueError (its run fails, naming
    it) instead of changing every later run.
    """
    for name, value in vars(obj).items():
        if name in keep:
            continue
        arrays = [value]
        if sp.issparse(value):
            arrays = [value.data, value.indices, value.indptr]
        for a in arrays:
            if isinstance(a, np.ndarray):
                a.flags.writeable = False


class NewtonSolve:
    """Mixin: :meth:`_newton` and :meth:`factor` for a model with an assembler.

    The model provides ``_asm`` (the assembler), ``backend`` (the linear
    solver's name), ``rtol``, ``atol``, ``max_iterations``, ``_cost``
    ([solves, Newton iterations, linear solves]), ``parameters`` (for the
    theta check :meth:`_theta`), and may set ``chord_ratio`` (default
    :data:`CHORD_RATIO`; 0 refactors every iteration: plain Newton); the
    mixin keeps ``last_residuals`` (the residual norms of the last load
    solved) and ``factorizations`` (a count).

    What other code uses of the model is public: :attr:`assembler`,
    :meth:`factor`, :meth:`solve` (a back-substitution with the factorization
    held), :meth:`count` and :meth:`cost` (the work counters).
    """

    _asm: Any
    backend: str
    _cost: list[int]
    parameters: ParameterSpec
    rtol: float
    atol: float
    max_iterations: int
    last_residuals: list[float]
    factorizations: int = 0
    chord_ratio: float = CHORD_RATIO
    last_update_factored: bool = False
    """Whether the last load solved ended with a Newton (not chord) update:
    then the solver holds K at the iterate before the solution, close enough
    for one step of iterative refinement (the models' sensitivities)."""

    @property
    def assembler(self) -> Any:
        """The assembler: ``kinematics(u, modulus)``, ``forces``, ``tangent_data``."""
        return self._asm

    def cost(self) -> Cost:
        """Cumulative forward solves, Newton iterations and linear solves."""
        return Cost(*self._cost)

    def count(
        self, forward_solves: int = 0, newton_its: int = 0, linear_solves: int = 0
    ) -> None:
        """Add work to the counters of :meth:`cost`."""
        self._cost[0] += forward_solves
        self._cost[1] += newton_its
        self._cost[2] += linear_solves

    def solve(self, rhs: FloatArray) -> FloatArray:
        """K^-1 ``rhs`` with the factorization held (uncounted: see :meth:`count`).

        ``rhs`` (n,) or (n, m); the tangent was factored by :meth:`factor`.
        """
        return np.asarray(self._solver.solve(rhs))

    @functools.cached_property
    def _pattern(self) -> Any:
        """The tangent's sparse pattern, built on first use.

        A model that is only probed (a truth read from the cache) never
        needs it: building it is most of a large model's set-up.
        """
        return self._asm.pattern(upper=self.backend == "pardiso")

    @functools.cached_property
    def _solver(self) -> Any:
        """The linear solver on :attr:`_pattern`, made on first use."""
        return make_solver(self.backend, self._pattern.indptr, self._pattern.indices)

    _factored_key: tuple[bytes, bytes] | None = None

    RUN_CACHES: tuple[str, ...] = ("_factored_key", "last_update_factored")
    """Attributes a copy for a run (:meth:`__copy__`) starts without: it
    starts from the class defaults, as a model just built."""

    def __copy__(self) -> Any:
        """A copy for one run: its own counters, caches and assembler object.

        idbench gives each run ``copy.copy`` of the model it built once
        (:mod:`idbench.run.isolation`), so what a run assigns to its model stays
        in its copy. The copy shares the master's read-only arrays (see
        :func:`freeze`), its sparse pattern and its linear solver (built here
        first, so that no run pays for them): every run's first solve
        factors, so the factorization the solver holds from an earlier run
        is never used, and a run's numbers depend on the run only.
        """
        self._solver  # noqa: B018  (built once, on the master)
        new = object.__new__(type(self))
        new.__dict__.update(self.__dict__)
        for name in self.RUN_CACHES:
            new.__dict__.pop(name, None)
        new._cost = list(self._cost)
        new.last_residuals = []
        new._asm = copy.copy(self._asm)
        new.__dict__["_master"] = self.__dict__.get("_master", self)
        return new

    def _key(self, theta: FloatArray, u: FloatArray) -> tuple[bytes, bytes]:
        return np.asarray(theta, dtype=np.float64).tobytes(), u.tobytes()

    def _remember_factorization(self, theta: FloatArray, u: FloatArray) -> None:
        """After a step to ``u``: note whether its factorization can serve it.

        It can if the last Newton update was one (see
        :attr:`last_update_factored`); :meth:`_state_sensitivity` reuses it then.
        """
        self._factored_key = self._key(theta, u) if self.last_update_factored else None

    def _state_sensitivity(
        self,
        theta: FloatArray,
        k: int,
        u: FloatArray,
        modulus: FloatArray,
        g: FloatArray,
        refine: bool = True,
    ) -> FloatArray:
        """du/dtheta = -K(u)^-1 g (n, p) at the converged ``u``.

        Reuses the factorization of the step just solved to ``u`` with
        ``theta`` (held at the iterate before ``u``; with ``refine``, one step
        of iterative refinement with K(u) removes that O(|last update|)
        error), else factors K(u).
        """
        key = self._key(theta, u)
        kin = self._asm.kinematics(u, modulus)
        exact = key != self._factored_key
        if exact:
            self.factor(kin, modulus, k)
            self._factored_key = key
        p = g.shape[1]
        du = -self._solver.solve(g)
        self._cost[2] += p
        if not exact and refine:
            data = self._asm.tangent_data(kin, modulus, self._pattern)
            du += self._solver.solve(-g - self._pattern.matvec(data, du))
            self._cost[2] += p
        return np.asarray(du)

    def _theta(self, theta: FloatArray, k: int | None) -> FloatArray:
        """Theta as a flat (p,) array, checked (:func:`checked_theta`)."""
        return checked_theta(theta, self.parameters.p, k)

    def factor(self, kin: Any, modulus: FloatArray, k: int) -> None:
        """Factor the tangent at ``kin``; a failure is a ModelFailure at step k."""
        self.factorizations += 1
        data = self._asm.tangent_data(kin, modulus, self._pattern)
        try:
            self._solver.factor(data)
        except SolverError as exc:
            raise ModelFailure(f"tangent factorization failed: {exc}", step=k) from exc

    def _newton(
        self, modulus: FloatArray, f_ext: FloatArray, u: FloatArray, k: int
    ) -> tuple[FloatArray, int]:
        """Newton iterations for one load; returns the state and the iterations.

        The tangent is refactored unless the last update cut the residual by
        ``chord_ratio`` (then its factorization is reused: a chord step).
        """
        asm = self._asm
        tol = max(self.rtol * float(np.linalg.norm(f_ext)), self.atol)
        res: list[float] = []
        self.last_residuals = res
        kin = asm.kinematics(u, modulus)
        if not np.all(kin.det > 0):
            raise ModelFailure("the starting state has inverted elements", step=k)
        self.last_update_factored = fresh = False
        for it in range(self.max_iterations + 1):
            r = asm.forces(kin) - f_ext
            norm = float(np.linalg.norm(r))
            res.append(norm)
            if not np.isfinite(norm):
                raise ModelFailure(
                    f"non-finite residual at Newton iteration {it}", step=k
                )
            if norm <= tol:
                self._cost[1] += it
                self.last_update_factored = fresh
                return u, it
            if it == self.max_iterations or norm > 1e10 * max(res[0], tol):
                self._cost[1] += it
                raise ModelFailure(
                    f"Newton did not converge in {it} iterations: |r| = {norm:.3e} "
                    f"> tol {tol:.3e} (first |r| = {res[0]:.3e})",
                    step=k,
                )
            fresh = it == 0 or norm > self.chord_ratio * res[-2]
            if fresh:
                self.factor(kin, modulus, k)
            du = self._solver.solve(-r)
            self._cost[2] += 1
            try:
                u, kin = backtrack(asm, u, du, modulus, k)
            except InvertedElements:
                self._cost[1] += it + 1
                raise
        raise AssertionError("unreachable")  # pragma: no cover
