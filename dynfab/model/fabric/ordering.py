"""A nested-dissection ordering of the fabric's Hessian, and SuperLU factors with it
(docs/model.md section 10).

The Hessian's graph is two-dimensional: warp k runs along x at Y_k, weft j along y at
X_j, each a chain whose dofs couple to the dofs of the next two nodes (the bending
stencil), the two families joined at the crossings (X_j, Y_k). Every unknown therefore
has a place in the plane (`coordinates`: a warp node at (its x, Y_k), a weft node at
(X_j, its y), as woven), and a line across the patch separates it: a line x = s between
two nodes of the warps cuts each warp once and no weft, so removing the two nodes of
each warp next to it (4 n_wa dofs) splits the graph in two.

Nested dissection (George, "Nested dissection of a regular finite element mesh", SIAM J.
Numer. Anal. 10, 1973) orders such a graph by recursive bisection: split the unknowns by
a separator, order each half the same way, the separator last (`nested_dissection`).
Eliminating in that order, the fill stays inside each half until its separator, and the
dense blocks are the separators': on a two-dimensional grid of n unknowns whose
separators have O(sqrt(n)) unknowns the factor has O(n log n) nonzeros and costs
O(n^1.5) flops, the lowest possible order for such graphs (Hoffman, Martin and Rose
1973); minimum degree has no such bound. Here the separators are found from the
geometry: each part is cut at the median of its longer in-plane extent, and the
separator is the smaller of the two boundary sets (the unknowns on one side coupled to
the other), which follows the graph's actual couplings (the affine planes' end nodes,
a periodic cell's wrap) whatever they are.

The ordering depends on the sparsity pattern alone, fixed per fabric: `fabric_order`
computes it once per `assembly.Pattern` and keeps it under that pattern and under a
digest of the Hessian's sparsity, where `known_order` finds it for a caller that holds
the Hessian only (the nearest eigenvalue). `OrderedLU` factors P A P^T by SuperLU with
that fixed ordering in its symmetric mode with diagonal pivots, so that the pivots are
those of P A P^T = L D L^T (`dynfab.model.fabric.inertia`). Its fill and factor time against
SuperLU's own orderings: docs/results.md, "Woven fabric: cost".
"""

from __future__ import annotations

import hashlib
import weakref
from collections import OrderedDict

import numpy as np
import scipy.sparse
import scipy.sparse.linalg

from dynfab.linalg import pardiso
from dynfab.model.terms.kinematics import woven_plan

LEAF = 64
"""Parts of at most this many unknowns are not dissected further (natural order: along
each yarn's band); smaller leaves lower the fill little and take longer to order."""
KEPT = 8
"""Orderings kept under their sparsity digest (`known_order`), the oldest dropped first."""
_orders: OrderedDict[bytes, "Ordering"] = OrderedDict()
_by_pattern: "weakref.WeakKeyDictionary" = weakref.WeakKeyDictionary()


