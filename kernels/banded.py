"""Banded matrices of one yarn inside a kernel (Warp twin of `dynfab.banded`).

A batch of yarns stores its matrices as `band[y, i, j - i + BANDWIDTH] = A_y[i, j]`,
shape (yarns, 2 (N+1), 2 BANDWIDTH + 1), dofs interleaved per node (2 i = x_i,
2 i + 1 = z_i), half-bandwidth 5 (the three-node bending stencil). The LU
factorisation is Doolittle's without pivoting, O(N BANDWIDTH^2), as in
`dynfab.banded`: stable for the positive definite matrices the semi-implicit
integrator builds, and a pivot that is not positive is reported.
"""

import functools
from types import SimpleNamespace

import warp as wp

from dynfab.banded import BANDWIDTH


@functools.cache
def functions(scalar) -> SimpleNamespace:
    """The banded-matrix `wp.func`s for one scalar type."""
    mat = wp.types.matrix((2, 2), scalar)

    @wp.func
    def add(band: wp.array3d(dtype=scalar), y: int, i: int, j: int, value: scalar):
        """A_y[i, j] += value."""
        band[y, i, j - i + BANDWIDTH] += value

    @wp.func
    def add_block(band: wp.array3d(dtype=scalar), y: int, node_p: int, node_q: int, block: mat):
        """Add the 2x2 block coupling node p's (x, z) rows to node q's columns."""
        for c in range(2):
            for d in range(2):
                band[y, 2 * node_p + c, 2 * (node_q - node_p) + d - c + BANDWIDTH] += block[c, d]

    @wp.func
    def clear(band: wp.array3d(dtype=scalar), y: int):
        """A_y = 0."""
        for i in range(band.shape[1]):
            for k in range(2 * BANDWIDTH + 1):
                band[y, i, k] = scalar(0.0)

    @wp.func
    def absolute_row_sum(band: wp.array3d(dtype=scalar), y: int, i: int) -> scalar:
        """sum_j |A_y[i, j]|: the Gershgorin radius plus |A_ii| of row i."""
        total = scalar(0.0)
        for k in range(2 * BANDWIDTH + 1):
            total += wp.abs(band[y, i, k])
        return total

    @wp.func
    def constrain(band: wp.array3d(dtype=scalar), y: int, i: int, rhs: wp.array2d(dtype=scalar)):
        """Replace row and column i by the identity and rhs_i by 0 (a fixed dof)."""
        n = band.shape[1]
        for j in range(wp.max(0, i - BANDWIDTH), wp.min(n, i + BANDWIDTH + 1)):
            band[y, i, j - i + BANDWIDTH] = scalar(0.0)
            band[y, j, i - j + BANDWIDTH] = scalar(0.0)
        band[y, i, BANDWIDTH] = scalar(1.0)
        rhs[y, i] = scalar(0.0)

    @wp.func
    def lu_factor(band: wp.array3d(dtype=scalar), y: int) -> int:
        """Factor A_y = L U in place; the first pivot that is not positive, or -1 if none."""
        n = band.shape[1]
        failed = int(-1)
        for k in range(n):
            pivot = band[y, k, BANDWIDTH]
            if not pivot > scalar(0.0):
                failed = k
                break
            for i in range(k + 1, wp.min(n, k + BANDWIDTH + 1)):
                factor = band[y, i, k - i + BANDWIDTH] / pivot
                band[y, i, k - i + BANDWIDTH] = factor
                if factor != scalar(0.0):
                    for j in range(k + 1, wp.min(n, k + BANDWIDTH + 1)):
                        band[y, i, j - i + BANDWIDTH] = band[y, i, j - i + BANDWIDTH] \
                            - factor * band[y, k, j - k + BANDWIDTH]
        return failed

    @wp.func
    def lu_solve(band: wp.array3d(dtype=scalar), y: int, rhs: wp.array2d(dtype=scalar)):
        """Solve A_y x = rhs_y in place with the factors of `lu_factor`."""
        n = band.shape[1]
        for i in range(n):
            total = rhs[y, i]
            for j in range(wp.max(0, i - BANDWIDTH), i):
                total -= band[y, i, j - i + BANDWIDTH] * rhs[y, j]
            rhs[y, i] = total
        for step in range(n):
            i = n - 1 - step
            total = rhs[y, i]
            for j in range(i + 1, wp.min(n, i + BANDWIDTH + 1)):
                total -= band[y, i, j - i + BANDWIDTH] * rhs[y, j]
            rhs[y, i] = total / band[y, i, BANDWIDTH]

    return SimpleNamespace(add=add, add_block=add_block, clear=clear,
                           absolute_row_sum=absolute_row_sum,
                           constrain=constrain, lu_factor=lu_factor, lu_solve=lu_solve)
