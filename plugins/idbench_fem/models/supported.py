r"""A solid model's elastic supports: its springs, their parameters and weights.

A body's ``[[support]]`` tables (:mod:`idbench_fem.bodies.supports`) become
spring *channels* on the model's mesh, a constant sparse matrix S_c each
(:func:`~idbench_fem.fem.springs.spring_matrices`: S_n and S_t of a region,
those of nonzero stiffness), and :meth:`Supported._attach_springs` wraps the model's
assembler in a :class:`~idbench_fem.fem.springs.SpringAssembler`. A channel's
stiffness is a known value or a parameter (``k_n_<support>``, after the
moduli, with the support's bounds and prior); the model's moduli array then
ends with the channels' stiffnesses at theta (:meth:`Springs.moduli`), and
the internal force stays linear in theta,

.. math::

    f_{int}(u; \theta) = \sum_r \theta_r g_r(u) + \sum_{j} \theta_j S_{c(j)} u
                         + \sum_{c\ \mathrm{known}} k_c S_c u,

so a stiffness's sensitivity is one back-substitution, like a modulus's. The
known springs are the part that is not proportional to theta: with them the
SVK line residuals of the batched steps (which assume f = theta g) are off,
and the model says its force is not a cubic of theta-scaled state
(``force_is_cubic = False``). :class:`Supported` gives the chord scaling
(:mod:`idbench_fem.fem.chords`) the parameters' shares of the rest tangent's
trace, the springs' included (:meth:`Springs.weights`).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np
import scipy.sparse as sp
from numpy.typing import NDArray

from idbench import ParameterSpec
from idbench_fem.bodies.description import Body
from idbench_fem.bodies.mesh import SolidMesh
from idbench_fem.bodies.regions import region_facets
from idbench_fem.fem.springs import SpringAssembler, spring_matrices

FloatArray = NDArray[np.float64]


@dataclass
class Springs:
    """The spring channels of a model and what of theta each one takes.

    Attributes
    ----------
    matrices
        S_c (n, n) per channel, on the state's free dofs.
    known
        (q,): each channel's stiffness where it is known, NaN where a parameter.
    index
        (q,): the parameter of each channel (-1 where known).
    values
        (q,): each channel's stiffness in the body (the truth's).
    names, lower, upper, true, priors
        The stiffness parameters, in order (after the moduli).
    """

    matrices: list[sp.csr_matrix] = field(default_factory=list)
    known: list[float] = field(default_factory=list)
    index: list[int] = field(default_factory=list)
    values: list[float] = field(default_factory=list)
    names: list[str] = field(default_factory=list)
    lower: list[float] = field(default_factory=list)
    upper: list[float] = field(default_factory=list)
    true: list[float] = field(default_factory=list)
    priors: list[tuple[str, float, float]] = field(default_factory=list)

    def moduli(self, element_moduli: FloatArray, theta: FloatArray) -> FloatArray:
        """The moduli array with the channels' stiffnesses at ``theta`` appended."""
        idx = np.asarray(self.index, dtype=np.int64)
        k = np.where(idx >= 0, theta[np.maximum(idx, 0)], np.asarray(self.known))
        return np.concatenate([element_moduli, k])

    def extend(self, spec: ParameterSpec) -> ParameterSpec:
        """``spec`` (the moduli) with the stiffness parameters after them."""
        default = spec.default or (float("nan"),) * spec.p
        return ParameterSpec(
            (*spec.names, *self.names),
            (*spec.lower, *self.lower),
            (*spec.upper, *self.upper),
            default=(*default, *self.true),
            priors=(*spec.priors, *self.priors),
        )

    @property
    def pairs(self) -> tuple[tuple[int, int], ...]:
        """(parameter, channel) of each identified stiffness."""
        return tuple((j, c) for c, j in enumerate(self.index) if j >= 0)

    def weights(
        self, asm: Any, pattern: Any, spec: ParameterSpec, regions: Any, unit: Any
    ) -> FloatArray:
        r"""Each parameter's share of the rest tangent's trace at the true values.

        :math:`w_j \propto \theta^*_j\, \mathrm{tr}\, K_j(0)` over the
        parameters and the known springs (so the weights sum to less than 1
        where known springs hold part of the body): the first-order scale of
        a factorization to other parameters, :math:`d \ln s = \sum_j w_j\,
        d \ln \theta_j`. From the model's assembler and tangent pattern, its
        parameters, its elements' regions (T,) and moduli at theta = 1.
        """
        T = asm.n_elements
        true = np.asarray(spec.default, dtype=float)
        u0 = np.zeros(asm.n_free)
        traces = np.zeros(spec.p)
        unit = np.asarray(unit[:T])
        for r in range(int(regions.max()) + 1):
            mod = np.where(regions == r, unit, 0.0)
            mod = np.concatenate([mod, np.zeros(len(self.index))])
            kin = asm.kinematics(u0, mod)
            data = asm.tangent_data(kin, mod, pattern)
            traces[r] = true[r] * float(pattern.matrix(data).diagonal().sum())
        known = 0.0
        for c, S in enumerate(self.matrices):
            tr = float(S.diagonal().sum())
            j = self.index[c]
            if j >= 0:
                traces[j] = true[j] * tr
            else:
                known += self.known[c] * tr
        return np.asarray(traces / (traces.sum() + known))


