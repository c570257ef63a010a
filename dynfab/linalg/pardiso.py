"""MKL PARDISO's sparse symmetric indefinite factorisation P A P^T = L D L^T, where MKL is
installed (a base dependency on x86-64 Linux and Windows, where MKL has wheels;
docs/model.md section 11.10).

On the shear specimens a SuperLU factorisation is most of a Newton iteration. PARDISO
(Schenk and Gaertner, Future Gener. Comput. Syst. 20, 2004) factors the same Hessians as a
symmetric matrix (one triangle, about half SuperLU's arithmetic and fill) in its own
nested-dissection order (METIS), faster than SuperLU in the fabric's order on the
specimens' Hessians (with the explicit zeros their Newton solves keep) even counting its
analysis (the order and the symbolic factor), which the Newton solves do once per pattern
(docs/results.md, "In-plane shear": PARDISO against SuperLU). Its pivots are
Bunch-Kaufman's 1 x 1 and 2 x 2 blocks within each supernode; a pivot below
PIVOT_THRESHOLD of its supernode's scale is perturbed instead (and counted). A factor
with a perturbed pivot, or with a pivot within TINY_PIVOT of max |A_ii| (SuperLU's guard:
the matrix singular to rounding), is refused, and SuperLU factors that matrix instead
(`dynfab.model.fabric.ordering.symmetric_factor`), so every count and solve taken from
PARDISO is of the matrix asked. D's inertia is A's (Sylvester); PARDISO
reports it.

MKL runs sequentially here (its threading layer set before its first call): the factors and
so every Newton iterate are the same bits run after run (a resumed run repeats an
uninterrupted one), and MKL's OpenMP runtime never meets numba's threads. MKL is bound
through ctypes (the `mkl` wheel's `mkl_rt`, found under the interpreter's prefix); without
it `available()` is False and the fabric factors by SuperLU alone, as it does matrices of
fewer than MIN_UNKNOWNS unknowns. `DYNFAB_PARDISO=0` in the environment turns it off (to
compare the two)."""

from __future__ import annotations

import ctypes
import ctypes.util
import functools
import glob
import os
import site
import sys

import numpy as np
import scipy.sparse

MIN_UNKNOWNS = 1000
"""Smaller matrices are factored by SuperLU (`dynfab.model.fabric.ordering.symmetric_factor`):
there PARDISO's fixed costs outweigh its speed. The threshold lies between the sizes where
PARDISO was slower, the 4 x 4 planar patch (504 unknowns) and the 30 mm frame (510), and
those where it was faster, the 8 x 8 patch (2,032) and the 60 mm frame (2,706)
(docs/results.md, "PARDISO's smallest matrix")."""
SYMMETRIC_INDEFINITE = -2
"""PARDISO's mtype for a real symmetric indefinite matrix."""
PIVOT_THRESHOLD = 13
"""iparm[9]: pivots below 1e-13 of their supernode's scale are perturbed (and the factor
refused)."""
TINY_PIVOT = 64.0 * np.finfo(np.float64).eps
"""Pivots within this of max |A_ii| are refused (`SymmetricFactor.tiny_pivots`), as the
sparse inertia's guard refuses SuperLU's (`dynfab.model.fabric.inertia`)."""
_SEQUENTIAL = 1
"""MKL_THREADING_SEQUENTIAL, for MKL_Set_Threading_Layer."""
_LP64 = 0
"""MKL_INTERFACE_LP64: 32-bit integers, for MKL_Set_Interface_Layer."""
_RELEASE_ALL = -1
_ANALYSIS, _FACTOR, _SOLVE = 11, 22, 33


def _candidates() -> list[str]:
    """Paths where the `mkl` wheel puts mkl_rt, shortest first, then the loader's."""
    found = []
    for prefix in (sys.prefix, site.USER_BASE):
        for pattern in ("lib/libmkl_rt.so*", "Library/bin/mkl_rt*.dll", "lib/libmkl_rt*.dylib"):
            found += sorted(glob.glob(os.path.join(prefix, pattern)), key=len)
    named = ctypes.util.find_library("mkl_rt")
    return found + ([named] if named else [])


