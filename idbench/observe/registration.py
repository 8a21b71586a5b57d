r"""Rigid registration of a point cloud to a model's surface (robust ICP).

A cloud given in the camera's frame is moved into the model's before a
filter starts: the rigid transform :math:`x = R p + t` that puts the points
p on the model's surface (vertices (V, 3), triangles (F, 3)), found by
point-to-plane ICP with a robust loss, from several starts.

Each iteration takes, for every moved point :math:`x_i`, its exact closest
point :math:`q_i` on the surface (among the ``candidates`` triangles of
nearest centroid, :func:`~idbench.observe.surface.closest_on_triangles`)
and that triangle's normal :math:`n_i`, the residual :math:`r_i = n_i
\cdot (x_i - q_i)`, Cauchy weights :math:`w_i = 1 / (1 + (r_i / c)^2)`
with the scale :math:`c = \max(3 \cdot 1.4826\, \mathrm{median} |r|,
c_{min})` (so a few percent of outliers, an instrument in front of the
organ, barely pull), and solves the linearised weighted least squares for a
small rotation :math:`\omega` about the cloud's centroid :math:`\bar x` and
a translation :math:`\delta`:

.. math::

    \min_{\omega, \delta} \sum_i w_i \left( ((x_i - \bar x) \times n_i)
    \cdot \omega + n_i \cdot \delta + r_i \right)^2,

then moves the points by the exact rotation :math:`\exp(\omega)`. It stops
when an update moves no point by more than ``tolerance`` times the scale
c (fixed after a few iterations), or when the robust cost stops falling
(the closest triangles switching back and forth). Starts: the given
transform and rotations of it about the cloud's centroid by
``start_angle`` about each axis, both ways (7); the best is the one whose
points lie closest to the surface (the robust cost at a common scale). A
result whose inliers (|r| <= 5 ``floor``, the cloud's noise) are fewer
than ``min_inliers``, or that did not converge, raises
:class:`RegistrationError` in one line.

The exact point-to-triangle distance (no sampled surface) is what lets a
1,000-point cloud recover a pose to a fraction of a millimetre; with
``backend = "open3d"`` (the optional Open3D, MIT; not installed with
idbench) the same starts run Open3D's point-to-plane ICP with a Tukey loss
on a dense sample of the surface, and the residual is ours.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy.spatial import cKDTree
from scipy.spatial.transform import Rotation

from idbench.core.interfaces import FloatArray
from idbench.observe.surface import closest_on_triangles

BACKENDS = ("numpy", "open3d")


class RegistrationError(ValueError):
    """A registration that did not converge or does not fit (one line)."""


@dataclass(frozen=True)
class Registration:
    """A rigid transform x = R p + t from the cloud's frame to the model's.

    Attributes
    ----------
    rotation, translation
        R (3, 3) and t (3,) (model units).
    rms
        Root mean square of the inliers' point-to-surface distances after it.
    inliers
        Fraction of the points within :data:`INLIER` ``floor`` of the surface.
    scale
        The robust scale c at the end (model units).
    iterations, start
        ICP iterations of the best start, and which start (0: the given one).
    backend
        ``"numpy"`` or ``"open3d"``.
    """

    rotation: FloatArray
    translation: FloatArray
    rms: float
    inliers: float
    scale: float
    iterations: int
    start: int
    backend: str = "numpy"

    def apply(self, points: FloatArray) -> FloatArray:
        """The points (N, 3) moved into the model's frame."""
        return np.asarray(points, dtype=float) @ self.rotation.T + self.translation

    @property
    def angle_deg(self) -> float:
        """The rotation's angle (degrees)."""
        c = (float(np.trace(self.rotation)) - 1.0) / 2.0
        return math.degrees(math.acos(min(1.0, max(-1.0, c))))

    def summary(self) -> dict[str, float]:
        """Angle (deg), offset |t|, rms and inliers: what a report shows."""
        return {
            "registration_angle_deg": self.angle_deg,
            "registration_offset": float(np.linalg.norm(self.translation)),
            "registration_rms": self.rms,
            "registration_inliers": self.inliers,
        }


def transform_error(
    found: Registration, rotation: FloatArray, translation: FloatArray,
    points: FloatArray,
) -> tuple[float, float]:  # fmt: skip
    """Angle (deg) and largest displacement of ``points`` between two transforms.

    The true transform (``rotation``, ``translation``) maps the cloud into
    the model's frame; the displacement is measured over the cloud's points
    (model units), so it does not depend on where the origin lies.
    """
    d = found.rotation @ np.asarray(rotation).T
    c = (float(np.trace(d)) - 1.0) / 2.0
    angle = math.degrees(math.acos(min(1.0, max(-1.0, c))))
    true = np.asarray(points) @ np.asarray(rotation).T + np.asarray(translation)
    return angle, float(np.linalg.norm(found.apply(points) - true, axis=1).max())


