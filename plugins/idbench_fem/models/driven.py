"""A displacement-controlled grasp: the solid model's prescribed-patch steps.

A grasp with ``displacement`` instead of ``force`` moves its patch's nodes by
t times it (:func:`~idbench_fem.bodies.resolve.driven_nodes`): their dofs
leave the unknowns (:class:`~idbench_fem.fem.prescribed.PrescribedAssembler`),
the step solves for the rest, and the tool's force is the reaction on the
patch. :class:`DrivenGrasp` is the part of
:class:`~idbench_fem.models.solid.SolidModel` that does it.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import NDArray

from idbench_fem.bodies import resolve
from idbench_fem.bodies.description import Body
from idbench_fem.bodies.mesh import SolidMesh
from idbench_fem.fem.prescribed import PrescribedAssembler

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]


class DrivenGrasp:
    """The solid model's steps when a grasp prescribes its patch's displacement.

    A mixin of :class:`~idbench_fem.models.solid.SolidModel`, whose attributes
    it uses: without a driven grasp (``_driven`` None) each method is the
    model's plain behaviour.
    """

    _asm: Any
    _driven: IntArray | None
    _u_end: FloatArray

    def _init_driven(self, body: Body, mesh: SolidMesh, scale: float) -> None:
        """A displacement-controlled grasp: its nodes' dofs leave the unknowns."""
        m = self.manipulation
        nodes = resolve.driven_nodes(body, m.name, mesh)
        dofs = self._asm.full_to_free[(3 * nodes[:, None] + np.arange(3)).ravel()]
        self._asm = PrescribedAssembler(self._asm, dofs)
        self._driven = nodes
        assert m.displacement is not None
        self._u_end = scale * np.tile(np.asarray(m.displacement, float), len(nodes))
        self.needs_observed = ("reaction",)

    def _driven_step(
        self, theta: FloatArray, k: int, u: FloatArray, modulus: FloatArray,
        substeps: int,
    ) -> FloatArray:  # fmt: skip
        """:meth:`step` of a displacement-controlled grasp, on the unknowns."""
        asm = self._asm
        x = u[asm.unknown]
        if substeps == 1 and self.settings.path_reuse is not False:
            self.prescribe(k)
            x = self._path_step(theta, k, x, modulus)
        else:
            self._last_path_step = None
            for j in range(1, substeps + 1):
                self.prescribe(k, j / substeps)
                x, _ = self._newton(modulus, self._load(k, j / substeps), x, k)
        self._remember_factorization(theta, x)
        return np.asarray(asm.embed(x))

    @property
    def driven_nodes(self) -> IntArray:
        """The nodes a displacement-controlled grasp moves (empty if none)."""
        if self._driven is None:
            return np.zeros(0, dtype=np.int64)
        return self._driven

    def prescribed_displacement(self, k: int) -> FloatArray:
        """The driven nodes' displacements (D, 3) at load step ``k`` (D = 0 if none)."""
        if self._driven is None:
            return np.zeros((0, 3))
        return np.asarray((k / self.n_steps) * self._u_end).reshape(-1, 3)

    def _state_asm(self) -> Any:
        """The assembler of the state's dofs (a driven grasp's included)."""
        return self._asm if self._driven is None else self._asm.inner

    def _reaction_nodes(self) -> NDArray[np.bool_]:
        """The nodes whose internal forces :meth:`reaction` sums (N,)."""
        if self._driven is None:
            return super()._reaction_nodes()
        mask = np.zeros(self.n_nodes, dtype=bool)
        mask[self._driven] = True
        return mask

    def prescribe(self, k: int, fraction: float = 1.0) -> None:
        """Set the prescribed dofs to their values ``fraction`` into step k."""
        if self._driven is not None:
            t = (k - 1 + fraction) / self.n_steps
            self._asm.values = t * self._u_end

    def _path_reference(
        self, k: int, u: FloatArray, modulus: FloatArray, f_ext: FloatArray
    ) -> float:
        """|r| at the given state: the load increment, or (driven) evaluated."""
        if self._driven is None:
            return super()._path_reference(k, u, modulus, f_ext)
        kin = self._asm.kinematics(u, modulus)
        if not np.all(kin.det > 0):
            return float("inf")
        return float(np.linalg.norm(self._asm.forces(kin) - f_ext))

    def _driven_force_scale(self) -> float:
        """The load the first step of a driven grasp puts on the unknowns (N).

        The internal force on the unknowns with the grasp's end displacement
        over K on its patch and the rest at rest, at the true moduli (f_ext
        is 0, so Newton's floor is a fraction of this).
        """
        asm = self._asm
        true = np.asarray(self.parameters.default, dtype=float)
        u = asm.embed(np.zeros(asm.n_free), self._u_end / self.n_steps)
        kin = asm.inner.kinematics(u, self.element_moduli(true, None))
        return float(np.linalg.norm(asm.inner.forces(kin)[asm.unknown]))