@functools.cache
def library() -> ctypes.CDLL | None:
    """MKL's runtime library, set sequential, or None (not installed, or DYNFAB_PARDISO=0)."""
    if os.environ.get("DYNFAB_PARDISO", "1") == "0":
        return None
    for path in _candidates():
        try:
            lib = ctypes.CDLL(path)
            _declare(lib)
        except (OSError, AttributeError):  # not loadable, or an MKL without these functions
            continue
        lib.MKL_Set_Interface_Layer(_LP64)
        lib.MKL_Set_Threading_Layer(_SEQUENTIAL)
        return lib
    return None


def available() -> bool:
    """Whether PARDISO factors here (`library`)."""
    return library() is not None


def takes(unknowns: int) -> bool:
    """Whether the fabric's symmetric matrices of `unknowns` unknowns go to PARDISO first
    (`dynfab.model.fabric.ordering.symmetric_factor`): MKL available, at least MIN_UNKNOWNS."""
    return available() and unknowns >= MIN_UNKNOWNS


def _declare(lib) -> None:
    """The signatures of MKL's C functions used here, every integer 32-bit (LP64):
    pardiso(pt, maxfct, mnum, mtype, phase, n, a, ia, ja, perm, nrhs, iparm, msglvl, b, x,
    error) and pardiso_getdiag(pt, df, da, mnum, error)."""
    pointer, integer = ctypes.c_void_p, ctypes.POINTER(ctypes.c_int32)
    lib.MKL_Set_Threading_Layer.argtypes = [ctypes.c_int]
    lib.MKL_Set_Interface_Layer.argtypes = [ctypes.c_int]
    lib.pardiso.restype = None
    lib.pardiso.argtypes = [pointer, integer, integer, integer, integer, integer, pointer,
                            pointer, pointer, pointer, integer, pointer, integer, pointer,
                            pointer, integer]
    lib.pardiso_getdiag.restype = None
    lib.pardiso_getdiag.argtypes = [pointer, pointer, pointer, integer, integer]


def upper_triangle(A) -> scipy.sparse.csr_matrix:
    """The upper triangle with the diagonal of the symmetric A in CSR, sorted, every
    diagonal entry stored (PARDISO's input for a symmetric matrix)."""
    upper = scipy.sparse.triu(A, format="csr")
    upper.sum_duplicates()
    upper.sort_indices()
    return upper


