r"""The camera's pose refined with the model: rigid pose and moduli fitted together.

The rigid registration (:mod:`idbench.observe.registration`) places the rest
cloud on the model's rest surface, and nothing else holds the pose. Where
the rest cloud leaves it loose (a view of flat faces slides along them) or
the rest surface pulls it, the recording's deformed frames say more, but
only through the model: each frame's cloud lies on the surface the model
deforms to under the moduli. :func:`refine` therefore fits the six pose
parameters and :math:`\xi = \ln\theta` together, by robust Gauss-Newton
(Levenberg-Marquardt steps) on the signed distances of the rest cloud to the
rest surface and of every frame's cloud to the model's surface at that
step:

.. math::

    \min_{\omega, \tau, \xi} \sum_i c^2 \ln\left(1 + \frac{r_i^2}{c^2}\right)
    / \sigma^2 + \lVert (\xi - \mu_\xi) / s_\xi \rVert^2,

a small rotation :math:`\omega` about the rest cloud's centroid and a
translation :math:`\tau` applied to every point after the rigid
registration, Cauchy weights at the frames' robust scale :math:`c` (as
the registration's, re-estimated each iteration as the clouds come onto
their surfaces), :math:`\sigma` the clouds' noise, and the run's prior
on :math:`\xi` (the log-normal of :class:`~idbench.LogTransform`) holding
what the frames leave open. The pose's columns are the point-to-plane
derivatives :math:`((x_i - \bar x) \times n_i,\ n_i)`; each modulus's a
forward difference (one path of the model per parameter and iteration).
The filters then run on the frames moved by the refined pose: the pose is
fitted once, before them, not tracked. It is a local fit from the rigid
pose, not a search.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy.spatial.transform import Rotation

from idbench.core.interfaces import (
    FloatArray,
    ForwardModel,
    ModelError,
    ModelFailure,
    Prior,
)
from idbench.estimate.transforms import LogTransform
from idbench.observe.registration import (
    FREEZE,
    INLIER,
    Registration,
    SurfaceIndex,
    robust_scale,
    transform_error,
)
from idbench.observe.surface import surface_of
from idbench.store import registered
from idbench.store.recording import Recording
from idbench.truth.simulate import simulate_path

__all__ = ["COLUMNS", "Refinement", "posed", "refine"]

log = logging.getLogger(__name__)

COLUMNS = ("registration_refined_deg", "registration_refined_mm")
"""The row's columns of a pose refined with the model (:meth:`Refinement.columns`)."""

CANDIDATES = 8
"""Triangles searched per point for the exact closest point."""

STEP = 1e-3
"""Forward-difference step in ln theta."""


@dataclass(frozen=True)
class Refinement:
    """The pose refined with the model, and what it moved.

    Attributes
    ----------
    fit
        The refined transform from the camera's frame to the body's.
    theta
        The moduli fitted with it (natural units, the model's order).
    angle_deg, shift_mm
        How far it turned the rigid registration's pose (degrees) and moved
        the rest cloud's points (the largest displacement, mm).
    iterations, paths
        Gauss-Newton iterations, and paths of the model solved.
    """

    fit: Registration
    theta: FloatArray
    angle_deg: float
    shift_mm: float
    iterations: int
    paths: int

    def columns(self) -> dict[str, float]:
        """A run's row: how far the model moved the rigid pose (deg, mm)."""
        return dict(zip(COLUMNS, (self.angle_deg, self.shift_mm), strict=True))


def posed(
    camera: Recording, body: Recording, rigid: Registration, model: ForwardModel,
    prior: Prior,
) -> tuple[Recording, Refinement]:  # fmt: skip
    """``camera`` (a recording in the camera's frame) moved by the refined pose.

    ``body`` is it moved by the rigid registration ``rigid``; the refinement
    (:func:`refine`) and its cost are logged.
    """
    log.info("refining the pose of %s with the model", camera.path)
    found = refine(body, rigid, model, prior, registered.noise_floor(camera))
    log.info("pose refined: %.3g deg, %.3g mm from the rigid one (%d iterations, "
             "%d paths)", found.angle_deg, found.shift_mm, found.iterations,
             found.paths)  # fmt: skip
    return registered.move(camera, found.fit), found


