"""Rigid registration of a cloud to a surface: a known transform is recovered."""

from __future__ import annotations

import importlib.util
import math

import numpy as np
import pytest
from scipy.spatial import ConvexHull
from scipy.spatial.transform import Rotation

from idbench.observe.registration import (
    RegistrationError,
    register,
    transform_error,
)


def lobe(n=2000, seed=0):
    """A lobe-like closed surface (convex hull of a bumped ellipsoid), m."""
    rng = np.random.default_rng(seed)
    d = rng.standard_normal((n, 3))
    d /= np.linalg.norm(d, axis=1)[:, None]
    r = 1.0 + 0.25 * np.exp(-8 * ((d[:, 0] - 0.7) ** 2 + (d[:, 2] - 0.3) ** 2))
    x = d * r[:, None] * np.array([0.08, 0.05, 0.04])
    hull = ConvexHull(x)
    tri = hull.simplices.copy()
    centre = x.mean(axis=0)
    a, b, c = (x[tri[:, i]] for i in range(3))
    flip = np.einsum("ij,ij->i", np.cross(b - a, c - a), a - centre) < 0
    tri[flip] = tri[flip][:, ::-1]
    return x, tri


def view(x, tri, n=1000, noise=5e-4, outliers=0.05, seed=1):
    """A cloud of the surface seen from +y (the visible half), with outliers."""
    rng = np.random.default_rng(seed)
    a, b, c = (x[tri[:, i]] for i in range(3))
    normal = np.cross(b - a, c - a)
    area = 0.5 * np.linalg.norm(normal, axis=1)
    seen = normal[:, 1] > 0
    pick = rng.choice(np.flatnonzero(seen), n, p=area[seen] / area[seen].sum())
    u, v = rng.uniform(size=(2, n))
    fold = u + v > 1
    u[fold], v[fold] = 1 - u[fold], 1 - v[fold]
    pts = a[pick] + u[:, None] * (b - a)[pick] + v[:, None] * (c - a)[pick]
    unit = normal[pick] / np.linalg.norm(normal[pick], axis=1)[:, None]
    pts += noise * rng.standard_normal(n)[:, None] * unit
    bad = rng.permutation(n)[: round(outliers * n)]
    pts[bad] += rng.uniform(0.005, 0.03, len(bad))[:, None] * np.array([0, 1, 0])
    return pts


OFFSET = 0.010  # m
ANGLE = 10.0  # degrees


def camera_frame(pts, seed=2):
    """The cloud in a camera frame: the model's frame moved by 10 mm, 10 deg."""
    rng = np.random.default_rng(seed)
    axis = rng.standard_normal(3)
    R = Rotation.from_rotvec(math.radians(ANGLE) * axis / np.linalg.norm(axis))
    t = OFFSET * np.array([0.6, -0.64, 0.48])  # |t| = 10 mm
    R = R.as_matrix()
    # points_model = R p + t  <=>  p = R^T (points_model - t)
    return (pts - t) @ R, R, t


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_a_known_transform_is_recovered(seed):
    x, tri = lobe(seed=seed)
    model_pts = view(x, tri, seed=seed + 10)
    cam, R, t = camera_frame(model_pts, seed=seed + 20)
    fit = register(cam, x, tri, floor=5e-4)
    angle, worst = transform_error(fit, R, t, cam)
    assert angle < 0.5  # degrees
    assert worst < 5e-4  # m, over the cloud
    assert fit.inliers > 0.9
    assert fit.rms < 1e-3
    assert abs(fit.angle_deg - ANGLE) < 0.5
    np.testing.assert_allclose(fit.apply(cam[:3]), (cam[:3] @ R.T) + t, atol=5e-4)


def test_a_cloud_of_another_body_gives_one_line():
    x, tri = lobe()
    other = np.random.default_rng(3).uniform(-0.2, 0.2, (300, 3)) + 0.5
    with pytest.raises(RegistrationError) as err:
        register(other, x, tri, max_iterations=20)
    assert "\n" not in str(err.value)
    assert "points" in str(err.value)


@pytest.mark.skipif(
    importlib.util.find_spec("open3d") is None, reason="Open3D not installed"
)
def test_the_open3d_backend_agrees():
    x, tri = lobe()
    cam, R, t = camera_frame(view(x, tri))
    fit = register(cam, x, tri, floor=5e-4, backend="open3d")
    angle, worst = transform_error(fit, R, t, cam)
    assert fit.backend == "open3d"
    assert angle < 1.0 and worst < 1e-3