class SymmetricFactor:
    """PARDISO's L D L^T of a symmetric matrix (module docstring). Raises RuntimeError where
    PARDISO reports an error (a structurally singular matrix, memory). `refactor` factors a
    matrix of the same pattern again on the kept analysis."""

    def __init__(self, A):
        self._lib = library()
        if self._lib is None:
            raise RuntimeError("PARDISO is not available (module docstring)")
        self._handle = np.zeros(64, np.int64)
        self.iparm = np.zeros(64, np.int32)
        p = self.iparm
        p[0] = 1             # these values, not PARDISO's defaults
        p[1] = 2             # nested dissection by METIS
        p[9] = PIVOT_THRESHOLD
        p[17] = -1           # report the factor's nonzeros
        p[20] = 1            # Bunch-Kaufman 1 x 1 and 2 x 2 pivots
        p[34] = 1            # zero-based indices
        p[55] = 1            # D's diagonal kept for pardiso_getdiag
        self._set(A)
        self._call(_ANALYSIS)
        self._factor()

    def _set(self, A) -> None:
        upper = upper_triangle(A)
        n = upper.shape[0]
        diagonal = upper.indices[upper.indptr[:-1]] if upper.nnz else np.empty(0)
        if upper.shape != (n, n) or n == 0 or np.any(np.diff(upper.indptr) == 0) \
                or not np.array_equal(diagonal, np.arange(n)):
            raise RuntimeError("PARDISO: a diagonal entry is not stored (structurally singular)")
        self.n = n
        self._data = np.ascontiguousarray(upper.data, np.float64)
        self._indptr = upper.indptr.astype(np.int32)
        self._indices = upper.indices.astype(np.int32)

    def refactor(self, A) -> bool:
        """Factor A on the kept analysis if its upper triangle has this factor's pattern;
        False (nothing done) if not."""
        upper = upper_triangle(A)
        if not (upper.shape[0] == self.n and np.array_equal(upper.indptr, self._indptr)
                and np.array_equal(upper.indices, self._indices)):
            return False
        self._data = np.ascontiguousarray(upper.data, np.float64)
        self._factor()
        return True

    def _factor(self) -> None:
        self._call(_FACTOR)
        self.perturbed = int(self.iparm[13])
        """Pivots PARDISO perturbed (the factor is then not of the matrix asked)."""
        self.negatives = int(self.iparm[22])
        """Negative eigenvalues of D, In(A)'s (Sylvester)."""
        self.fill = int(self.iparm[17])
        """nnz(L) with the diagonal."""
        pivots, diagonal = np.zeros(self.n), np.zeros(self.n)
        error = ctypes.c_int32(0)
        self._lib.pardiso_getdiag(self._handle.ctypes.data, pivots.ctypes.data,
                                  diagonal.ctypes.data, ctypes.byref(ctypes.c_int32(1)),
                                  ctypes.byref(error))
        if error.value != 0:
            raise RuntimeError(f"PARDISO error {error.value} reading the pivots")
        self.smallest_pivot = float(np.abs(pivots).min())
        """min |D_ii| (the diagonal of D, a 2 x 2 block's two diagonal entries included)."""
        self.scale = float(np.abs(diagonal).max())
        """max |A_ii|, the scale of `tiny_pivots`."""

    @property
    def tiny_pivots(self) -> bool:
        """A pivot within TINY_PIVOT max |A_ii| of zero (SuperLU's guard in
        `dynfab.model.fabric.inertia`): A is singular to rounding, its solve and count unusable."""
        return self.smallest_pivot <= TINY_PIVOT * self.scale

    def solve(self, rhs) -> np.ndarray:
        """A^-1 rhs, rhs (n,) or (n, k)."""
        b = np.asarray(rhs, np.float64)
        columns = 1 if b.ndim == 1 else b.shape[1]
        b = np.asfortranarray(b)
        x = np.zeros_like(b, order="F")
        self._call(_SOLVE, b, x, columns)
        return np.ascontiguousarray(x)

    def _call(self, phase: int, b=None, x=None, columns: int = 1) -> None:
        error = ctypes.c_int32(0)
        one = ctypes.c_int32(1)
        self._lib.pardiso(
            self._handle.ctypes.data, ctypes.byref(one), ctypes.byref(one),
            ctypes.byref(ctypes.c_int32(SYMMETRIC_INDEFINITE)), ctypes.byref(ctypes.c_int32(phase)),
            ctypes.byref(ctypes.c_int32(self.n)), self._data.ctypes.data, self._indptr.ctypes.data,
            self._indices.ctypes.data, None, ctypes.byref(ctypes.c_int32(columns)),
            self.iparm.ctypes.data, ctypes.byref(ctypes.c_int32(0)),
            None if b is None else b.ctypes.data, None if x is None else x.ctypes.data,
            ctypes.byref(error))
        if error.value != 0:
            raise RuntimeError(f"PARDISO error {error.value} in phase {phase}")

    def __del__(self):
        if getattr(self, "_lib", None) is not None and self._handle.any():
            try:
                self._call(_RELEASE_ALL)
            except Exception:  # noqa: BLE001 -- at exit, ctypes or numpy may be gone
                pass
