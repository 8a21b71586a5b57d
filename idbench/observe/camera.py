"""A pinhole camera: one ray through each pixel centre, a z-buffer of the hits.

:func:`render` casts the rays of a camera of ``resolution`` pixels
(:func:`camera_rays`) onto a triangulated surface (vertices (V, 3),
triangles (T, 3)). Every (triangle, pixel in its projected bounding box)
pair is intersected (Moeller-Trumbore, both faces) and a z-buffer keeps the
nearest hit per pixel, so what another part of the surface hides is never
seen (occlusion, not a normal test). The depth camera of the ``cloud``
observation (:mod:`idbench.observe.cloud`) renders the deformed surface with
it.
"""

from __future__ import annotations

import functools
import math

import numpy as np
from numpy.typing import NDArray

from idbench.core.interfaces import FloatArray

MAX_PAIRS = 20_000_000
"""Triangle-pixel pairs a rendering may test (a resolution too fine refuses)."""


def camera_rays(
    origin: FloatArray, look: FloatArray, resolution: tuple[int, int], fov: float
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Camera basis (right, up, forward), each (3,): forward towards ``look``."""
    f = np.asarray(look, float) - np.asarray(origin, float)
    f = f / np.linalg.norm(f)
    up = np.array([0.0, 0.0, 1.0])
    if abs(f @ up) > 0.99:
        up = np.array([0.0, 1.0, 0.0])
    r = np.cross(f, up)
    r /= np.linalg.norm(r)
    return r, np.cross(r, f), f


def winding_number(
    point: FloatArray, vertices: FloatArray, triangles: NDArray[np.int64]
) -> float:
    r"""How many times the closed surface (vertices, triangles) winds around ``point``.

    The sum of the solid angles the triangles subtend at the point over
    :math:`4\pi` (Van Oosterom and Strackee's formula, vectorised over the
    triangles): 1 inside a closed surface with outward normals, 0 outside
    (about 0.5 on it).
    """
    a, b, c = (vertices[triangles[:, i]] - point for i in range(3))
    la, lb, lc = (np.linalg.norm(x, axis=1) for x in (a, b, c))
    dot = functools.partial(np.einsum, "ij,ij->i")
    det = dot(a, np.cross(b, c))
    den = la * lb * lc + dot(a, b) * lc + dot(b, c) * la + dot(c, a) * lb
    return float(np.sum(2.0 * np.arctan2(det, den)) / (4.0 * np.pi))


def render(
    vertices: FloatArray,
    triangles: NDArray[np.int64],
    origin: FloatArray,
    look: FloatArray,
    resolution: tuple[int, int],
    fov: float,
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Ray-cast every pixel onto the triangles, keep the nearest hit per pixel.

    Returns
    -------
    tuple
        Hit points (P, 3), their depth along the ray (P,) and the unit rays
        (P, 3), of the P covered pixels in row-major pixel order.
    """
    W, H = resolution
    r, u, f = camera_rays(origin, look, resolution, fov)
    ty = math.tan(math.radians(fov) / 2)
    tx = ty * W / H
    rel = vertices - origin
    z = rel @ f
    tri = triangles[np.all(z[triangles] > 1e-12, axis=1)]  # in front of the camera
    zz = z[tri]
    col = ((rel[tri] @ r) / zz / tx + 1) * W / 2 - 0.5
    row = (1 - (rel[tri] @ u) / zz / ty) * H / 2 - 0.5
    c0 = np.clip(np.ceil(col.min(axis=1)), 0, W).astype(np.int64)
    c1 = np.clip(np.floor(col.max(axis=1)), -1, W - 1).astype(np.int64)
    r0 = np.clip(np.ceil(row.min(axis=1)), 0, H).astype(np.int64)
    r1 = np.clip(np.floor(row.max(axis=1)), -1, H - 1).astype(np.int64)
    nc = np.maximum(c1 - c0 + 1, 0)
    nr = np.maximum(r1 - r0 + 1, 0)
    counts = nc * nr
    total = int(counts.sum())
    if total > MAX_PAIRS:
        raise ValueError(
            f"observe cloud: {total:,} triangle-pixel pairs at resolution {W}x{H}; "
            f"more than {MAX_PAIRS:,}: lower the resolution"
        )
    empty = np.empty((0, 3))
    if total == 0:
        return empty, np.empty(0), empty
    t_idx = np.repeat(np.arange(len(tri)), counts)
    local = np.arange(total) - np.repeat(np.cumsum(counts) - counts, counts)
    pc = c0[t_idx] + local % nc[t_idx]
    pr = r0[t_idx] + local // nc[t_idx]
    sx = ((pc + 0.5) * 2 / W - 1) * tx
    sy = (1 - (pr + 0.5) * 2 / H) * ty
    d = f[None, :] + sx[:, None] * r[None, :] + sy[:, None] * u[None, :]
    d /= np.linalg.norm(d, axis=1)[:, None]
    v0 = vertices[tri[t_idx, 0]]
    e1 = vertices[tri[t_idx, 1]] - v0
    e2 = vertices[tri[t_idx, 2]] - v0
    pvec = np.cross(d, e2)
    det = np.einsum("ij,ij->i", e1, pvec)
    ok = np.abs(det) > 1e-300
    inv = np.where(ok, 1.0 / np.where(ok, det, 1.0), 0.0)
    tvec = origin[None, :] - v0
    a = np.einsum("ij,ij->i", tvec, pvec) * inv
    qvec = np.cross(tvec, e1)
    b = np.einsum("ij,ij->i", d, qvec) * inv
    t = np.einsum("ij,ij->i", e2, qvec) * inv
    hit = ok & (a >= 0) & (b >= 0) & (a + b <= 1) & (t > 0)
    pix = (pr * W + pc)[hit]
    t, d = t[hit], d[hit]
    order = np.lexsort((t, pix))
    pix, t, d = pix[order], t[order], d[order]
    first = np.ones(pix.size, dtype=bool)
    first[1:] = pix[1:] != pix[:-1]
    t, d = t[first], d[first]
    return origin[None, :] + t[:, None] * d, t, d