class SurfaceIndex:
    """Closest points on a triangle surface, through a KD-tree of centroids."""

    def __init__(
        self, vertices: FloatArray, triangles: NDArray[np.int64], candidates: int
    ) -> None:
        self.v = np.asarray(vertices, dtype=float)
        self.tri = np.asarray(triangles, dtype=np.int64)
        a, b, c = (self.v[self.tri[:, i]] for i in range(3))
        normal = np.cross(b - a, c - a)
        self.normals = normal / np.linalg.norm(normal, axis=1)[:, None]
        self.tree = cKDTree((a + b + c) / 3.0)
        self.k = int(min(candidates, len(self.tri)))
        self.size = float(np.linalg.norm(np.ptp(self.v[self.tri.ravel()], axis=0)))

    def closest(self, x: FloatArray) -> tuple[FloatArray, FloatArray]:
        """Closest surface point (N, 3) and its triangle's normal (N, 3)."""
        _, idx = self.tree.query(x, k=self.k)
        idx = np.asarray(idx).reshape(len(x), -1)
        rows = np.repeat(x, idx.shape[1], axis=0)
        flat = idx.ravel()
        q, _ = closest_on_triangles(
            rows, self.v[self.tri[flat, 0]], self.v[self.tri[flat, 1]],
            self.v[self.tri[flat, 2]],
        )  # fmt: skip
        d = np.linalg.norm(q - rows, axis=1).reshape(len(x), -1)
        best = np.argmin(d, axis=1)
        pick = np.arange(len(x)) * idx.shape[1] + best
        return q[pick], self.normals[flat[pick]]


INLIER = 5.0
"""An inlier lies within this many ``floor`` (the cloud's noise) of the surface."""

FREEZE = 5
"""ICP iterations after which the robust scale stays fixed."""

STALL = 10
"""ICP iterations without a lower robust cost that end it."""


def robust_scale(r: FloatArray, floor: float) -> float:
    """The robust scale c of residuals ``r``: 3 MAD-sigmas, at least ``floor``."""
    return max(3.0 * 1.4826 * float(np.median(np.abs(r))), floor)


def _icp(
    surface: SurfaceIndex, p: FloatArray, R: FloatArray, t: FloatArray, floor: float,
    max_iterations: int, tolerance: float,
) -> tuple[FloatArray, FloatArray, int, bool]:  # fmt: skip
    """Robust point-to-plane ICP from (R, t); returns R, t, iterations, converged.

    The scale c is the residuals' until :data:`FREEZE` iterations, then
    fixed. Converged: an update moves no point by more than ``tolerance``
    c, or the robust cost at that scale has not fallen by 1e-9 of itself in
    :data:`STALL` iterations (the closest triangles switching back and forth:
    the best iterate is returned).
    """
    c = math.inf
    best: tuple[float, FloatArray, FloatArray] = (math.inf, R, t)
    since = 0
    for it in range(1, max_iterations + 1):
        x = p @ R.T + t
        q, n = surface.closest(x)
        r = np.einsum("ij,ij->i", n, x - q)
        if it <= FREEZE:
            c = robust_scale(r, floor)
        w = 1.0 / (1.0 + (r / c) ** 2)
        cost = float(np.log1p((r / c) ** 2)[w > 0].sum())
        if it > FREEZE:
            since = 0 if cost < best[0] * (1 - 1e-9) else since + 1
            if cost < best[0]:
                best = (cost, R, t)
            if since >= STALL:
                return best[1], best[2], it, True
        centre = x.mean(axis=0)
        A = np.hstack([np.cross(x - centre, n), n])
        Aw = A * w[:, None]
        H = A.T @ Aw + 1e-12 * np.eye(6) * float(np.trace(A.T @ Aw))
        step = np.linalg.solve(H, -(Aw.T @ r))
        inc = Rotation.from_rotvec(step[:3]).as_matrix()
        R = inc @ R
        t = inc @ (t - centre) + centre + step[3:]
        reach = float(np.linalg.norm(x - centre, axis=1).max())
        moved = np.linalg.norm(step[:3]) * reach + np.linalg.norm(step[3:])
        if moved <= tolerance * c:
            return R, t, it, True
    return R, t, max_iterations, False


def _starts(p: FloatArray, R0: FloatArray, t0: FloatArray, angle: float) -> list:
    """The given transform, then rotated about the moved cloud's centroid."""
    out = [(R0, t0)]
    if angle <= 0:
        return out
    centre = (p @ R0.T + t0).mean(axis=0)
    for axis in range(3):
        for sign in (1.0, -1.0):
            v = np.zeros(3)
            v[axis] = sign * math.radians(angle)
            S = Rotation.from_rotvec(v).as_matrix()
            out.append((S @ R0, S @ (t0 - centre) + centre))
    return out


