"""What the FE models show an observation model: their surface and reaction force.

:class:`Observables` is a mixin of the FE models (the beam and the solid)
giving them the optional members of idbench's observation models:
``surface(state)`` (:class:`idbench.SurfaceModel`, for ``cloud``) and
``reaction(theta, k, state)`` (:class:`idbench.ReactionModel`, for
``force``). It needs the model's ``mesh()``, ``displacement_field(state)``,
``_asm`` (an assembler with ``kinematics``, ``element_forces`` and
``full_to_free``) and ``_modulus(theta, k)``.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import NDArray

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]

_FACES = np.array([[1, 2, 3], [0, 3, 2], [0, 1, 3], [0, 2, 1]])
"""The faces of a tet (a, b, c, d), each with the vertex opposite it: 0..3."""


def boundary_triangles(points: FloatArray, tets: IntArray) -> IntArray:
    """The boundary faces (F, 3) of a tet mesh, each ordered with its normal outward.

    A face is on the boundary when exactly one tet has it; its order is
    flipped where the right-hand normal points towards the tet's fourth
    vertex.
    """
    faces = tets[:, _FACES].reshape(-1, 3)
    opposite = tets.reshape(-1)  # face i of a tet is opposite its vertex i
    key = np.sort(faces, axis=1)
    _, inverse, counts = np.unique(key, axis=0, return_inverse=True, return_counts=True)
    once = counts[inverse.ravel()] == 1
    tri, opp = faces[once], opposite[once]
    p0, p1, p2 = points[tri[:, 0]], points[tri[:, 1]], points[tri[:, 2]]
    normal = np.cross(p1 - p0, p2 - p0)
    inward = np.einsum("ij,ij->i", normal, points[opp] - p0) > 0
    tri[inward] = tri[inward][:, [0, 2, 1]]
    return np.ascontiguousarray(tri, dtype=np.int64)


class Observables:
    """Mixin: ``surface`` and ``reaction`` of an FE model (see the module)."""

    _asm: Any
    n_nodes: int

    def surface(self, state: FloatArray) -> tuple[FloatArray, IntArray]:
        """Deformed boundary at ``state``: vertices (N, 3) (all nodes), triangles.

        The vertices are every node's deformed position (the triangles index
        the boundary ones); triangles (F, 3), normals outward.
        """
        points, tets = self.mesh()  # type: ignore[attr-defined]
        cached = self.__dict__.get("_boundary")
        if cached is None:
            cached = boundary_triangles(points, tets)
            self.__dict__["_boundary"] = cached
        moved = points + self.displacement_field(state)  # type: ignore[attr-defined]
        return moved, cached

    def reaction(self, theta: FloatArray, k: int, state: FloatArray) -> FloatArray:
        """Reaction force (3,): the internal forces at the constrained nodes, summed.

        The force the support exerts on the body, f_int(state; theta) summed
        over the nodes with prescribed displacement (model force unit, N).
        """
        asm = self._asm
        modulus = self._modulus(np.asarray(theta, float), None)  # type: ignore[attr-defined]
        kin = asm.kinematics(np.asarray(state, dtype=float), modulus)
        fe = np.asarray(asm.element_forces(kin)).reshape(-1, 4, 3)
        _, tets = self.mesh()  # type: ignore[attr-defined]
        fixed = np.asarray(asm.full_to_free).reshape(-1, 3)[:, 0] < 0
        on_fixed = fixed[tets]  # (T, 4)
        return np.asarray((fe * on_fixed[:, :, None]).sum(axis=(0, 1)), dtype=float)
