"""Symmetric banded LDL^T without pivoting, with the inertia of the matrix
(docs/model.md section 6).

H = L D L^T, L unit lower triangular with the half-bandwidth of H
(`dynfab.linalg.banded.BANDWIDTH`), D diagonal: O(n BANDWIDTH^2) work, O(n) memory.
By Sylvester's law of inertia H and D have as many negative eigenvalues: the
factorisation counts the negative pivots instead of stopping at the first one
(as `dynfab.linalg.banded.lu_factor` does). Without pivoting a pivot can vanish on an
indefinite or singular matrix: `ldlt_factor` then reports it, and the caller
factors H + tau I with tau at the rounding level instead (all pivots positive
then prove lambda_min(H) > -tau).

Storage: the `dynfab.linalg.banded` layout, band[i, j - i + BANDWIDTH] = H[i, j]; only
the lower half (j <= i) is read. After `ldlt_factor`, band[i, BANDWIDTH] holds
d_i and band[i, j - i + BANDWIDTH] (j < i) holds L[i, j].
"""

from __future__ import annotations

import numba
import numpy as np

from dynfab.linalg.banded import BANDWIDTH, forward_substitute

TINY_PIVOT = -1
"""`ldlt_factor`'s answer when a pivot is within the tolerance of zero."""


@numba.njit(cache=True)
def ldlt_factor(band, shift, tiny):
    """Factor band + shift I = L D L^T in place; returns the number of negative pivots.

    Returns TINY_PIVOT (-1) as soon as a pivot has |d_k| <= tiny (the factor is
    then unusable). Column k eliminates rows k+1..k+BANDWIDTH:
    H[k+o, k+m] -= L[k+o, k] d_k L[k+m, k] = a_o a_m / d_k for 1 <= m <= o, a_o = H[k+o, k].
    """
    n = band.shape[0]
    negatives = 0
    for k in range(n):
        d = band[k, BANDWIDTH] + shift
        if not abs(d) > tiny:  # NaN too
            return TINY_PIVOT
        band[k, BANDWIDTH] = d
        if d < 0.0:
            negatives += 1
        reach = min(BANDWIDTH, n - 1 - k)
        inverse = 1.0 / d
        # Column k below the diagonal still holds a_o = H[k+o, k]; L[k+o, k] = a_o / d.
        for o in range(1, reach + 1):
            a = band[k + o, BANDWIDTH - o]
            if a != 0.0:
                factor = a * inverse
                for m in range(1, o + 1):
                    band[k + o, BANDWIDTH - o + m] -= factor * band[k + m, BANDWIDTH - m]
        for o in range(1, reach + 1):
            band[k + o, BANDWIDTH - o] *= inverse
    return negatives


@numba.njit(cache=True)
def ldlt_solve(band, rhs):
    """Solve (L D L^T) x = rhs in place with the factor of `ldlt_factor`."""
    forward_substitute(band, rhs)
    for i in range(rhs.size):
        rhs[i] /= band[i, BANDWIDTH]
    back_substitute(band, rhs)


@numba.njit(cache=True)
def back_substitute(band, rhs):
    """Solve L^T x = rhs in place (the unit upper triangle of the factor)."""
    n = rhs.size
    for j in range(n - 1, 0, -1):  # by rows of L: x_j is final, remove it from the rows above
        x = rhs[j]
        if x != 0.0:
            for i in range(max(0, j - BANDWIDTH), j):
                rhs[i] -= band[j, i - j + BANDWIDTH] * x


@numba.njit(cache=True)
def negative_direction(band, pivot, out):
    """out = L^-T e_pivot, for which out^T H out = d_pivot (the pivot's value).

    H = L D L^T gives v^T H v = (L^T v)^T D (L^T v) = e^T D e = d_pivot.
    """
    out[:] = 0.0
    out[pivot] = 1.0
    back_substitute(band, out)


@numba.njit(cache=True)
def inverse_norm_1(band, free):
    """Hager's (1984) estimate of ||H^-1||_1 (= ||H^-1||_inf, H symmetric) over the free dofs.

    Higham's refinement (1988, LAPACK xLACON): at most 5 Hager sweeps, each
    two solves with the factor, and the alternating-sign test vector
    x_i = (-1)^i (1 + i / (n - 1)), whose 2 ||H^-1 x||_1 / (3 n) is taken if
    larger. The result is a lower bound of the norm, in practice within a
    factor of 3 and usually exact. Fixed dofs (`free` False; identity rows
    after `dynfab.linalg.banded.constrain`) are left out.
    """
    n, count = free.size, np.count_nonzero(free)
    if count == 0:
        return 0.0
    x, y = np.zeros(n), np.zeros(n)
    for i in range(n):
        if free[i]:
            x[i] = 1.0 / count
    estimate = 0.0
    previous_j = -1
    for sweep in range(5):
        y[:] = x
        ldlt_solve(band, y)
        norm = 0.0
        for i in range(n):
            if free[i]:
                norm += abs(y[i])
        if sweep > 0 and norm <= estimate:
            break
        estimate = norm
        for i in range(n):
            y[i] = (1.0 if y[i] >= 0.0 else -1.0) if free[i] else 0.0
        ldlt_solve(band, y)  # z = H^-T sign(y) = H^-1 sign(y)
        j, largest, zx = -1, -1.0, 0.0
        for i in range(n):
            if free[i]:
                zx += y[i] * x[i]
                if abs(y[i]) > largest:
                    largest, j = abs(y[i]), i
        if largest <= zx or j == previous_j:
            break
        previous_j = j
        x[:] = 0.0
        x[j] = 1.0
    # Higham's extra vector catches the matrices Hager's sweeps are blind to.
    k = 0
    for i in range(n):
        y[i] = 0.0
        if free[i]:
            y[i] = (1.0 if k % 2 == 0 else -1.0) * (1.0 + k / max(count - 1, 1))
            k += 1
    ldlt_solve(band, y)
    alternative = 0.0
    for i in range(n):
        if free[i]:
            alternative += abs(y[i])
    return max(estimate, 2.0 * alternative / (3.0 * count))
