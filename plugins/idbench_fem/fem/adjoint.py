r"""The parameter derivative of the equilibrium, for adjoint and forward products.

Both laws are linear in each element's modulus, and the moduli are linear in
the parameters, :math:`E_e = \theta_{r(e)} c_e`, so the internal force is
:math:`f_{int}(u; \theta) = \sum_r \theta_r g_r(u)` with :math:`g_r` the
force of the elements of parameter r at unit value. At a converged state of
step k, :math:`r(u, \theta) = f_{int} - f_{ext}(k) = 0` gives

.. math::

    \frac{du}{d\theta} = -K^{-1} G, \qquad G = [g_1, \dots, g_p],

and for any weights w (the adjoint)

.. math::

    w^T \frac{du}{d\theta} = -\lambda^T G, \qquad K^T \lambda = w,

one transposed solve (K is symmetric for a hyperelastic law). G is sparse:
column r has the dofs of parameter r's elements only (:func:`parameter_matrix`),
so products with it cost O(elements) whatever p.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import scipy.sparse as sp
from numpy.typing import NDArray

IntArray = NDArray[np.int64]


def parameter_matrix(asm: Any, kin_unit: Any, regions: IntArray, p: int) -> Any:
    """G (n_free, p), CSR: column r the internal force of parameter r at unit value.

    Parameters
    ----------
    asm
        An assembler of the state's dofs (``element_forces``, ``element_dofs``,
        ``n_free``).
    kin_unit
        Its kinematics at the state with the elements' moduli at theta = 1.
    regions
        (T,) each element's parameter.
    p
        Number of parameters.
    """
    fe = np.asarray(asm.element_forces(kin_unit)).reshape(-1, 12)
    dofs = np.asarray(asm.element_dofs).reshape(-1, 12)
    cols = np.broadcast_to(np.asarray(regions)[:, None], dofs.shape)
    keep = dofs >= 0
    return sp.csr_matrix(
        (fe[keep], (dofs[keep], cols[keep])), shape=(int(asm.n_free), int(p))
    )


def node_sums(
    fe: NDArray[np.float64], on_nodes: NDArray[np.bool_], regions: IntArray, p: int
) -> NDArray[np.float64]:
    """(3, p): per parameter, the element forces ``fe`` (T, 4, 3) on ``on_nodes``.

    ``on_nodes`` (T, 4) marks each element's nodes that count (a reaction's).
    """
    per_element = (fe * on_nodes[:, :, None]).sum(axis=1)  # (T, 3)
    return np.stack(
        [np.bincount(regions, weights=per_element[:, c], minlength=p) for c in range(3)]
    )
