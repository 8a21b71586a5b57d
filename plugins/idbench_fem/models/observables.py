"""What the FE models show an observation model: their surface and reaction force.

:class:`LinearReadouts` gives the solid model and its reductions the
readouts that are linear in the state: ``observe`` (the markers), ``grid``
(the shape-error points) and ``targets``, from the matrices ``_obs``,
``_grid`` and ``_targets`` of the model's state.

:class:`Observables` is a mixin of the FE models (the beam and the solid)
giving them the optional members of idbench's observation models:
``surface(state)`` (:class:`idbench.SurfaceModel`, for ``cloud``) and
``reaction(theta, k, state)`` (:class:`idbench.ReactionModel`, for
``force``). It needs the model's ``mesh()``, ``displacement_field(state)``,
``_asm`` (an assembler with ``kinematics``, ``element_forces`` and
``full_to_free``) and ``element_moduli(theta, k)``.
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


class LinearReadouts:
    """Mixin: the markers, shape-error points and targets, linear in the state."""

    _obs: Any
    _grid: Any
    _targets: Any

    def observe(self, state: FloatArray) -> FloatArray:
        """Marker displacements, shape (3M,), ``[p0x, p0y, p0z, p1x, ...]``."""
        return np.asarray(self._obs @ state)

    def grid(self, state: FloatArray) -> FloatArray:
        """Displacements of the shape-error points, shape (G, 3)."""
        return np.asarray(self._grid @ state).reshape(-1, 3)

    def targets(self, state: FloatArray) -> FloatArray:
        """Displacements (T, 3) of the body's ``[targets]`` (T = 0 without)."""
        return np.asarray(self._targets @ state).reshape(-1, 3)


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

        Force-controlled manipulations: the force the support exerts on the
        body, f_int(state; theta) summed over the fixed nodes (it balances
        the applied load, so it says nothing of E). A displacement-controlled
        grasp: the force the tool exerts on the body, f_int summed over the
        nodes whose displacement it prescribes (the fixed ones left out).
        Model force unit, N.
        """
        asm = self._state_asm()
        modulus = self.element_moduli(np.asarray(theta, float), None)  # type: ignore[attr-defined]
        kin = asm.kinematics(np.asarray(state, dtype=float), modulus)
        fe = np.asarray(asm.element_forces(kin)).reshape(-1, 4, 3)
        _, tets = self.mesh()  # type: ignore[attr-defined]
        on_nodes = self._reaction_nodes()[tets]  # (T, 4)
        return np.asarray((fe * on_nodes[:, :, None]).sum(axis=(0, 1)), dtype=float)

    def _state_asm(self) -> Any:
        """The assembler of the state's dofs."""
        return self._asm

    def _reaction_nodes(self) -> NDArray[np.bool_]:
        """The nodes whose internal forces :meth:`reaction` sums: the fixed ones."""
        return np.asarray(self._state_asm().full_to_free).reshape(-1, 3)[:, 0] < 0
