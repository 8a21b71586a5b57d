r"""Hyperelastic laws, vectorised over quadrature points.

Every law is a small frozen dataclass parameterised by Young's modulus E and
Poisson's ratio nu, with the Lamé parameters

.. math::

    \lambda = \frac{E \nu}{(1 + \nu)(1 - 2\nu)},\qquad \mu = \frac{E}{2(1 + \nu)}.

Given deformation gradients F, shape (n, 3, 3), each law returns

- :meth:`energy`: the strain-energy density W per unit reference volume, (n,);
- :meth:`stress`: the second Piola-Kirchhoff stress
  :math:`S = \partial W / \partial \mathbf{E}`, (n, 3, 3);
- :meth:`tangent`: the material tangent
  :math:`\mathbb{C} = \partial S / \partial \mathbf{E}`, (n, 3, 3, 3, 3), with
  major and minor symmetries;
- :meth:`mandel_tangent`: the same tangent as a (n, 6, 6) matrix in Mandel
  (orthonormal Voigt) form, the form :mod:`idbench_fem.fem.svk_assembly` consumes.

Here :math:`\mathbf{E} = (F^T F - I)/2` is the Green-Lagrange strain and
:math:`C = F^T F = I + 2\mathbf{E}`; every law below depends on F only through
C, so :func:`deformation_from_strain` turns a strain into a valid F.

Kernel contract
---------------
The P1 kernel of :mod:`idbench_fem.fem.svk_assembly` builds, per element, the
variations of E in Mandel order (11, 22, 33, sqrt2 12, sqrt2 13, sqrt2 23),
``B`` (T, 6, 12) (:func:`strain_variation`), and forms

.. math::

    f = V B^T s,\qquad K = V\,(B^T D B + G S G^T \otimes I),

with s = :func:`mandel` (S) and D = :meth:`mandel_tangent`. Its SVK fast path
splits D = 2 mu I_6 + lambda m m^T (m the Mandel identity); a general law
passes D itself.

Linear in the modulus
---------------------
For a fixed nu both laws have :math:`W(F; E) = E\,W(F; 1)`, so S, the internal
force and the tangent are E times their unit-modulus values
(``linear_in_modulus = True``): f_int(u; E) = E g(u), the property that makes
the sensitivity du/dE = -K^-1 g(u) one back-substitution. A model evaluates
the law once at ``E = 1`` and scales per element (or region).
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import ClassVar, Protocol

import numpy as np
from numpy.typing import NDArray

FloatArray = NDArray[np.float64]

MANDEL_PAIRS = ((0, 0), (1, 1), (2, 2), (0, 1), (0, 2), (1, 2))
"""Tensor index pairs of the six Mandel components, in order."""

_MANDEL_W = np.array([1.0, 1.0, 1.0, np.sqrt(2.0), np.sqrt(2.0), np.sqrt(2.0)])
_I = np.arange(3)


def lame(E: float, nu: float) -> tuple[float, float]:
    """Lamé parameters (lambda, mu) from Young's modulus and Poisson's ratio.

    Raises
    ------
    ValueError
        If E <= 0 or nu is not in (-1, 0.5).
    """
    if not (np.isfinite(E) and E > 0):
        raise ValueError(f"E = {E!r}: Young's modulus must be a positive number")
    if not -1.0 < nu < 0.5:
        raise ValueError(f"nu = {nu!r}: Poisson's ratio must be in (-1, 0.5)")
    return E * nu / ((1.0 + nu) * (1.0 - 2.0 * nu)), E / (2.0 * (1.0 + nu))


def green_lagrange(F: FloatArray) -> FloatArray:
    """Green-Lagrange strain (F^T F - I) / 2, shape (n, 3, 3)."""
    E = np.matmul(np.swapaxes(F, -1, -2), F)
    E[..., _I, _I] -= 1.0
    return 0.5 * E


def deformation_from_strain(E: FloatArray) -> FloatArray:
    """Symmetric F = (I + 2E)^(1/2) with the given Green-Lagrange strain.

    Raises
    ------
    ValueError
        If I + 2E is not positive definite (no deformation has that strain).
    """
    C = 2.0 * np.asarray(E, dtype=float)
    C[..., _I, _I] += 1.0
    w, v = np.linalg.eigh(C)
    if np.any(w <= 0):
        raise ValueError("strain: I + 2E must be positive definite")
    return np.einsum("...ij,...j,...kj->...ik", v, np.sqrt(w), v)


def mandel(S: FloatArray) -> FloatArray:
    """Symmetric tensors (n, 3, 3) to Mandel vectors (n, 6), shears times sqrt 2."""
    i, j = np.array(MANDEL_PAIRS).T
    return S[..., i, j] * _MANDEL_W


def mandel_matrix(C: FloatArray) -> FloatArray:
    """Minor-symmetric fourth-order tensors (n, 3, 3, 3, 3) to Mandel (n, 6, 6).

    ``s = D e`` in Mandel vectors whenever ``S = C : E``.
    """
    i, j = np.array(MANDEL_PAIRS).T
    D = C[..., i[:, None], j[:, None], i[None, :], j[None, :]]
    return D * np.outer(_MANDEL_W, _MANDEL_W)


def strain_variation(F: FloatArray, grads: FloatArray) -> FloatArray:
    r"""Variation of the Mandel strain w.r.t. the nodal displacements.

    :math:`\delta E_{JL} = \tfrac12 (F_{iJ} G_{aL} + F_{iL} G_{aJ})\,\delta u_{ai}`,
    so that e = B u to first order.

    Parameters
    ----------
    F
        Deformation gradients (T, 3, 3).
    grads
        Shape-function gradients (T, A, 3) (A = 4 for P1 tets).

    Returns
    -------
    B
        (T, 6, 3 A), columns ordered (node, component) as in the assembly.
    """
    i, j = np.array(MANDEL_PAIRS).T
    # Q[t, J, L, a, i] = F_iJ G_aL
    Q = np.einsum("tiJ,taL->tJLai", F, grads)
    B = 0.5 * (Q[:, i, j] + Q[:, j, i]) * _MANDEL_W[None, :, None, None]
    return B.reshape(len(F), 6, -1)


class Material(Protocol):
    """Anything with an energy, a stress and a tangent over F (n, 3, 3)."""

    name: ClassVar[str]
    linear_in_modulus: ClassVar[bool]
    E: float
    nu: float

    def energy(self, F: FloatArray) -> FloatArray: ...  # noqa: D102

    def stress(self, F: FloatArray) -> FloatArray: ...  # noqa: D102

    def tangent(self, F: FloatArray) -> FloatArray: ...  # noqa: D102

    def mandel_tangent(self, F: FloatArray) -> FloatArray: ...  # noqa: D102


@dataclass(frozen=True)
class _Law:
    """Shared parameters and checks (E, nu) of the laws below."""

    E: float = 1.0
    nu: float = 0.45

    def __post_init__(self) -> None:
        lame(self.E, self.nu)  # validates

    @property
    def lam(self) -> float:
        """First Lamé parameter lambda (Pa)."""
        return lame(self.E, self.nu)[0]

    @property
    def mu(self) -> float:
        """Shear modulus mu (Pa)."""
        return lame(self.E, self.nu)[1]

    def with_modulus(self, E: float) -> _Law:
        """The same law with another Young's modulus (e.g. ``1.0``)."""
        return replace(self, E=E)

    def mandel_tangent(self, F: FloatArray) -> FloatArray:
        """Material tangent dS/dE in Mandel form, shape (n, 6, 6)."""
        return mandel_matrix(self.tangent(F))


