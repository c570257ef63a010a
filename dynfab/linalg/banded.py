"""Banded matrices of a yarn's degrees of freedom, and their O(N) LU factorisation.

The unknowns are interleaved per node, dof 2 i = x_i and 2 i + 1 = z_i. The
bending term couples nodes i-1, i, i+1, so every matrix of the model has
half-bandwidth `BANDWIDTH` = 5. A matrix A (n x n) is stored as
`band[i, j - i + BANDWIDTH] = A[i, j]`, shape (n, 2 BANDWIDTH + 1).

The factorisation is Doolittle LU without pivoting: O(n BANDWIDTH^2) work.
Without pivoting it is stable for the (nearly) symmetric positive definite
matrices Newton and the semi-implicit integrator hand it; a pivot that is not
positive is reported, so the caller can shift the matrix (Newton on an
indefinite Hessian) instead of dividing by it.
"""

from __future__ import annotations

import numba
import numpy as np

BANDWIDTH = 5
"""Half-bandwidth of every model matrix (interleaved x, z; three-node bending stencil)."""


def zeros_band(dofs: int) -> np.ndarray:
    """An all-zero banded matrix for `dofs` unknowns."""
    return np.zeros((dofs, 2 * BANDWIDTH + 1))


def to_dense(band: np.ndarray) -> np.ndarray:
    """The full n x n matrix A[i, j] = band[i, j - i + BANDWIDTH] of a banded one (numpy's
    dense linear algebra: inverses, eigenvalues; O(n^2) memory)."""
    n = band.shape[0]
    matrix = np.zeros((n, n))
    for offset in range(-BANDWIDTH, BANDWIDTH + 1):
        rows = np.arange(max(0, -offset), min(n, n - offset))
        matrix[rows, rows + offset] = band[rows, offset + BANDWIDTH]
    return matrix


@numba.njit(cache=True)
def band_add(band, i, j, value):
    """A[i, j] += value."""
    band[i, j - i + BANDWIDTH] += value


@numba.njit(cache=True)
def band_matvec(band, x, out):
    """out = A x."""
    n = x.size
    for i in range(n):
        acc = 0.0
        for j in range(max(0, i - BANDWIDTH), min(n, i + BANDWIDTH + 1)):
            acc += band[i, j - i + BANDWIDTH] * x[j]
        out[i] = acc


@numba.njit(cache=True)
def constrain(band, rhs, fixed):
    """Replace the rows and columns of fixed dofs by the identity, their rhs by 0."""
    n = rhs.size
    for i in range(n):
        if not fixed[i]:
            continue
        for j in range(max(0, i - BANDWIDTH), min(n, i + BANDWIDTH + 1)):
            band[i, j - i + BANDWIDTH] = 0.0
            band[j, i - j + BANDWIDTH] = 0.0
        band[i, BANDWIDTH] = 1.0
        rhs[i] = 0.0


@numba.njit(cache=True)
def lu_factor(band):
    """Factor A = L U in place (unit lower L below the diagonal, U on and above).

    Returns the index of the first pivot that is not positive, or -1 when all
    pivots are positive (for a symmetric matrix: it is positive definite).
    Row i = k + o of the band holds A[i, k] at column BANDWIDTH - o and
    A[i, k + m] at column BANDWIDTH + m - o.
    """
    n = band.shape[0]
    for k in range(n):
        pivot = band[k, BANDWIDTH]
        if not pivot > 0.0:
            return k
        reach = min(BANDWIDTH, n - 1 - k)
        for o in range(1, reach + 1):
            row = band[k + o]
            factor = row[BANDWIDTH - o] / pivot
            row[BANDWIDTH - o] = factor
            if factor != 0.0:
                for m in range(1, reach + 1):
                    row[BANDWIDTH + m - o] -= factor * band[k, BANDWIDTH + m]
    return -1


@numba.njit(cache=True)
def forward_substitute(band, rhs):
    """rhs = L^-1 rhs in place, L the unit lower triangle stored left of the diagonal of
    `band` (the factor of `lu_factor`, or of `dynfab.linalg.ldlt.ldlt_factor`)."""
    for i in range(rhs.size):
        acc = rhs[i]
        for j in range(max(0, i - BANDWIDTH), i):
            acc -= band[i, j - i + BANDWIDTH] * rhs[j]
        rhs[i] = acc


@numba.njit(cache=True)
def lu_solve(band, rhs):
    """Solve A x = rhs in place with the factors of `lu_factor`."""
    n = rhs.size
    forward_substitute(band, rhs)
    for i in range(n - 1, -1, -1):
        acc = rhs[i]
        for j in range(i + 1, min(n, i + BANDWIDTH + 1)):
            acc -= band[i, j - i + BANDWIDTH] * rhs[j]
        rhs[i] = acc / band[i, BANDWIDTH]
