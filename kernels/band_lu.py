"""Banded matrices of a run of dofs in flat storage, and their LU factorisation, inside a kernel
(the Warp twin of `dynfab.linalg.banded`; docs/model.md section 5).

A matrix over all dofs stores row i as band[i, j - i + w] = A_ij, shape (dofs, 2 w + 1), dofs
dim node + coordinate, half-bandwidth w = `bandwidth(dim)` = 3 dim - 1 (a node's dofs and the
three-node bending stencil: 5 in the plane, `BANDWIDTH`, 8 in space). A chain's dofs are
contiguous (lo..hi-1), so each chain's block is factored and solved on its own: Doolittle's LU without pivoting, O(N BANDWIDTH^2),
stable for the symmetric positive definite matrices the semi-implicit integrator builds; the
first pivot that is not positive is reported. Entries linking dofs of different chains are
never stored here (the caller keeps them zero).
"""

import functools
from types import SimpleNamespace

import warp as wp

from dynfab.linalg.banded import BANDWIDTH


def bandwidth(dim: int) -> int:
    """The half-bandwidth of a chain's band with `dim` coordinates per node (module
    docstring)."""
    return 3 * dim - 1


assert bandwidth(2) == BANDWIDTH


@functools.cache
def functions(scalar, dim: int = 2) -> SimpleNamespace:
    """The band `wp.func`s for one scalar type and `dim` coordinates per node."""
    mat = wp.types.matrix((dim, dim), scalar)
    BANDWIDTH = bandwidth(dim)  # noqa: N806 (the module's constant, for this dim)

    @wp.func(inline=True)
    def add_block(band: wp.array2d(dtype=scalar), node_p: int, node_q: int, block: mat):
        """A[(p's dim dofs), (q's dim dofs)] += block."""
        for c in range(dim):
            for d in range(dim):
                band[dim * node_p + c, dim * (node_q - node_p) + d - c + BANDWIDTH] += \
                    block[c, d]

    @wp.func(inline=True)
    def add_pair(band: wp.array2d(dtype=scalar), start: int, end: int, block: mat):
        """block on (start, start) and (end, end), -block on (start, end) and (end, start)."""
        add_block(band, start, start, block)
        add_block(band, end, end, block)
        add_block(band, start, end, -block)
        add_block(band, end, start, -block)

    @wp.func(inline=True)
    def clear(band: wp.array2d(dtype=scalar), lo: int, hi: int):
        """Rows lo..hi-1 = 0."""
        for row in range(lo, hi):
            for k in range(2 * BANDWIDTH + 1):
                band[row, k] = scalar(0.0)

    @wp.func(inline=True)
    def row_product(band: wp.array2d(dtype=scalar), row: int, lo: int, hi: int,
                    x: wp.array(dtype=scalar)) -> scalar:
        """sum_j A[row, j] x_j over the band within dofs lo..hi-1."""
        total = scalar(0.0)
        for j in range(wp.max(lo, row - BANDWIDTH), wp.min(hi, row + BANDWIDTH + 1)):
            total += band[row, j - row + BANDWIDTH] * x[j]
        return total

    @wp.func(inline=True)
    def absolute_row_sum(band: wp.array2d(dtype=scalar), row: int) -> scalar:
        """sum_j |A[row, j]| [N/m]."""
        total = scalar(0.0)
        for k in range(2 * BANDWIDTH + 1):
            total += wp.abs(band[row, k])
        return total

    @wp.func(inline=True)
    def constrain(band: wp.array2d(dtype=scalar), lo: int, hi: int, i: int):
        """Row and column i (dofs lo..hi-1) replaced by the identity's."""
        for j in range(wp.max(lo, i - BANDWIDTH), wp.min(hi, i + BANDWIDTH + 1)):
            band[i, j - i + BANDWIDTH] = scalar(0.0)
            band[j, i - j + BANDWIDTH] = scalar(0.0)
        band[i, BANDWIDTH] = scalar(1.0)

    @wp.func(inline=True)
    def factor(band: wp.array2d(dtype=scalar), lo: int, hi: int) -> int:
        """A = L U in place over dofs lo..hi-1; the first pivot that is not positive, or -1."""
        failed = int(-1)
        for k in range(lo, hi):
            pivot = band[k, BANDWIDTH]
            if not pivot > scalar(0.0):
                failed = k
                break
            for i in range(k + 1, wp.min(hi, k + BANDWIDTH + 1)):
                multiplier = band[i, k - i + BANDWIDTH] / pivot
                band[i, k - i + BANDWIDTH] = multiplier
                if multiplier != scalar(0.0):
                    for j in range(k + 1, wp.min(hi, k + BANDWIDTH + 1)):
                        band[i, j - i + BANDWIDTH] = band[i, j - i + BANDWIDTH] \
                            - multiplier * band[k, j - k + BANDWIDTH]
        return failed

    @wp.func(inline=True)
    def solve(band: wp.array2d(dtype=scalar), lo: int, hi: int, rhs: wp.array(dtype=scalar)):
        """rhs[lo:hi] = A^-1 rhs[lo:hi] with the factors of `factor`."""
        solve_into(band, lo, hi, rhs, rhs)

    @wp.func(inline=True)
    def solve_into(band: wp.array2d(dtype=scalar), lo: int, hi: int, rhs: wp.array(dtype=scalar),
                   out: wp.array(dtype=scalar)):
        """out[lo:hi] = A^-1 rhs[lo:hi] with the factors of `factor` (rhs unchanged unless it
        is out)."""
        for i in range(lo, hi):
            total = rhs[i]
            for j in range(wp.max(lo, i - BANDWIDTH), i):
                total -= band[i, j - i + BANDWIDTH] * out[j]
            out[i] = total
        for step in range(hi - lo):
            i = hi - 1 - step
            total = out[i]
            for j in range(i + 1, wp.min(hi, i + BANDWIDTH + 1)):
                total -= band[i, j - i + BANDWIDTH] * out[j]
            out[i] = total / band[i, BANDWIDTH]

    return SimpleNamespace(add_block=add_block, add_pair=add_pair, clear=clear,
                           row_product=row_product, absolute_row_sum=absolute_row_sum,
                           constrain=constrain, factor=factor, solve=solve, solve_into=solve_into)