def coordinates(fabric, index, count: int) -> np.ndarray:
    """(x, y) [m] of each of the `count` unknowns, as woven (`woven_plan`); `index` maps dofs
    to unknowns (-1 fixed, `assembly.Pattern.index`), a tied unknown placed at its first dof."""
    d = fabric.rest_position.shape[1]
    xy = woven_plan(fabric)
    dofs = np.flatnonzero(index >= 0)
    unknowns, first = np.unique(index[dofs], return_index=True)
    out = np.zeros((count, 2))
    out[unknowns] = xy[dofs[first] // d]
    return out


def nested_dissection(A, xy, leaf: int = LEAF) -> np.ndarray:
    """The elimination order (a permutation of range(n): order[k] is the unknown
    eliminated k-th) of the symmetric pattern of A by geometric nested dissection on the
    unknowns' positions xy (n, 2) (module docstring)."""
    n = A.shape[0]
    G = scipy.sparse.csr_matrix(A, copy=True)
    G.data[:] = 1.0
    G = (G + G.T).tocsr()
    label = np.zeros(n, np.int8)
    out: list[np.ndarray] = []
    _dissect(np.arange(n), G.indptr, G.indices, np.asarray(xy, float), label, leaf, out)
    return np.concatenate(out) if out else np.zeros(0, np.int64)


def _dissect(part, indptr, indices, xy, label, leaf, out) -> None:
    """Appends the order of `part` (sorted unknowns) to out: the halves', then the separator."""
    if part.size <= leaf:
        out.append(part)
        return
    split = _bisect(part, indptr, indices, xy, label)
    if split is None:
        out.append(part)
        return
    first, second, separator = split
    _dissect(first, indptr, indices, xy, label, leaf, out)
    _dissect(second, indptr, indices, xy, label, leaf, out)
    out.append(separator)


def _bisect(part, indptr, indices, xy, label):
    """(one half, the other, the separator) of `part`, cut across its longer extent at the
    midpoint between positions nearest the median; None if every unknown sits at one point."""
    points = xy[part]
    for axis in np.argsort(np.ptp(points, axis=0))[::-1]:
        values = np.unique(points[:, axis])
        if values.size < 2:
            continue
        middles = 0.5 * (values[:-1] + values[1:])
        cut = middles[np.argmin(np.abs(middles - np.median(points[:, axis])))]
        low = points[:, axis] < cut
        left, right = part[low], part[~low]
        boundary_left = _boundary(left, right, indptr, indices, label)
        boundary_right = _boundary(right, left, indptr, indices, label)
        if boundary_left.size <= boundary_right.size:
            keep = ~np.isin(left, boundary_left, assume_unique=True)
            return left[keep], right, boundary_left
        keep = ~np.isin(right, boundary_right, assume_unique=True)
        return left, right[keep], boundary_right
    return None


def _boundary(side, other, indptr, indices, label) -> np.ndarray:
    """The unknowns of `side` coupled to one of `other` (sorted)."""
    label[other] = 1
    start, stop = indptr[side], indptr[side + 1]
    degree = stop - start
    total = int(degree.sum())
    offsets = np.repeat(start - np.cumsum(degree) + degree, degree) + np.arange(total)
    rows = np.repeat(side, degree)
    found = np.unique(rows[label[indices[offsets]] == 1])
    label[other] = 0
    return found


def digest(A) -> bytes:
    """A key of A's sparsity pattern (shape, column pointers and row indices)."""
    A = scipy.sparse.csc_matrix(A)
    h = hashlib.blake2b(digest_size=16)
    h.update(np.asarray(A.shape, np.int64).tobytes())
    for array in (A.indptr, A.indices):
        h.update(str(array.dtype).encode())
        h.update(np.ascontiguousarray(array).tobytes())
    return h.digest()


class Ordering:
    """An elimination order (`order[k]`: the unknown eliminated k-th) and the symmetric
    permutation P A P^T by it, whose gather of A's values is kept for the last sparsity
    pattern seen (the fabric's Hessians share one)."""

    def __init__(self, order):
        self.order = np.asarray(order, np.int64)
        self.inverse = np.empty_like(self.order)
        self.inverse[self.order] = np.arange(self.order.size)
        self._pattern = None  # (indptr, indices) of A; (indptr, indices, gather) of P A P^T

    def permuted(self, A) -> scipy.sparse.csc_matrix:
        """P A P^T (CSC): entry (i, j) is A[order[i], order[j]]."""
        A = scipy.sparse.csc_matrix(A)
        known = self._pattern
        if not (known is not None and np.array_equal(known[0], A.indptr)
                and np.array_equal(known[1], A.indices)):
            coo = A.tocoo()
            slots = scipy.sparse.csc_matrix(
                (np.arange(1, A.nnz + 1, dtype=float), (self.inverse[coo.row], self.inverse[coo.col])),
                shape=A.shape)  # each entry's position in A's data, 1-based (0 is no entry)
            slots.sort_indices()
            known = (A.indptr.copy(), A.indices.copy(), slots.indptr, slots.indices,
                     slots.data.astype(np.int64) - 1)
            self._pattern = known
        return scipy.sparse.csc_matrix((A.data[known[4]], known[3], known[2]), shape=A.shape)


def fabric_order(fabric, pattern) -> Ordering:
    """The nested-dissection order of the fabric's Hessian on its unknowns (`pattern`: its
    `assembly.Pattern`, whose every entry counts, whatever its value), computed once per
    pattern and kept (`known_order` finds it from a Hessian alone)."""
    found = _by_pattern.get(pattern)
    if found is not None:
        return found
    A = pattern.counts()
    key = digest(A)
    if key not in _orders:
        _orders[key] = Ordering(nested_dissection(
            A, coordinates(fabric, pattern.index, A.shape[0])))
        while len(_orders) > KEPT:
            _orders.popitem(last=False)
    _by_pattern[pattern] = _orders[key]
    return _orders[key]


def known_order(A) -> Ordering | None:
    """The order `fabric_order` computed for A's sparsity pattern, or None."""
    return _orders.get(digest(A))


class OrderedLU:
    """SuperLU's factors of P A P^T, P from an `Ordering`, with that ordering kept
    (permc_spec "NATURAL": SuperLU only postorders the elimination tree, which leaves the
    fill as it is), in its symmetric mode with diagonal pivot threshold 0 (module
    docstring). Raises RuntimeError where SuperLU does (an exactly zero pivot with no other
    row)."""

    def __init__(self, A, ordering: Ordering):
        self.order = ordering.order
        self.lu = scipy.sparse.linalg.splu(ordering.permuted(A), permc_spec="NATURAL",
                                           diag_pivot_thresh=0.0,
                                           options=dict(SymmetricMode=True))

    def solve(self, rhs) -> np.ndarray:
        """A^-1 rhs."""
        out = np.empty(np.shape(rhs))
        out[self.order] = self.lu.solve(np.asarray(rhs, float)[self.order])
        return out

    @property
    def diagonal_pivots(self) -> bool:
        """Every pivot taken on the diagonal (SuperLU's row and column permutations equal)."""
        return bool(np.array_equal(self.lu.perm_r, self.lu.perm_c))

    @property
    def elimination(self) -> np.ndarray:
        """The unknowns of A in the order SuperLU eliminated them."""
        return self.order[np.argsort(self.lu.perm_c)]

    @property
    def fill(self) -> int:
        """nnz(L) + nnz(U)."""
        return int(self.lu.L.nnz + self.lu.U.nnz)


def symmetric_factor(A, ordering: Ordering, kept=None):
    """Factors of the symmetric A, with a `solve`: PARDISO's L D L^T
    (`pardiso.SymmetricFactor`, on `kept`'s analysis where A has its pattern) where MKL is
    available, A has at least `pardiso.MIN_UNKNOWNS` unknowns, no pivot was perturbed and
    none is tiny (`SymmetricFactor.tiny_pivots`), else SuperLU's in `ordering`
    (`OrderedLU`). Raises RuntimeError where SuperLU does (an exactly zero pivot with no
    other row)."""
    if pardiso.takes(A.shape[0]):
        try:
            if kept is None or not kept.refactor(A):
                kept = pardiso.SymmetricFactor(A)
            if kept.perturbed == 0 and not kept.tiny_pivots:
                return kept
        except RuntimeError:
            pass
    return OrderedLU(A, ordering)