@dataclass(frozen=True)
class Svk(_Law):
    r"""St Venant-Kirchhoff: linear isotropic law on the Green-Lagrange strain.

    .. math::

        W = \tfrac{\lambda}{2} (\mathrm{tr}\,\mathbf{E})^2
            + \mu\, \mathbf{E} : \mathbf{E},\qquad
        S = \lambda\, \mathrm{tr}(\mathbf{E})\, I + 2 \mu \mathbf{E},\qquad
        \mathbb{C} = \lambda\, I \otimes I + 2 \mu\, \mathbb{I}^{sym}.

    The tangent is constant. Linear in the modulus (W = E W_1). Defined for
    any F, also inverted ones (its known weakness in compression).
    """

    name: ClassVar[str] = "svk"
    linear_in_modulus: ClassVar[bool] = True

    def energy(self, F: FloatArray) -> FloatArray:
        """Strain-energy density W (n,)."""
        E = green_lagrange(F)
        tr = np.trace(E, axis1=-2, axis2=-1)
        return 0.5 * self.lam * tr**2 + self.mu * np.einsum("...ij,...ij->...", E, E)

    def stress(self, F: FloatArray) -> FloatArray:
        """Second Piola-Kirchhoff stress S (n, 3, 3)."""
        E = green_lagrange(F)
        S = 2.0 * self.mu * E
        S[..., _I, _I] += (self.lam * np.trace(E, axis1=-2, axis2=-1))[..., None]
        return S

    def tangent(self, F: FloatArray) -> FloatArray:
        """Material tangent dS/dE (n, 3, 3, 3, 3), the same at every point."""
        eye = np.eye(3)
        C = self.lam * np.einsum("ij,kl->ijkl", eye, eye) + self.mu * (
            np.einsum("ik,jl->ijkl", eye, eye) + np.einsum("il,jk->ijkl", eye, eye)
        )
        return np.broadcast_to(C, (*np.shape(F)[:-2], 3, 3, 3, 3)).copy()


