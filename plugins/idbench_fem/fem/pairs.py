"""The pairs of a batched step still to converge, and the work done on them.

:class:`PendingPairs` is what a model's
:meth:`~idbench_fem.fem.batched.BatchedSteps.solve_pairs` converges, here or
in a helper process (:mod:`idbench_fem.fem.step_workers`):
:func:`helper_solve` runs in the helper and returns the states with the work
done (:data:`Work`), :func:`collect` takes a helper's answer (or solves the
pairs here if the helper is lost) and :func:`add_work` counts the helper's
work as the model's own (:class:`BatchStats`, the model's ``cost``).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol

import numpy as np
from numpy.typing import NDArray

from idbench import Cost
from idbench_fem.fem.step_workers import Helper, HelperLost

FloatArray = NDArray[np.float64]


@dataclass
class BatchStats:
    """Work of the batched steps, cumulative (for benchmarks and tests).

    Attributes
    ----------
    calls, pairs
        Calls of ``step_many`` and parameter/state pairs advanced.
    modified
        Modified-Newton iterations (residual + back-substitution, no factor).
    converged_at_prediction
        Pairs whose prediction from the anchor already met the tolerance.
    """

    calls: int = 0
    pairs: int = 0
    modified: int = 0
    converged_at_prediction: int = 0


@dataclass
class PendingPairs:
    """Pairs still to converge: what a model's ``solve_pairs`` (in a helper) needs.

    Attributes
    ----------
    thetas, preds, starts
        Parameters (r, p), predicted states (r, n) and the given states
        (r, n), where a row starts if its prediction inverts an element.
    residuals, ok
        The predictions' residuals (r, n) and whether they invert no element
        (r,), if known (else ``solve_pairs`` evaluates them).
    """

    thetas: FloatArray
    preds: FloatArray
    starts: FloatArray
    residuals: FloatArray | None = None
    ok: NDArray[np.bool_] | None = None

    def take(self, index: NDArray[np.intp]) -> PendingPairs:
        """The rows ``index``."""
        known = self.residuals is not None and self.ok is not None
        return PendingPairs(
            self.thetas[index], self.preds[index], self.starts[index],
            self.residuals[index] if known else None,  # type: ignore[index]
            self.ok[index] if known else None,  # type: ignore[index]
        )  # fmt: skip


class PairSolver(Protocol):
    """What the functions here use of a model with batched steps.

    :class:`~idbench_fem.fem.batched.BatchedSteps` gives a model all of it.
    """

    factorizations: int

    @property
    def batch_stats(self) -> BatchStats:
        """The batched steps' work counters."""

    def solve_pairs(
        self, k: int, rows: PendingPairs, theta_f: FloatArray | None
    ) -> tuple[FloatArray, FloatArray | None]:
        """Converge ``rows`` at load step ``k``; the states and the theta held."""

    def prescribe(self, k: int, fraction: float = 1.0) -> None:
        """Set any prescribed displacements to step ``k``'s."""

    def cost(self) -> Cost:
        """Cumulative work."""

    def count(
        self, forward_solves: int = 0, newton_its: int = 0, linear_solves: int = 0
    ) -> None:
        """Add to the work of :meth:`cost`."""


Work = tuple[Cost, int, int, int]
"""A helper's work: the increment of its model's cost, its factorizations,
chord iterations and pairs converged at their prediction."""


def helper_solve(
    model: PairSolver, k: int, rows: PendingPairs
) -> tuple[FloatArray, Work]:
    """``model.solve_pairs`` in a helper process, from no factorization.

    Returns the states and the work done, which the caller adds to its model's
    counters (:func:`add_work`).
    """
    model.prescribe(k)
    stats = model.batch_stats
    cost, fac = model.cost(), model.factorizations
    mod, settled = stats.modified, stats.converged_at_prediction
    states, _ = model.solve_pairs(k, rows, None)
    work = (
        model.cost() - cost,
        model.factorizations - fac,
        stats.modified - mod,
        stats.converged_at_prediction - settled,
    )
    return states, work


def collect(
    model: PairSolver,
    k: int,
    helper: Helper,
    rows: PendingPairs,
    theta_f: FloatArray | None,
) -> tuple[FloatArray, FloatArray | None]:
    """A helper's states for ``rows`` (solved here if the helper is lost)."""
    try:
        states, work = helper.collect()
    except HelperLost:  # solved here instead, as without helpers
        return model.solve_pairs(k, rows, theta_f)
    add_work(model, work)
    return states, theta_f


def add_work(model: PairSolver, work: Work) -> None:
    """Count a helper's work as the model's own."""
    cost, fac, mod, settled = work
    model.count(cost.forward_solves, cost.newton_its, cost.linear_solves)
    model.factorizations += fac
    model.batch_stats.modified += mod
    model.batch_stats.converged_at_prediction += settled