def springs_of(body: Body, mesh: SolidMesh, full_to_free: Any, p0: int) -> Springs:
    """The spring channels of ``body``'s supports on ``mesh`` (free dofs' map).

    ``p0``: the number of parameters before the stiffnesses (the moduli).

    Raises
    ------
    ValueError
        A support region with no boundary facet in ``mesh``, a volume
        region's name, or springs that leave a body without ``[fixed]`` free
        to move rigidly (one line).
    """
    springs = Springs()
    for s in body.supports:
        what = f"{body.source}: [[support]] {s.name!r} region"
        if s.region.name is not None and mesh.volume_only(s.region.name):
            raise ValueError(
                f"{what} {s.region.name!r} is a volume of {mesh.path!r}, not a "
                "surface: name a surface group or use a selector"
            )
        facets = region_facets(mesh, s.region, what=what)
        pair = spring_matrices(mesh.points, mesh.facets[facets], full_to_free)
        for which, S in zip(("k_n", "k_t"), pair, strict=True):
            if s.value(which) == 0.0:
                continue
            springs.matrices.append(S)
            springs.values.append(s.value(which))
            if which not in s.identify:
                springs.known.append(s.value(which))
                springs.index.append(-1)
                continue
            springs.known.append(float("nan"))
            springs.index.append(p0 + len(springs.names))
            springs.names.append(s.parameter(which))
            lo, hi = s.bound(which)
            springs.lower.append(lo)
            springs.upper.append(hi)
            springs.true.append(s.value(which))
            mean, std = next((m, d) for k, m, d in s.prior if k == which)
            springs.priors.append((s.parameter(which), mean, std))
    if body.fixed is None:
        _check_held(springs, mesh, full_to_free, body.source)
    return springs


HELD = 1e-8
"""A body without ``[fixed]`` is held if its springs' stiffness against each
rigid motion is at least this share of the stiffest one's."""


def _check_held(
    springs: Springs, mesh: SolidMesh, full_to_free: Any, source: str
) -> None:
    """Refuse springs that leave a rigid motion free (a body without a clamp).

    The springs' stiffness R^T S R (6 x 6) against the rigid motions R
    (translations and rotations about the centroid, scaled by the body's
    size), S = sum_c k_c S_c at the true values: its smallest eigenvalue must
    be at least :data:`HELD` times its largest.

    Raises
    ------
    ValueError
        Naming the free motion (one line).
    """
    x = mesh.points - mesh.points.mean(axis=0)
    size = float(np.max(np.ptp(mesh.points, axis=0)))
    modes = np.zeros((len(x), 3, 6))
    for i in range(3):
        modes[:, i, i] = 1.0
        modes[:, :, 3 + i] = np.cross(np.eye(3)[i], x) / size
    free = np.asarray(full_to_free) >= 0
    R = modes.reshape(-1, 6)[free][np.argsort(np.asarray(full_to_free)[free])]
    A = sum(
        kc * (R.T @ (S @ R))
        for kc, S in zip(springs.values, springs.matrices, strict=True)
    )
    w, v = np.linalg.eigh(np.asarray(A))
    if w[0] < HELD * max(w[-1], 0.0) or w[-1] <= 0:
        names = ("x", "y", "z", "rotation about x", "rotation about y",
                 "rotation about z")  # fmt: skip
        worst = names[int(np.argmax(np.abs(v[:, 0])))]
        raise ValueError(
            f"{source}: no [fixed] region and the [[support]] springs of "
            f"{mesh.path!r} do not hold the body against a rigid motion (mostly "
            f"{'translation along ' if len(worst) == 1 else ''}{worst}): give a "
            "support k_t > 0, another support or a [fixed] region"
        )


class Supported:
    """Mixin: a solid model's springs and their chord weights (see the module)."""

    _springs: Springs | None = None
    _asm: Any
    parameters: ParameterSpec
    force_is_cubic: bool

    def _attach_springs(self, body: Body, mesh: SolidMesh) -> None:
        """Give the model its body's supports (none: ``_springs`` stays None).

        Wraps the assembler of the state's dofs in a
        :class:`~idbench_fem.fem.springs.SpringAssembler`, extends
        ``parameters`` by the identified stiffnesses and sets
        ``force_is_cubic = False`` (see the module). Called after the
        moduli's parameters are set and before the model freezes its arrays.

        Raises
        ------
        ValueError
            See :func:`springs_of`.
        """
        if not body.supports:
            return
        inner = self._state_asm()  # type: ignore[attr-defined]
        springs = springs_of(body, mesh, inner.full_to_free, self.parameters.p)
        wrapped = SpringAssembler(inner, springs.matrices, springs.pairs)
        if inner is self._asm:
            self._asm = wrapped
        else:  # a displacement-controlled grasp's assembler wraps the state's
            self._asm.inner = wrapped
        self.parameters = springs.extend(self.parameters)
        self.force_is_cubic = False
        self._springs = springs

    @property
    def springs(self) -> Springs | None:
        """The model's spring channels (None: no ``[[support]]``)."""
        return self._springs

    def region_weights(self) -> FloatArray:
        """The parameters' stiffness shares (:meth:`Springs.weights` with springs)."""
        if self._springs is None:
            return np.asarray(super().region_weights())  # type: ignore[misc]
        cached = self.__dict__.get("_spring_weights")
        if cached is None:
            cached = self._springs.weights(
                self._asm, self._pattern, self.parameters,  # type: ignore[attr-defined]
                self.element_regions, self.unit_moduli,  # type: ignore[attr-defined]
            )  # fmt: skip
            self.__dict__["_spring_weights"] = cached
        return np.asarray(cached)