def refine(
    rec: Recording,
    rigid: Registration,
    model: ForwardModel,
    prior: Prior,
    floor: float,
    *,
    max_iterations: int = 30,
    tolerance: float = 1e-3,
    on_path: Callable[[int], None] | None = None,
) -> Refinement:
    """The rigid pose ``rigid`` and the moduli fitted together on ``rec``'s frames.

    Parameters
    ----------
    rec
        The recording in the body's frame (moved by ``rigid``), its clouds
        the frames' ``points`` and ``rest``.
    rigid
        The rigid registration that moved it.
    model
        The run's model, on the recording's path.
    prior
        The run's prior (natural units); its mean is the first moduli.
    floor
        The clouds' noise std (model units).
    max_iterations, tolerance
        The fit's limit, and its stop: an update moving no point by more
        than ``tolerance`` times the robust scale and no ln theta by more
        than ``tolerance``.
    on_path
        Called with the number of paths solved so far (for progress).
    """
    ln = LogTransform()
    mu, cov = ln.prior(np.asarray(prior.mean, float), np.asarray(prior.std, float))
    s_xi = np.sqrt(np.diag(cov))
    fit = _Problem(rec, model, on_path)
    R, t, xi = np.eye(3), np.zeros(3), mu.copy()
    at = fit.surfaces(xi)
    r, n = fit.residuals(R, t, at)
    c = math.inf

    def cost(r: FloatArray, xi: FloatArray) -> float:
        data = c**2 * np.log1p((r / c) ** 2).sum() / floor**2
        return float(data + np.sum(((xi - mu) / s_xi) ** 2))

    lam, its = 1e-3, 0
    prior_h = np.zeros((6 + xi.size,) * 2)
    prior_h[6:, 6:] = np.diag(1.0 / s_xi**2)
    while its < max_iterations:
        its += 1
        c = robust_scale(r[len(fit.rest) :], floor)  # the frames', as they come on
        now = cost(r, xi)
        A = fit.jacobian(R, t, xi, r, n)
        w = 1.0 / (1.0 + (r / c) ** 2) / floor**2
        H = A.T @ (A * w[:, None]) + prior_h
        g = A.T @ (w * r)
        g[6:] += (xi - mu) / s_xi**2
        while True:
            step = np.asarray(np.linalg.solve(H + lam * np.diag(np.diag(H)), -g), float)
            R2, t2 = _turned(R, t, step[:3], step[3:6], fit.centre)
            try:
                at2 = fit.surfaces(xi + step[6:])
            except (ModelError, ModelFailure):  # moduli the model cannot take
                then = math.inf
            else:
                r2, n2 = fit.residuals(R2, t2, at2)
                then = cost(r2, xi + step[6:])
            if then <= now or lam > 1e6:
                break
            lam *= 10.0
        if then > now:  # no step lowers the cost: the last iterate is the fit
            break
        R, t, xi, at, r, n = R2, t2, xi + step[6:], at2, r2, n2
        lam = max(lam / 10.0, 1e-6)
        moved = np.linalg.norm(step[:3]) * fit.reach + np.linalg.norm(step[3:6])
        small = moved <= tolerance * c and np.all(np.abs(step[6:]) <= tolerance)
        if its > FREEZE and small:  # the scale settled, and the fit
            break
    rest = r[: len(fit.rest)]
    return _result(rigid, R, t, fit.rest, rest, floor, ln.to_theta(xi), its,
                   fit.paths)  # fmt: skip


