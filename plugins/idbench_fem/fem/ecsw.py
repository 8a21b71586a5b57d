r"""Energy-conserving sampling and weighting (ECSW): the elements a reduced model keeps.

Hyper-reduction replaces the sum over all T elements of a reduced force by
a weighted sum over a few (Farhat, Avery, Chapman and Cortial, IJNME 2014).
For each training snapshot s (reduced coordinates q_s, lifted to V q_s) and
element e, its contribution to region rho's reduced force at unit modulus is
c_se = c_e V_e^T f_e^1(V_e q_s) (r,); the weights w >= 0 solve

.. math::

    \min_{w \ge 0} \|w\|_0 \quad\text{such that}\quad
    \| C w - b \| \le \tau \| b \|,\qquad b = C\,\mathbf{1},

with C the stacked contributions (N r x T_rho) of the region's elements and
b the exact reduced force of every snapshot (each snapshot's block scaled to
unit norm, so small loads count as much as large ones). As in Farhat's
sparse NNLS and Chapman et al.'s accelerated variant, a greedy active set:
add the elements with the largest positive gradient C^T (b - C w), solve the
non-negative least squares on the active set (:func:`scipy.optimize.nnls`),
drop the zero weights, stop at the tolerance.

Why ECSW rather than DEIM: the reduced force stays a weighted sum of element
forces with w >= 0, so its Jacobian is the same weighted sum of element
tangents: symmetric, the derivative of a (weighted) energy, positive definite
wherever the elements' tangents are. Newton on q then converges as on the
full model; DEIM interpolates the force vector and gives a non-symmetric
reduced Jacobian that can lose stability. Both laws are linear in each
region's modulus, so each region is sampled on its own and theta stays exact.

A training snapshot whose projection inverts an element (a large
deformation that r modes do not hold on a fine mesh) is left out, with a
warning. C is never formed: the element forces of every snapshot are kept (N, T, 12)
(float32) and the gradient is computed by lifting the residual, so memory
grows with N T, not N r T.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy.optimize import nnls

from idbench_fem.fem.element_set import ElementSet

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class Sampling:
    """The sampled elements, their weights and how well they fit the training.

    Attributes
    ----------
    elements
        Indices of the kept elements into the mesh's tets (sorted).
    weights
        Their weights w_e > 0.
    residual
        The training fit reached, |C w - b| / |b|, worst region.
    """

    elements: IntArray
    weights: FloatArray
    residual: float


def ecsw(
    elements: ElementSet,
    element_dofs: IntArray,
    basis: FloatArray,
    factors: FloatArray,
    regions: IntArray,
    p: int,
    training: FloatArray,
    tolerance: float = 1e-3,
    max_elements: int | None = None,
) -> Sampling:
    """ECSW weights for every region (see the module).

    Parameters
    ----------
    elements
        Every element of the mesh (T).
    element_dofs
        Their free-dof indices (T, 12), -1 at fixed dofs.
    basis
        V (n, r).
    factors, regions, p
        c_e (T,), the parameter region of each element (T,), regions.
    training
        Reduced coordinates q_s of the training snapshots (N, r).
    tolerance
        tau, the relative fit of the reduced forces to reach.
    max_elements
        At most this many elements per region (None: no cap).
    """
    if not 0 < tolerance < 1:
        raise ValueError(f"ECSW tolerance {tolerance!r}: need 0 < tol < 1")
    V = np.asarray(basis, dtype=np.float64)
    dofs = np.asarray(element_dofs, dtype=np.int64)
    regions = np.asarray(regions, dtype=np.int64)
    Q = np.atleast_2d(np.asarray(training, dtype=np.float64))
    held = dofs >= 0
    forces, targets = _training(elements, dofs, held, V, factors, regions, p, Q)
    kept: list[IntArray] = []
    weights: list[FloatArray] = []
    worst = 0.0
    for rho in range(p):
        cand = np.flatnonzero(regions == rho)
        idx, w, fit = _greedy(forces, targets[rho], V, dofs, held, cand, tolerance,
                              max_elements)  # fmt: skip
        log.info("ECSW region %d: %d of %d elements, fit %.2e", rho, len(idx),
                 len(cand), fit)  # fmt: skip
        kept.append(idx)
        weights.append(w)
        worst = max(worst, fit)
    order = np.argsort(np.concatenate(kept))
    return Sampling(
        np.concatenate(kept)[order].astype(np.int64),
        np.concatenate(weights)[order],
        worst,
    )


def _training(
    elements: ElementSet, dofs: IntArray, held: NDArray[np.bool_], V: FloatArray,
    factors: FloatArray, regions: IntArray, p: int, Q: FloatArray,
) -> tuple[NDArray[np.float32], FloatArray]:  # fmt: skip
    """Element forces (N, T, 12) and each region's reduced force (p, N, r)."""
    n, r = V.shape
    T = len(dofs)
    forces = np.empty((len(Q), T, 12), dtype=np.float32)
    targets = np.zeros((p, len(Q), r))
    safe = np.where(held, dofs, 0)
    kept = []
    for s, q in enumerate(Q):
        u = V @ q
        ue = np.where(held, u[safe], 0.0).reshape(T, 4, 3)
        st = elements.state(ue)
        fe = elements.forces(st, np.asarray(factors, float))
        if not (np.all(st.det > 0) and np.all(np.isfinite(fe))):
            continue  # its projection inverts an element: no state to train on
        forces[len(kept)] = fe
        for rho in range(p):
            sel = held & (regions == rho)[:, None]
            g = np.bincount(dofs[sel], weights=fe[sel], minlength=n)
            targets[rho, len(kept)] = V.T @ g
        kept.append(s)
    if len(kept) < len(Q):
        log.warning("ECSW: %d of %d projected training snapshots invert an element "
                    "(left out)", len(Q) - len(kept), len(Q))  # fmt: skip
    if not kept:
        raise ValueError("ECSW: every projected training snapshot inverts an element")
    return forces[: len(kept)], targets[:, : len(kept)]


