r"""A virtual depth camera: the ``cloud`` observation model.

Sensing (the truth, once per step): a pinhole camera of ``resolution``
pixels, posed by :meth:`Cloud.pose`, renders the deformed surface
(``model.surface(state)``; :func:`idbench.observe.camera.render`: one ray
through each pixel centre, a z-buffer keeps the nearest hit, so what another
part of the surface hides is never seen). The clean reading of a covered
pixel is its hit depth t along its unit ray (the hit point is origin + t
ray).

Measuring (per run, through its seeded generator; common random numbers):
``holes`` drops that fraction of the covered pixels, ``points`` of the rest
are drawn (with replacement if fewer), each point moves along its ray by
N(0, sigma^2), and ``outliers`` of them (an exact count) are replaced by a
point on the same ray at a uniform fraction in [0.3, 0.95] of its depth (an
instrument in front of the organ). A frame therefore has exactly ``points``
points, without correspondence to the mesh.

Residual (the model side, any state): each point's signed distance to the
model's deformed surface, point-to-plane at the triangle of nearest
centroid, or the exact closest point among ``candidates`` triangles
(:mod:`idbench.observe.surface`, which also has the maths and the cached
association of points to triangles). Outliers are gated: :math:`r_i` is
clipped to :math:`\pm g`, :math:`g = \max(\mathrm{gate}\,\sigma,
\mathrm{gate\_min})`; a clipped point has the same residual for every sigma
point or ensemble member, so it does not move a filter's estimate. The
observation is y = 0 (m = ``points`` values) with noise std sigma.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from idbench.core.capabilities import member
from idbench.core.interfaces import FloatArray, ForwardModel
from idbench.observe.camera import render, winding_number
from idbench.observe.surface import (
    CANDIDATES,
    point_to_surface,
    point_to_surface_jacobian,
    surface_of,
)


@dataclass(frozen=True)
class Cloud:
    """A depth camera on the deformed surface; settings are realism knobs.

    Attributes
    ----------
    points
        Points per frame N (the observation size), >= 1.
    resolution
        Camera pixels (width, height).
    fov
        Vertical field of view, degrees in (0, 180).
    position, look_at
        Camera pose in model coordinates; None: ``look_at`` the centre of the
        unloaded body's bounding box, ``position`` at ``distance`` diagonals
        from it along ``direction``.
    direction
        From the target towards the camera, when ``position`` is None.
    distance
        Camera distance in bounding-box diagonals, when ``position`` is None.
    noise
        Noise std along the ray (model length unit); None: the run's
        ``--noise``.
    holes
        Fraction of the covered pixels dropped, in [0, 1).
    outliers
        Fraction of each frame's points made outliers, in [0, 1).
    gate, gate_min
        Residuals are clipped to +- max(gate sigma, gate_min).
    candidates
        Triangles searched per point (:func:`point_to_surface`): 1 (default)
        point-to-plane at the nearest-centroid triangle; more, the exact
        closest point among that many (slower, kinked at edges).
    """

    points: int = 500
    resolution: tuple[int, int] = (160, 120)
    fov: float = 45.0
    position: tuple[float, float, float] | None = None
    look_at: tuple[float, float, float] | None = None
    direction: tuple[float, float, float] = (0.0, -1.0, 1.0)
    distance: float = 2.0
    noise: float | None = None
    holes: float = 0.0
    outliers: float = 0.0
    gate: float = 5.0
    gate_min: float = 1e-3
    candidates: int = CANDIDATES
    requires: tuple[str, ...] = dataclasses.field(
        default=("surface",), init=False, repr=False
    )

    def __post_init__(self) -> None:
        for name in ("resolution", "position", "look_at", "direction"):
            value = getattr(self, name)
            if isinstance(value, list):
                object.__setattr__(self, name, tuple(value))
        if isinstance(self.points, bool) or not isinstance(self.points, int):
            raise ValueError(f"points = {self.points!r}: need a whole number >= 1")
        if self.points < 1:
            raise ValueError(f"points = {self.points!r}: need a whole number >= 1")
        res = self.resolution
        if not (
            isinstance(res, tuple) and len(res) == 2
            and all(isinstance(v, int) and not isinstance(v, bool) and v >= 2
                    for v in res)
        ):  # fmt: skip
            raise ValueError(f"resolution = {res!r}: need [WIDTH, HEIGHT], each >= 2")
        if not (_num(self.fov) and 0 < self.fov < 180):
            raise ValueError(f"fov = {self.fov!r}: need degrees in (0, 180)")
        for name in ("position", "look_at", "direction"):
            value = getattr(self, name)
            if value is None and name != "direction":
                continue
            if not (isinstance(value, tuple) and len(value) == 3
                    and all(_num(v) for v in value)):  # fmt: skip
                raise ValueError(f"{name} = {value!r}: need [x, y, z], numbers")
        if not np.any(self.direction):
            raise ValueError("direction = [0, 0, 0]: need a nonzero vector")
        c = self.candidates
        if isinstance(c, bool) or not isinstance(c, int) or c < 1:
            raise ValueError(f"candidates = {c!r}: need a whole number >= 1")
        if not (_num(self.distance) and self.distance > 0):
            raise ValueError(f"distance = {self.distance!r}: need a number > 0")
        if self.noise is not None and not (_num(self.noise) and self.noise >= 0):
            raise ValueError(f"noise = {self.noise!r}: need a number >= 0 (or unset)")
        for name in ("holes", "outliers"):
            value = getattr(self, name)
            if not (_num(value) and 0 <= value < 1):
                raise ValueError(f"{name} = {value!r}: need a fraction in [0, 1)")
        for name in ("gate", "gate_min"):
            value = getattr(self, name)
            if not (_num(value) and value > 0):
                raise ValueError(f"{name} = {value!r}: need a number > 0")

    # -- the ObservationModel protocol ----------------------------------------

    def sense(
        self, model: ForwardModel, theta: FloatArray, k: int, state: FloatArray
    ) -> dict[str, FloatArray]:
        """Render the deformed surface: ``depth`` (P,), ``rays`` (P, 3), ``origin``.

        The P covered pixels' hit depth along their unit ray from the camera
        at ``origin`` (3,); the hit points are ``origin + depth * rays``.
        """
        vertices, triangles = surface_of(model, state)
        rest, _ = surface_of(model, model.reset())
        origin, look = self.pose(rest)
        _, depth, rays = render(
            vertices, triangles, origin, look, self.resolution, self.fov
        )
        if depth.size == 0:
            raise ValueError(
                f"the camera at {np.round(origin, 6).tolist()} looking at "
                f"{np.round(look, 6).tolist()} sees no part of the body at step {k} "
                "(check position, look_at, direction, fov)"
            )
        return {"depth": depth, "rays": rays, "origin": origin}

    def measure(
        self, clean: Sequence[Mapping[str, FloatArray]], rng: np.random.Generator,
        noise: float,
    ) -> list[dict[str, FloatArray]]:  # fmt: skip
        """Holes, N points per frame, noise along the ray, outliers (see module)."""
        sigma = float(noise if self.noise is None else self.noise)
        out = []
        for c in clean:
            depth, rays, origin = c["depth"], c["rays"], c["origin"]
            if depth.size == 0:
                raise ValueError(
                    "observe cloud: the camera sees no part of the body (check "
                    "position, look_at, fov)"
                )
            keep = rng.permutation(depth.size)[
                : depth.size - round(self.holes * depth.size)
            ]
            if keep.size == 0:
                keep = np.arange(depth.size)
            pick = rng.choice(keep, size=self.points, replace=keep.size < self.points)
            t = depth[pick] + sigma * rng.standard_normal(self.points)
            n_out = round(self.outliers * self.points)
            bad = rng.permutation(self.points)[:n_out]
            t[bad] = depth[pick[bad]] * rng.uniform(0.3, 0.95, n_out)
            points = origin[None, :] + t[:, None] * rays[pick]
            out.append({"points": points, "origin": origin, "sigma": np.array(sigma)})
        return out

    def values(self, frame: Any) -> FloatArray:
        """Y = 0 for every point, shape (N,)."""
        return np.zeros(len(frame.data["points"]))

    def noise_std(self, frame: Any, noise: float) -> float:
        """The sigma along the ray the frame was measured with."""
        return float(
            frame.data.get("sigma", noise if self.noise is None else self.noise)
        )

    def predict(
        self, model: ForwardModel, frame: Any, theta: FloatArray, k: int,
        state: FloatArray,
    ) -> FloatArray:  # fmt: skip
        """Gated signed distance of each point to ``model``'s deformed surface."""
        vertices, triangles = surface_of(model, state)
        sigma = self.noise_std(frame, 0.0)
        g = max(self.gate * sigma, self.gate_min)
        return point_to_surface(
            frame.data["points"], vertices, triangles, gate=g,
            candidates=self.candidates,
        )  # fmt: skip

    def linearize(
        self, model: ForwardModel, frame: Any, theta: FloatArray, k: int,
        state: FloatArray,
    ) -> tuple[Any, FloatArray]:  # fmt: skip
        """(dh/du (N, n), dh/dtheta = 0): the gated distances' derivative.

        Point-to-plane (``candidates = 1``) through the model's
        ``surface_jacobian`` (:func:`point_to_surface_jacobian`).

        Raises
        ------
        ValueError
            With ``candidates`` > 1, or a model without ``surface_jacobian``.
        """
        jac = member(model, "surface_jacobian")
        if self.candidates != 1 or jac is None:
            raise ValueError(
                "observe cloud: a linearization needs candidates = 1 and a model "
                "with surface_jacobian"
            )
        vertices, triangles = surface_of(model, state)
        g = max(self.gate * self.noise_std(frame, 0.0), self.gate_min)
        dv = point_to_surface_jacobian(frame.data["points"], vertices, triangles, g)
        p = np.size(theta)
        return dv @ jac(state), np.zeros((dv.shape[0], p))

    def positions(self, model: ForwardModel, frame: Any, k: int) -> FloatArray:
        """Where each point is: the frame's points (N, 3), as measured."""
        return np.asarray(frame.data["points"], dtype=float)

    def identity(self) -> list[Any]:
        """Every setting but the noise sigma (it scales common draws)."""
        fields = dataclasses.asdict(self)
        fields.pop("noise")
        fields.pop("requires")
        return ["cloud", sorted((k, _plain(v)) for k, v in fields.items())]

    def check(self, model: ForwardModel) -> None:
        """Refuse a camera that cannot see the unloaded body of ``model`` well enough.

        Raises
        ------
        ValueError
            The camera inside the body; seeing no part of it (looking away);
            or fewer distinct surface pixels (after ``holes``) than ``points``.
        """
        vertices, triangles = surface_of(model, model.reset())
        origin, look = self.pose(vertices)
        at = np.round(origin, 6).tolist()
        if abs(winding_number(origin, vertices, triangles)) > 0.5:
            raise ValueError(
                f"the camera at {at} is inside the body; place it outside "
                "(position, or direction and distance)"
            )
        _, depth, _ = render(
            vertices, triangles, origin, look, self.resolution, self.fov
        )
        if depth.size == 0:
            raise ValueError(
                f"the camera at {at} looking at {np.round(look, 6).tolist()} sees "
                "no part of the body (it looks away from it); check position, "
                "look_at, direction, fov"
            )
        seen = depth.size - round(self.holes * depth.size)
        if seen < self.points:
            raise ValueError(
                f"points = {self.points}: the camera sees {seen} distinct surface "
                f"pixels of the unloaded body at resolution {list(self.resolution)}"
                + (f" (holes = {self.holes:g})" if self.holes else "")
                + f"; ask for at most {seen} points, or raise the resolution"
            )

    # -- the camera -------------------------------------------------------------

    def pose(self, rest: FloatArray) -> tuple[FloatArray, FloatArray]:
        """Camera position and look-at point (3,), from the settings or ``rest``."""
        lo, hi = rest.min(axis=0), rest.max(axis=0)
        look = (lo + hi) / 2 if self.look_at is None else np.array(self.look_at, float)
        if self.position is not None:
            return np.array(self.position, dtype=float), look
        d = np.array(self.direction, dtype=float)
        diag = float(np.linalg.norm(hi - lo)) or 1.0
        return look + self.distance * diag * d / np.linalg.norm(d), look


def clean_points(
    cloud: Cloud, clean: Mapping[str, FloatArray], rng: np.random.Generator
) -> FloatArray:
    """``cloud.points`` noise-free points (N, 3) of a clean reading, no outliers.

    Pixels drawn without replacement where there are enough (``rng``); the
    held-out cloud of a recording (:mod:`idbench.run.record`).
    """
    depth, rays, origin = clean["depth"], clean["rays"], clean["origin"]
    n = min(cloud.points, depth.size)
    pick = rng.choice(depth.size, size=n, replace=False)
    return np.asarray(origin)[None, :] + depth[pick][:, None] * rays[pick]


def _num(x: Any) -> bool:
    ok = isinstance(x, int | float) and not isinstance(x, bool)
    return ok and math.isfinite(x)


def _plain(v: Any) -> Any:
    return list(v) if isinstance(v, tuple) else v