def register(
    points: FloatArray,
    vertices: FloatArray,
    triangles: NDArray[np.int64],
    *,
    rotation: FloatArray | None = None,
    translation: FloatArray | None = None,
    floor: float = 1e-4,
    start_angle: float = 15.0,
    max_iterations: int = 100,
    tolerance: float = 1e-4,
    min_inliers: float = 0.5,
    candidates: int = 8,
    backend: str = "numpy",
) -> Registration:
    """Register ``points`` (N, 3), in the camera's frame, to the surface.

    Parameters
    ----------
    points
        The cloud.
    vertices, triangles
        The model's surface (its unloaded state, or the state the cloud shows).
    rotation, translation
        A first guess of the transform (None: identity, zero).
    floor
        The cloud's noise std (model units): the smallest robust scale c,
        and :data:`INLIER` times it the farthest an inlier lies.
    start_angle
        Degrees of the rotated starts about each axis (0: the guess only).
    max_iterations, tolerance
        ICP's limit, and its stop: an update moving no point by more than
        ``tolerance`` times the robust scale.
    min_inliers
        The fraction of points within 3 c of the surface below which it fails.
    candidates
        Triangles searched per point for the exact closest point.
    backend
        ``"numpy"`` (default, deterministic everywhere) or ``"open3d"``.

    Raises
    ------
    RegistrationError
        No start converged, or too few points fit (one line, with the rms).
    """
    if backend not in BACKENDS:
        raise ValueError(f"backend {backend!r}: allowed: {', '.join(BACKENDS)}")
    p = np.asarray(points, dtype=float)
    p = p[np.all(np.isfinite(p), axis=1)]
    if len(p) < 6:
        raise RegistrationError(f"registration: {len(p)} finite points, need >= 6")
    surface = SurfaceIndex(vertices, triangles, candidates)
    R0 = np.eye(3) if rotation is None else np.asarray(rotation, dtype=float)
    t0 = np.zeros(3) if translation is None else np.asarray(translation, dtype=float)
    tried = []
    for i, (R, t) in enumerate(_starts(p, R0, t0, start_angle)):
        if backend == "numpy":
            out = _icp(surface, p, R, t, floor, max_iterations, tolerance)
        else:
            out = _open3d_icp(surface, p, R, t, floor, max_iterations, tolerance)
        tried.append((*out, i))
    scored = []
    for R, t, its, ok, i in tried:
        x = p @ R.T + t
        q, n = surface.closest(x)
        r = np.einsum("ij,ij->i", n, x - q)
        scored.append((r, R, t, its, ok, i))
    c = min(robust_scale(s[0], floor) for s in scored)  # one scale: comparable costs
    costs = [float(np.log1p((s[0] / c) ** 2).sum()) for s in scored]
    r, R, t, its, ok, i = scored[int(np.argmin(costs))]
    inside = np.abs(r) <= INLIER * floor
    rms = float(np.sqrt(np.mean(r[inside] ** 2))) if inside.any() else math.inf
    fit = Registration(R, t, rms, float(inside.mean()), robust_scale(r, floor), its, i,
                       backend)  # fmt: skip
    if not ok or fit.inliers < min_inliers:
        why = "did not converge" if not ok else "fits too few points"
        raise RegistrationError(
            f"registration {why}: {100 * fit.inliers:.0f}% of {len(p)} points "
            f"within {INLIER * floor:.3g} of the surface (rms {rms:.3g}) after "
            f"{its} iterations, best of {len(tried)} starts; the cloud may show "
            "another body, or lie farther from it than the starts reach"
        )
    return fit


def _open3d_icp(
    surface: SurfaceIndex, p: FloatArray, R: FloatArray, t: FloatArray, floor: float,
    max_iterations: int, tolerance: float,
) -> tuple[FloatArray, FloatArray, int, bool]:  # fmt: skip
    """Open3D's point-to-plane ICP with a Tukey loss (the optional backend)."""
    try:
        import open3d as o3d
    except ImportError:
        raise RegistrationError(
            "registration backend 'open3d': Open3D is not installed (pip install "
            "'idbench[open3d]'), or use backend 'numpy'"
        ) from None
    reg = o3d.pipelines.registration
    target = _open3d_target(o3d, surface)
    source = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(p))
    init = np.eye(4)
    init[:3, :3], init[:3, 3] = R, t
    loss = reg.TukeyLoss(k=3.0 * max(floor, 1e-3 * surface.size / 10))
    result = reg.registration_icp(
        source, target, 0.1 * surface.size, init,
        reg.TransformationEstimationPointToPlane(loss),
        reg.ICPConvergenceCriteria(
            relative_fitness=1e-9, relative_rmse=1e-9, max_iteration=max_iterations
        ),
    )  # fmt: skip
    T = np.asarray(result.transformation)
    return T[:3, :3].copy(), T[:3, 3].copy(), max_iterations, True


def _open3d_target(o3d: Any, surface: SurfaceIndex) -> Any:
    """A dense sample of the surface with normals (cached on ``surface``)."""
    cached = surface.__dict__.get("_o3d")
    if cached is None:
        mesh = o3d.geometry.TriangleMesh(
            o3d.utility.Vector3dVector(surface.v),
            o3d.utility.Vector3iVector(surface.tri.astype(np.int32)),
        )
        mesh.compute_triangle_normals()
        o3d.utility.random.seed(0)  # the sample, hence the result, is repeatable
        cached = mesh.sample_points_uniformly(
            number_of_points=20 * len(surface.tri), use_triangle_normal=True
        )
        surface.__dict__["_o3d"] = cached
    return cached