def _greedy(
    forces: NDArray[np.float32], target: FloatArray, V: FloatArray, dofs: IntArray,
    held: NDArray[np.bool_], cand: IntArray, tolerance: float,
    max_elements: int | None,
) -> tuple[IntArray, FloatArray, float]:  # fmt: skip
    """One region's greedy NNLS: kept elements, weights, relative fit."""
    N, r = target.shape
    norms = np.linalg.norm(target, axis=1)
    scale = np.where(norms > 0, 1.0 / np.where(norms > 0, norms, 1.0), 0.0)
    b = (target * scale[:, None]).ravel()
    b_norm = float(np.linalg.norm(b))
    if b_norm == 0.0 or not len(cand):
        return np.zeros(0, np.int64), np.zeros(0), 0.0
    cdofs, cheld = dofs[cand], held[cand]
    safe = np.where(cheld, cdofs, 0)
    Vc = np.where(cheld[:, :, None], V[safe], 0.0)  # (Tc, 12, r)
    cap = len(cand) if max_elements is None else min(len(cand), int(max_elements))

    def column(j: int) -> FloatArray:
        c = np.einsum("ir,si->sr", Vc[j], forces[:, cand[j]].astype(np.float64))
        return np.asarray((c * scale[:, None]).ravel())

    def gradient(res: FloatArray) -> FloatArray:
        lifted = (res.reshape(N, r) * scale[:, None]) @ V.T  # (N, n)
        g = np.zeros(len(cand))
        for s in range(N):
            at = np.where(cheld, lifted[s][safe], 0.0)
            g += np.einsum("ti,ti->t", forces[s, cand], at)
        return g

    active: list[int] = []
    cols: dict[int, FloatArray] = {}
    w = np.zeros(0)
    res = b.copy()
    fit = 1.0
    while fit > tolerance and len(active) < cap:
        g = gradient(res)
        g[active] = -np.inf
        # a quarter more each time (Chapman et al.): few NNLS solves
        batch = max(1, min(max(8, len(active) // 4), cap - len(active)))
        picks = [int(j) for j in np.argsort(-g)[:batch] if g[j] > 0]
        if not picks:
            break
        active.extend(picks)
        for j in picks:
            cols[j] = column(j)
        A = np.column_stack([cols[j] for j in active])
        w, _ = nnls(A, b, maxiter=50 * A.shape[1])
        keep = w > 0
        active = [j for j, k in zip(active, keep, strict=True) if k]
        w = w[keep]
        res = b - A[:, keep] @ w
        fit = float(np.linalg.norm(res)) / b_norm
    return cand[np.array(active, dtype=np.int64)], w, fit