class _Problem:
    """The clouds of a recording against its model's surfaces."""

    def __init__(
        self, rec: Recording, model: ForwardModel,
        on_path: Callable[[int], None] | None,
    ) -> None:  # fmt: skip
        self.model, self.on_path, self.paths = model, on_path, 0
        self.rest = _finite(rec.rest)
        self.centre = self.rest.mean(axis=0)
        self.reach = float(np.linalg.norm(self.rest - self.centre, axis=1).max())
        clouds = [(f.step, _finite(p)) for f in rec.frames for p in _points(f.data)]
        self.clouds = [(k, p) for k, p in clouds if len(p)]
        self.at_rest = SurfaceIndex(*surface_of(model, model.reset()), CANDIDATES)

    def surfaces(self, xi: FloatArray) -> dict[int, SurfaceIndex]:
        """The model's surface at each frame's step, for theta = exp(xi)."""
        states = simulate_path(self.model, np.exp(xi))
        self.paths += 1
        if self.on_path is not None:
            self.on_path(self.paths)
        return {
            k: SurfaceIndex(*surface_of(self.model, states[k - 1]), CANDIDATES)
            for k in sorted({k for k, _ in self.clouds})
        }

    def residuals(
        self, R: FloatArray, t: FloatArray, at: dict[int, SurfaceIndex]
    ) -> tuple[FloatArray, FloatArray]:
        """Signed distances (rest cloud first) and their triangles' normals."""
        rs, ns = [], []
        pairs = [(self.at_rest, self.rest), *((at[k], p) for k, p in self.clouds)]
        for surface, p in pairs:
            x = p @ R.T + t
            q, n = surface.closest(x)
            rs.append(np.einsum("ij,ij->i", n, x - q))
            ns.append(n)
        return np.concatenate(rs), np.vstack(ns)

    def jacobian(
        self, R: FloatArray, t: FloatArray, xi: FloatArray, r: FloatArray,
        n: FloatArray,
    ) -> FloatArray:  # fmt: skip
        """D r / d (omega, tau, xi): point-to-plane, then forward differences."""
        x = np.vstack([p for _, p in [(None, self.rest), *self.clouds]]) @ R.T + t
        cols = [np.cross(x - self.centre, n), n]
        for j in range(xi.size):
            e = np.zeros_like(xi)
            e[j] = STEP
            col = (self.residuals(R, t, self.surfaces(xi + e))[0] - r) / STEP
            col[: len(self.rest)] = 0.0  # the rest does not depend on theta
            cols.append(col[:, None])
        return np.hstack(cols)


def _turned(
    R: FloatArray, t: FloatArray, omega: FloatArray, tau: FloatArray,
    centre: FloatArray,
) -> tuple[FloatArray, FloatArray]:  # fmt: skip
    """(R, t) followed by a rotation ``omega`` about ``centre`` and ``tau``."""
    inc = Rotation.from_rotvec(omega).as_matrix()
    return inc @ R, inc @ (t - centre) + centre + tau


def _result(
    rigid: Registration, R: FloatArray, t: FloatArray, rest: FloatArray,
    r: FloatArray, floor: float, theta: FloatArray, its: int, paths: int,
) -> Refinement:  # fmt: skip
    """The composed transform (camera -> body), its rest-cloud fit and the move."""
    inside = np.abs(r) <= INLIER * floor
    rms = float(np.sqrt(np.mean(r[inside] ** 2))) if inside.any() else math.inf
    fit = Registration(R @ rigid.rotation, R @ rigid.translation + t, rms,
                       float(inside.mean()), robust_scale(r, floor), its,
                       rigid.start, rigid.backend)  # fmt: skip
    camera = (rest - rigid.translation) @ rigid.rotation  # the camera's frame
    angle, shift = transform_error(fit, rigid.rotation, rigid.translation, camera)
    return Refinement(fit, np.asarray(theta, float), angle, 1e3 * shift, its, paths)


def _points(data: Mapping[str, Any]) -> list[FloatArray]:
    """A frame's clouds (each block's ``points``)."""
    return [np.asarray(v, float) for name, v in data.items()
            if name.rpartition("/")[2] == "points"]  # fmt: skip


def _finite(points: Any) -> FloatArray:
    p = np.asarray(points, dtype=float).reshape(-1, 3)
    return p[np.all(np.isfinite(p), axis=1)]
