"""A recording seen in the camera's frame, moved into the body's before any run.

A camera sees the organ in its own coordinates, not the mesh's. A recording
whose manifest says ``frame = "camera"`` holds, besides its frames, the cloud
of the organ at rest (``rest/points``, (N, 3), m, in the camera's frame).
Before any filter starts, that cloud is registered to the model's rest
surface (:func:`idbench.observe.registration.register`: robust point-to-plane
ICP from several starts), and every frame is moved by the transform found,
x = R p + t: the clouds' points and camera centres as positions, held-out
points likewise, held-out marker and target displacements rotated. Each
model mesh is registered on its own surface (a coarse mesh's surface lies
elsewhere than a fine one's), and the transform and its residual are stored
in each run's row (:func:`columns`).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from typing import Any

import numpy as np

from idbench.core.interfaces import FloatArray
from idbench.observe.kinds import Frame
from idbench.observe.registration import Registration, register
from idbench.store.recording import Recording

__all__ = ["COLUMNS", "columns", "to_body"]

COLUMNS = (
    "registration_rms_mm",
    "registration_inliers",
    "registration_angle_deg",
    "registration_shift_mm",
)
"""The row's columns of a registered recording (see :func:`columns`)."""

POSITIONS = ("points", "origin")
"""Frame data that are positions (moved); ``markers`` are displacements (turned)."""


def to_body(
    rec: Recording, vertices: FloatArray, triangles: Any
) -> tuple[Recording, Registration]:
    """``rec`` in the body's frame, registered to the surface (vertices, triangles).

    A recording already in the body's frame is returned as it is, with the
    identity.

    Raises
    ------
    idbench.observe.registration.RegistrationError
        The rest cloud does not register (no convergence, or too few inliers).
    """
    if rec.frame != "camera" or rec.rest is None:
        return rec, Registration(np.eye(3), np.zeros(3), 0.0, 1.0, 0.0, 0, 0)
    floor = noise_floor(rec)
    fit = register(rec.rest, vertices, triangles, floor=floor)
    return move(rec, fit), fit


def noise_floor(rec: Recording) -> float:
    """The clouds' noise std (model units): the registration's smallest scale."""
    sigmas = [
        float(v) for f in rec.frames for n, v in f.data.items() if n.endswith("sigma")
    ]
    return min(sigmas, default=rec.noise) or 1e-4


def move(rec: Recording, fit: Registration) -> Recording:
    """``rec`` (in the camera's frame) moved by ``fit`` into the body's frame."""
    frames = [Frame(f.step, _moved(f.data, fit)) for f in rec.frames]
    held = {
        name: (_positions if name == "points" else _turned)(value, fit)
        for name, value in rec.held_out.items()
    }
    rest = None if rec.rest is None else fit.apply(rec.rest)
    return dataclasses.replace(
        rec, frames=frames, held_out=held, frame="body", rest=rest
    )


def columns(fit: Registration | None) -> dict[str, float]:
    """A run's registration: rms residual (mm), inliers, rotation (deg), shift (mm).

    NaN for a run whose data needed none.
    """
    if fit is None:
        return dict.fromkeys(COLUMNS, float("nan"))
    return {
        "registration_rms_mm": 1e3 * float(fit.rms),
        "registration_inliers": float(fit.inliers),
        "registration_angle_deg": fit.angle_deg,
        "registration_shift_mm": 1e3 * float(np.linalg.norm(fit.translation)),
    }


def _moved(data: Mapping[str, Any], fit: Registration) -> dict[str, Any]:
    """One frame's data in the body's frame."""
    out = {}
    for name, value in data.items():
        leaf = name.rpartition("/")[2]
        if leaf in POSITIONS:
            out[name] = _positions(value, fit)
        elif leaf == "markers":
            out[name] = _turned(value, fit)
        else:
            out[name] = value
    return out


def _positions(value: Any, fit: Registration) -> FloatArray:
    """Positions (..., 3) moved by x = R p + t (NaN rows stay NaN)."""
    a = np.asarray(value, dtype=float)
    return np.asarray(fit.apply(a.reshape(-1, 3)).reshape(a.shape))


def _turned(value: Any, fit: Registration) -> FloatArray:
    """Displacements (..., 3k) turned by R (NaN stays NaN)."""
    a = np.asarray(value, dtype=float)
    return np.asarray((a.reshape(-1, 3) @ fit.rotation.T).reshape(a.shape))