@dataclass(frozen=True)
class NeoHookean(_Law):
    r"""Compressible neo-Hookean (the Ciarlet/Simo-Pister form, as in FElupe).

    .. math::

        W = \tfrac{\mu}{2} (I_1 - 3) - \mu \ln J + \tfrac{\lambda}{2} (\ln J)^2,
        \qquad I_1 = \mathrm{tr}\, C,\ J = \det F,

        S = \mu (I - C^{-1}) + \lambda \ln J\, C^{-1},

        \mathbb{C}_{IJKL} = \lambda C^{-1}_{IJ} C^{-1}_{KL}
            + (\mu - \lambda \ln J)(C^{-1}_{IK} C^{-1}_{JL} + C^{-1}_{IL} C^{-1}_{JK}).

    At F = I it reduces to linear elasticity with the same (lambda, mu), so it
    agrees with :class:`Svk` to first order in the strain. Linear in the
    modulus (W = E W_1). Undefined for J <= 0 (inverted elements): the
    results are NaN there, which a Newton solver must treat as a failed step.
    """

    name: ClassVar[str] = "neo-hookean"
    linear_in_modulus: ClassVar[bool] = True

    @staticmethod
    def _invariants(F: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray]:
        """Return C, C^-1 and ln J (NaN where J <= 0)."""
        C = np.matmul(np.swapaxes(F, -1, -2), F)
        J = np.linalg.det(F)
        with np.errstate(invalid="ignore", divide="ignore"):
            lnJ = np.where(J > 0, np.log(np.where(J > 0, J, 1.0)), np.nan)
        return C, np.linalg.inv(C), lnJ

    def energy(self, F: FloatArray) -> FloatArray:
        """Strain-energy density W (n,)."""
        C, _, lnJ = self._invariants(F)
        I1 = np.trace(C, axis1=-2, axis2=-1)
        return 0.5 * self.mu * (I1 - 3.0) - self.mu * lnJ + 0.5 * self.lam * lnJ**2

    def stress(self, F: FloatArray) -> FloatArray:
        """Second Piola-Kirchhoff stress S (n, 3, 3)."""
        _, Ci, lnJ = self._invariants(F)
        S = (self.lam * lnJ - self.mu)[..., None, None] * Ci
        S[..., _I, _I] += self.mu
        return S

    def mandel_tangent(self, F: FloatArray) -> FloatArray:
        """Material tangent in Mandel form (n, 6, 6), built directly.

        The same as ``mandel_matrix(tangent(F))`` without the (n, 81) tensor:
        D = lambda c c^T + (mu - lambda ln J) M, c = mandel(C^-1),
        M_(IJ)(KL) = w_IJ w_KL (C^-1_IK C^-1_JL + C^-1_IL C^-1_JK), w the
        Mandel weights (1 or sqrt 2).
        """
        _, Ci, lnJ = self._invariants(F)
        i, j = np.array(MANDEL_PAIRS).T
        a, b = i[:, None], i[None, :]
        c, d = j[:, None], j[None, :]
        M = Ci[..., a, b] * Ci[..., c, d] + Ci[..., a, d] * Ci[..., c, b]
        M *= (self.mu - self.lam * lnJ)[..., None, None] * np.outer(
            _MANDEL_W, _MANDEL_W
        )
        m = mandel(Ci)
        M += self.lam * m[..., :, None] * m[..., None, :]
        return M

    def tangent(self, F: FloatArray) -> FloatArray:
        """Material tangent dS/dE (n, 3, 3, 3, 3)."""
        _, Ci, lnJ = self._invariants(F)
        a = (self.mu - self.lam * lnJ)[..., None, None, None, None]
        return self.lam * np.einsum("...ij,...kl->...ijkl", Ci, Ci) + a * (
            np.einsum("...ik,...jl->...ijkl", Ci, Ci)
            + np.einsum("...il,...jk->...ijkl", Ci, Ci)
        )


LAWS: dict[str, type[_Law]] = {"svk": Svk, "neo-hookean": NeoHookean}
"""Laws by the name a body description uses."""


def make_material(name: str, E: float = 1.0, nu: float = 0.45) -> _Law:
    """Build the law called ``name`` (``"svk"`` or ``"neo-hookean"``).

    Raises
    ------
    ValueError
        Naming the unknown law and the allowed ones, or a bad E or nu.
    """
    if name not in LAWS:
        raise ValueError(f"material {name!r}: allowed are {', '.join(LAWS)}")
    return LAWS[name](E=float(E), nu=float(nu))
