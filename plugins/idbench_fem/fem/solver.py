"""Sparse direct solvers with a fixed pattern: PARDISO (pypardiso's MKL) and scipy.

Both factor a symmetric matrix given as CSR data in a pattern fixed at
construction and keep the last factorization for further right-hand sides.

- :class:`PardisoSolver`: MKL PARDISO on the upper triangle, zero-based
  indices: Cholesky (mtype 2), or symmetric indefinite LDL^T (mtype -2) for a
  matrix that is not positive definite (the SVK tangent far from
  equilibrium); each type's symbolic analysis (phase 11, METIS ordering) runs
  once and every later factorization is numeric only (phase 22).
- :class:`ScipySolver`: SuperLU (``scipy.sparse.linalg.splu``) on the full
  matrix with the minimum-degree ordering of A^T + A and symmetric pivoting.

:func:`make_solver` picks one: ``backend`` argument, else the environment
variable ``IDBENCH_SOLVER`` (``pardiso`` or ``scipy``), else PARDISO when
pypardiso is importable.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import importlib.metadata
import logging
import os
from typing import Any, Protocol

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla
from numpy.typing import NDArray

log = logging.getLogger(__name__)

SOLVER_ENV = "IDBENCH_SOLVER"
BACKENDS = ("pardiso", "scipy")


class SolverError(RuntimeError):
    """The factorization failed (e.g. a singular matrix)."""


class LinearSolver(Protocol):
    """A direct solver for matrices with one fixed sparsity pattern."""

    name: str
    upper: bool
    """Whether the solver wants only the upper triangle of the pattern."""

    def factor(self, data: NDArray[np.float64]) -> None:
        """Factor the matrix with CSR ``data`` (in the fixed pattern)."""
        ...

    def solve(self, rhs: NDArray[np.float64]) -> NDArray[np.float64]:
        """Solve with the last factorization; ``rhs`` (n,) or (n, k)."""
        ...


def pardiso_available() -> bool:
    """Whether pypardiso (and MKL) can be loaded."""
    try:
        _mkl()
    except (ImportError, OSError):
        return False
    return True


_MKL: ctypes.CDLL | None = None


def _mkl_rt_path() -> str | None:
    """Path of MKL's runtime library, without importing pypardiso.

    ``import pypardiso`` builds a solver at import time, which globs all of
    site-packages for ``mkl_rt`` when ``find_library`` fails (about a second at
    every process start). The same library is found from, in order:
    ``PYPARDISO_MKL_RT`` (the variable pypardiso honours), the file list of the
    installed ``mkl`` distribution, and ``ctypes.util.find_library``.
    """
    env = os.environ.get("PYPARDISO_MKL_RT")
    if env:
        return env
    try:
        files = importlib.metadata.files("mkl") or []
    except importlib.metadata.PackageNotFoundError:
        files = []
    found = sorted(
        (f for f in files if f.name.startswith(("libmkl_rt.so", "mkl_rt"))),
        key=lambda f: len(f.name),
    )
    for f in found:
        path = os.path.normpath(str(f.locate()))
        if os.path.exists(path):
            return path
    return ctypes.util.find_library("mkl_rt")


def _mkl() -> ctypes.CDLL:
    global _MKL
    if _MKL is None:
        path = _mkl_rt_path()
        if path is not None:
            try:
                _MKL = ctypes.CDLL(path)
            except OSError:
                log.debug("could not load %s; asking pypardiso", path)
        if _MKL is None:
            import pypardiso  # slow: globs site-packages for mkl_rt

            _MKL = pypardiso.PyPardisoSolver().libmkl
    return _MKL


class _Pardiso:
    """One PARDISO handle of matrix type ``mtype`` on a fixed upper CSR pattern."""

    def __init__(self, fn: Any, ia: NDArray[np.int32], ja: NDArray[np.int32],
                 data: NDArray[np.float64], mtype: int) -> None:  # fmt: skip
        self._fn = fn
        self._ia, self._ja, self._data = ia, ja, data
        self.n = len(ia) - 1
        self._pt = np.zeros(64, dtype=np.int64)
        self.iparm = np.zeros(64, dtype=np.int32)
        ip = self.iparm
        ip[0] = 1  # user-set iparm
        ip[1] = 2  # METIS nested dissection
        # iterative refinement: 0 = two steps only when pivots were perturbed;
        # always refining (2) made every solve 3-5x slower for the same
        # residual (benchmarks: 0.55 -> 0.11 ms at 500 nodes, 13 -> 4.7 ms at 4k)
        ip[7] = 0
        ip[9] = 8  # pivot perturbation 1e-8 (indefinite type)
        ip[10] = 0  # no scaling: keeps the analysis independent of the values
        ip[12] = 0  # no weighted matching (same reason)
        ip[17] = -1  # report nnz of the factor
        ip[20] = 1  # Bunch-Kaufman 1x1 and 2x2 pivoting (indefinite type)
        ip[34] = 1  # zero-based indexing
        self.analysed = False
        self._c = {
            name: ctypes.c_int32(v)
            for name, v in (("maxfct", 1), ("mnum", 1), ("mtype", mtype), ("n", self.n),
                            ("msglvl", 0))
        }  # fmt: skip
        self._perm = np.zeros(0, dtype=np.int32)

    def call(
        self, phase: int, b: NDArray[np.float64], x: NDArray[np.float64], nrhs: int
    ) -> None:
        err = ctypes.c_int32(0)
        c = self._c
        i32p = ctypes.POINTER(ctypes.c_int32)
        self._fn(
            self._pt.ctypes.data_as(ctypes.POINTER(ctypes.c_int64)),
            ctypes.byref(c["maxfct"]), ctypes.byref(c["mnum"]),
            ctypes.byref(c["mtype"]),
            ctypes.byref(ctypes.c_int32(phase)), ctypes.byref(c["n"]),
            self._data.ctypes.data, self._ia.ctypes.data_as(i32p),
            self._ja.ctypes.data_as(i32p), self._perm.ctypes.data_as(i32p),
            ctypes.byref(ctypes.c_int32(nrhs)), self.iparm.ctypes.data_as(i32p),
            ctypes.byref(c["msglvl"]), b.ctypes.data, x.ctypes.data, ctypes.byref(err),
        )  # fmt: skip
        if err.value != 0:
            raise SolverError(f"PARDISO phase {phase} failed with error {err.value}")

    def factor(self) -> None:
        """Numeric factorization (runs the symbolic analysis the first time)."""
        dummy = np.zeros(1)
        if not self.analysed:
            self.call(11, dummy, dummy, 1)
            self.analysed = True
            log.debug(
                "PARDISO analysis (mtype %d): n=%d, nnz(L)=%d",
                self._c["mtype"].value, self.n, self.iparm[17],
            )  # fmt: skip
        self.call(22, dummy, dummy, 1)

    def release(self) -> None:
        if self.analysed:
            dummy = np.zeros(1)
            self.call(-1, dummy, dummy, 1)
            self.analysed = False


class PardisoSolver:
    """MKL PARDISO on the upper triangle; Cholesky, else Bunch-Kaufman LDL^T.

    Each factorization tries the positive definite type first (mtype 2: a
    Cholesky factorization, 10-25% faster than the indefinite one from 2,600
    nodes up, benchmarks/forward.py) and falls back to the symmetric
    indefinite type (mtype -2) when PARDISO finds a non-positive pivot: the SVK
    tangent is positive definite near a stable equilibrium, but may be
    indefinite far from it. The choice is made per factorization from the
    matrix alone, so a solve never depends on what was factored before. Each
    type's symbolic analysis (phase 11) runs once, on its first use.

    Parameters
    ----------
    indptr, indices
        Upper-triangle CSR pattern (zero-based, sorted column indices).
    """

    name = "pardiso"
    upper = True

    def __init__(self, indptr: NDArray[np.int32], indices: NDArray[np.int32]) -> None:
        lib = _mkl()
        fn = lib.pardiso
        i32p = ctypes.POINTER(ctypes.c_int32)
        fn.argtypes = [ctypes.POINTER(ctypes.c_int64)] + [i32p] * 5 + [
            ctypes.c_void_p, i32p, i32p, i32p, i32p, i32p, i32p,
            ctypes.c_void_p, ctypes.c_void_p, i32p,
        ]  # fmt: skip
        fn.restype = None
        self.n = len(indptr) - 1
        ia = np.ascontiguousarray(indptr, dtype=np.int32)
        ja = np.ascontiguousarray(indices, dtype=np.int32)
        self._data = np.zeros(len(ja))
        self._spd = _Pardiso(fn, ia, ja, self._data, 2)
        self._indefinite = _Pardiso(fn, ia, ja, self._data, -2)
        self._factored: _Pardiso | None = None
        self.indefinite_factorizations = 0
        """How many factorizations fell back to the indefinite type."""

    def factor(self, data: NDArray[np.float64]) -> None:
        """Numeric factorization of the matrix with CSR ``data``."""
        self._data[:] = data
        self._factored = None
        try:
            self._spd.factor()
            self._factored = self._spd
            return
        except SolverError:  # a non-positive pivot: not positive definite
            pass
        self._indefinite.factor()
        self.indefinite_factorizations += 1
        self._factored = self._indefinite

    def solve(self, rhs: NDArray[np.float64]) -> NDArray[np.float64]:
        """Forward and back substitution with the last factorization."""
        if self._factored is None:
            raise SolverError("solve before factor")
        b = np.asfortranarray(rhs, dtype=np.float64)
        x = np.zeros_like(b)
        self._factored.call(33, b, x, 1 if b.ndim == 1 else b.shape[1])
        return np.ascontiguousarray(x)

    def __del__(self) -> None:
        for handle in (getattr(self, "_spd", None), getattr(self, "_indefinite", None)):
            try:
                if handle is not None:
                    handle.release()
            except Exception:  # interpreter shutdown
                pass


class ScipySolver:
    """SuperLU on the full symmetric matrix, minimum degree on A^T + A.

    Parameters
    ----------
    indptr, indices
        Full CSR pattern (sorted column indices).
    """

    name = "scipy"
    upper = False

    def __init__(self, indptr: NDArray[np.int32], indices: NDArray[np.int32]) -> None:
        n = len(indptr) - 1
        self._a = sp.csr_matrix((np.zeros(len(indices)), indices, indptr), shape=(n, n))
        self._lu: spla.SuperLU | None = None

    def factor(self, data: NDArray[np.float64]) -> None:
        """LU factorization (the matrix is symmetric: CSR = CSC of its transpose)."""
        self._a.data[:] = data
        try:
            # CSR of a symmetric matrix is its CSC: no conversion needed
            csc = sp.csc_matrix(
                (self._a.data, self._a.indices, self._a.indptr), shape=self._a.shape
            )
            self._lu = spla.splu(
                csc,
                permc_spec="MMD_AT_PLUS_A",
                diag_pivot_thresh=0.01,
                options={"SymmetricMode": True},
            )
        except RuntimeError as exc:  # "Factor is exactly singular"
            self._lu = None
            raise SolverError(f"SuperLU failed: {exc}") from exc

    def solve(self, rhs: NDArray[np.float64]) -> NDArray[np.float64]:
        """Substitution with the last factorization."""
        if self._lu is None:
            raise SolverError("solve before factor")
        return self._lu.solve(np.asarray(rhs, dtype=np.float64))


def resolve_backend(backend: str | None = None) -> str:
    """Pick the backend: argument, else ``IDBENCH_SOLVER``, else the fastest."""
    choice = backend or os.environ.get(SOLVER_ENV, "").strip().lower() or None
    if choice is None:
        return "pardiso" if pardiso_available() else "scipy"
    if choice not in BACKENDS:
        raise ValueError(
            f"solver backend {choice!r}: allowed are {', '.join(BACKENDS)}"
        )
    if choice == "pardiso" and not pardiso_available():
        raise ValueError(
            "solver backend 'pardiso' requested but pypardiso/MKL is not available"
        )
    return choice


def make_solver(
    backend: str, indptr: NDArray[np.int32], indices: NDArray[np.int32]
) -> LinearSolver:
    """Build the solver ``backend`` (see :func:`resolve_backend`) on a pattern."""
    if backend == "pardiso":
        return PardisoSolver(indptr, indices)
    if backend == "scipy":
        return ScipySolver(indptr, indices)
    raise ValueError(f"solver backend {backend!r}: allowed are {', '.join(BACKENDS)}")
