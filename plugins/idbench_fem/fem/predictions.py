"""Predicting the pairs of a batched step from the anchor's, and their residuals.

Around the anchor's solution u_a at theta_a, the other pairs are predicted as
u_a + S t with S = du/dtheta there and t a step that is theta - theta_a to
the first order (:func:`prediction_steps`); :func:`residuals` evaluates the
predictions' residuals together (vectorised over rows), and
:func:`line_residuals` serves many one-parameter predictions of a cubic
internal force (SVK) from four assemblies. :func:`region_weights` gives the
regions' stiffness fractions that scale a factorization to other parameters
(:mod:`idbench_fem.fem.chords`), :func:`central` the anchor.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import NDArray

FloatArray = NDArray[np.float64]

BETA = 2.0
"""The form of the predictions with several parameters (:func:`prediction_steps`):
linear in 1 / theta, as the tip deflection of slabs in series (their
compliances add). On the RO-UKF path with 4 slabs (benchmarks/filters.py):
6.3 factorizations a step, against 6.7 in log theta and 7.25 linear in theta."""

BETA_ONE = 0.0
"""The form with one parameter: linear in theta. A large deflection stiffens
the beam, so 1 / E overshoots far from the anchor (the RO-UKF's first step
from rest: residual 9e9 x tol against 3e8; 2.1 factorizations a step against
1.55 over the path); near it the forms agree to 1%."""

FAR = 10.0
"""A prediction whose residual exceeds FAR |f_ext| is compared with the given state."""

BATCH_ELEMENTS = 50_000
"""Elements (rows x tets) per vectorised residual evaluation of predictions."""

POLYNOMIAL_ABOVE = 8
"""With one parameter and more predictions than this, their residuals come
from the cubic through four assemblies (:func:`line_residuals`)."""


def central(log_thetas: FloatArray) -> int:
    """Index of the row nearest (L1) to the median of the rows, the first if tied."""
    d = np.abs(log_thetas - np.median(log_thetas, axis=0)).sum(axis=1)
    return int(np.argmin(d))


def prediction_steps(
    theta_a: FloatArray, thetas: FloatArray, beta: float
) -> FloatArray:
    """Steps t (r, p) of the predictions u_a + S t from the anchor's theta_a.

    u is predicted linearly in theta^(1 - beta) (in log theta for beta = 1),
    scaled to the first order of theta: t = theta_a ((theta /
    theta_a)^(1 - beta) - 1) / (1 - beta). Beta = 0 is linear in theta, 2
    linear in 1 / theta (exact for a linear model with one modulus, where u is
    proportional to 1 / E, and for regions in series, whose compliances add).
    """
    if beta == 0.0:
        return np.asarray(thetas - theta_a)
    ratio = thetas / theta_a
    if beta == 1.0:
        return np.asarray(theta_a * np.log(ratio))
    return np.asarray(theta_a * (ratio ** (1.0 - beta) - 1.0) / (1.0 - beta))


def region_weights(
    regions: NDArray[np.int64], volumes: FloatArray, unit_moduli: FloatArray, p: int
) -> FloatArray:
    """Stiffness fraction of each parameter region, (p,).

    A region's volume weighted by its elements' moduli at unit parameters
    (its volume fraction where those are all 1): from each element's region
    (T,), volume (T,) and modulus at unit parameters (T,).
    """
    w = np.bincount(regions, weights=volumes * unit_moduli, minlength=p)
    return np.asarray(w / w.sum())


def residuals(
    asm: Any, states: FloatArray, moduli: FloatArray, f_ext: FloatArray
) -> tuple[NDArray[np.bool_], FloatArray, FloatArray]:
    """Residuals f_int - f_ext of each row (r, n), their norms (r,), det F > 0 (r,).

    Vectorised over rows in chunks of about ``BATCH_ELEMENTS`` elements (one
    row at a time if the assembler's ``STACKS`` is false); rows with an
    inverted element get an infinite norm. ``asm`` is the model's assembler,
    ``moduli`` (r, T) the elements' moduli of each row.
    """
    r = len(states)
    ok = np.zeros(r, dtype=bool)
    norms = np.full(r, np.inf)
    residuals = np.empty_like(states)
    stacks = asm.STACKS
    step = max(1, BATCH_ELEMENTS // asm.n_elements) if stacks else 1
    for lo in range(0, r, step):
        if stacks:
            kin = asm.kinematics(states[lo : lo + step], moduli[lo : lo + step])
            good = np.all(kin.det > 0, axis=1)
            res = asm.forces(kin) - f_ext
        else:  # an assembler of one state at a time
            kin = asm.kinematics(states[lo], moduli[lo])
            good = np.array([np.all(kin.det > 0)])
            res = (asm.forces(kin) - f_ext)[None, :]
        ok[lo : lo + step] = good
        norms[lo : lo + step] = np.where(good, np.linalg.norm(res, axis=1), np.inf)
        residuals[lo : lo + step] = res
    return ok, norms, residuals


def line_residuals(
    asm: Any,
    unit_moduli: FloatArray,
    u_a: FloatArray,
    s: FloatArray,
    t: FloatArray,
    thetas: FloatArray,
    f_ext: FloatArray,
) -> tuple[NDArray[np.bool_], FloatArray, FloatArray]:
    """:func:`residuals` of the predictions u_a + t_j s at theta_j, for p = 1.

    The SVK internal force at unit parameters is a cubic polynomial of the
    displacement (P = F S, S linear in the Green strain, which is quadratic),
    so along the line u_a + t s it is g(t) = c0 + c1 t + c2 t^2 + c3 t^3
    exactly, and so is det F of each element. Four assemblies at Chebyshev
    points of the range of t give the coefficients; every prediction's
    residual theta_j g(t_j) - f_ext is then a polynomial evaluation, O(n)
    instead of an assembly over the elements (the full UKF has 2n + 1
    predictions a step). Round-off: about 1e-12 |f_ext| even for parameters
    30% apart (tests/test_skfem_batched.py), far below the tolerance (1e-8
    |f_ext|). ``unit_moduli`` (T,): the elements' moduli at theta = 1.
    """
    r = len(t)
    h = float(np.max(np.abs(t), initial=0.0))
    if h == 0.0:  # every prediction is u_a itself
        kin = asm.kinematics(u_a, unit_moduli)
        g, good = asm.forces(kin), bool(np.all(kin.det > 0))
        residuals = thetas[:, None] * g - f_ext
        ok = np.full(r, good)
        return ok, np.where(ok, np.linalg.norm(residuals, axis=1), np.inf), residuals
    nodes = h * np.cos(np.pi * (np.arange(4) + 0.5) / 4)  # Chebyshev, in [-h, h]
    unit = unit_moduli
    forces, dets = [], []
    for x in nodes:
        kin = asm.kinematics(u_a + x * s, unit)
        forces.append(asm.forces(kin))
        dets.append(kin.det)
    vander = np.vander(nodes / h, 4, increasing=True)  # scaled: well conditioned
    coef_f = np.linalg.solve(vander, np.array(forces))  # (4, n)
    coef_d = np.linalg.solve(vander, np.array(dets))  # (4, T)
    powers = np.vander(t / h, 4, increasing=True)  # (r, 4)
    residuals = thetas[:, None] * (powers @ coef_f) - f_ext
    ok = np.empty(r, dtype=bool)
    step = max(1, BATCH_ELEMENTS // asm.n_elements)
    for lo in range(0, r, step):
        ok[lo : lo + step] = np.all(powers[lo : lo + step] @ coef_d > 0, axis=1)
    norms = np.where(ok, np.linalg.norm(residuals, axis=1), np.inf)
    return ok, norms, residuals
