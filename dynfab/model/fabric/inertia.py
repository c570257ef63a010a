"""The fabric's inertia count and eigen-solves: the sparse route of the step certificate
(`dynfab.solvers.certificate.certify_patch`, docs/model.md sections 6, 10).

First route (`sparse_inertia`): with the pattern's order, the Newton solve's factorisation
(`ordering.symmetric_factor`). Where MKL is installed (and A has at least 1,000 unknowns)
that is PARDISO's L D L^T, whose D (1 x 1 and 2 x 2 Bunch-Kaufman blocks) has A's inertia by
Sylvester's law; it is refused where PARDISO perturbed a pivot or one of D's is within
64 eps max|A_ii| of zero (`dynfab.linalg.pardiso`), and SuperLU counts instead. SuperLU in
symmetric mode (the pattern's nested-dissection order, `dynfab.model.fabric.ordering`, or without
one SuperLU's minimum degree on A^T + A; diagonal pivot threshold 0) factors P A P^T = L U of the
symmetrised A = (H + H^T)/2 + tau I. When it took every pivot on the diagonal
(perm_r == perm_c), the factorisation is unpivoted Gaussian elimination of the symmetric
P A P^T, so U = D L^T with D = diag(U) (uniqueness of LDU), and P A P^T = L D L^T is a
congruence: by Sylvester's law the negatives of A are the negative pivots diag(U). Guards,
each sending the count to the second route: SuperLU failing, an off-diagonal pivot, a pivot
within 64 eps max|H_ii| of zero (the threshold the banded LDL^T below uses), or element
growth (max |L_ij| or max |U_ij| / max|H_ii| above GROWTH: unpivoted elimination of an
indefinite matrix is backward stable only while its factors stay bounded). Its cost is the
Newton solve's factorisation, so it scales like a Newton iteration
(docs/results.md, "Woven fabric: cost").

Second route, the reference and fallback: library sparse factorisations that pivot
off the diagonal give no inertia. It comes from Haynsworth's inertia additivity: split the free dofs into the crossing
dofs K (both coordinates of every crossing's warp and weft node) and the rest I. The
crossing couplings (contact and friction blocks) only join dofs of K, so H_II is block
diagonal, one band per yarn (that yarn's band with its crossing and fixed dofs replaced
by identity rows), and

    In(H) = In(H_II) + In(S),   S = H_KK - H_KI H_II^-1 H_IK

(Haynsworth 1968). In(H_II) is counted from each yarn's unpivoted banded LDL^T
(`dynfab.linalg.ldlt`, Sylvester's law: the negative pivots), O(n) per yarn; S is dense,
|K| = 4 C, assembled from one banded solve per crossing dof and counted by its
Bunch-Kaufman LDL^T (`dense_negatives`). A pivot within rounding of zero makes H_II unusable: the matrix is then
shifted by tau I at the rounding level (docs/model.md section 6), and "no negative" proves
lambda_min(H) > -tau.

The matrix is the symmetric Hessian with F_T frozen (the softer branch at kinks, as
`dynfab.model.fabric.contact` and `friction` give it); instabilities from friction's
non-associated coupling are not seen (docs/model.md section 6).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.linalg
import scipy.sparse.linalg

from dynfab.linalg.banded import BANDWIDTH, constrain
from dynfab.errors import SolverError
from dynfab.model.fabric import assembly, ordering
from dynfab.linalg import pardiso
from dynfab.linalg.ldlt import TINY_PIVOT, ldlt_factor, ldlt_solve

EPS = np.finfo(np.float64).eps
EIGEN_TOL = 1e-10
"""ARPACK's relative tolerance on the eigenvalues (`nearest_eigenvalue`, `lowest_eigenvectors`)."""
DENSE_LIMIT = 6000
"""Most unknowns the dense count takes (`_dense_inertia`: n^2 doubles, 288 MB at 6,000, and
LAPACK's O(n^3) factorisation): a periodic cell or a small specimen. A larger Hessian whose
sparse factorisations all fail stops the step (`inertia`) rather than fill the memory."""
GROWTH = 1e4
"""Largest max |L_ij| and max |U_ij| / max|H_ii| the sparse route accepts (a positive definite
matrix's |U_ij| stay within max|H_ii|, and on the benchmark's patches its |L_ij| far below
GROWTH, in either ordering)."""


@dataclass
class Inertia:
    negatives: int
    """Negative eigenvalues of the Hessian on the free dofs (with the shift)."""
    shift: float
    """The shift tau [N/m] applied (0 unless a pivot vanished, or as asked)."""
    schur_size: int
    """|K|, the dense Schur complement's order (0 when the sparse route counted)."""
    method: str = "schur"
    """"pardiso" or "superlu" (the sparse route), "schur" (Haynsworth) or "dense" (the
    periodic cell)."""


def nearest_eigenvalue(H, order=None) -> float:
    """The eigenvalue of the sparse symmetric H nearest zero [N/m] (ARPACK shift-invert at
    0, relative accuracy about EIGEN_TOL): the lowest one when the inertia has no negative
    (docs/model.md section 6's estimate of the smallest eigenvalue); NaN if ARPACK fails.
    The inverse is `shift_inverse`'s, in `order` or the one `ordering.fabric_order` computed
    for H's pattern."""
    order = ordering.known_order(H) if order is None else order
    try:
        value = scipy.sparse.linalg.eigsh(H, k=1, sigma=0.0, which="LM", tol=EIGEN_TOL,
                                          OPinv=shift_inverse(H, 0.0, order),
                                          v0=start_vector(H.shape[0]),
                                          return_eigenvectors=False)
    except (RuntimeError, scipy.sparse.linalg.ArpackNoConvergence):
        return float("nan")
    return float(value[0])


def shift_inverse(H, sigma, order=None):
    """(H - sigma I)^-1 as a LinearOperator for ARPACK's shift-invert mode, or None (ARPACK
    then factors H - sigma I itself, with SuperLU's default column ordering and partial
    pivoting): `shifted_solve`'s."""
    solve = shifted_solve(H, sigma, order)
    if solve is None:
        return None
    return scipy.sparse.linalg.LinearOperator(H.shape, matvec=solve, dtype=float)


def shifted_solve(H, sigma, order=None):
    """The solve x = A^-1 b of A = (H + H^T)/2 - sigma I, or None (singular): `_guarded`'s
    factors, else SuperLU with partial pivoting."""
    A = (0.5 * (H + H.T) - sigma * scipy.sparse.identity(H.shape[0])).tocsc()
    scale = float(np.abs(H.diagonal()).max()) if H.shape[0] else 0.0
    guarded = _guarded(A, scale, order)
    if guarded is not None:
        return guarded[1]
    try:
        return scipy.sparse.linalg.splu(A).solve
    except RuntimeError:
        return None


def start_vector(n: int) -> np.ndarray:
    """ARPACK's start vector, fixed (seeded), so that the vectors found in a degenerate
    eigenspace (identical yarns share eigenvalues), and the escape they lead to, are the
    same from run to run; ARPACK's own start is random."""
    return np.random.default_rng(20070101).standard_normal(n)


def lowest_eigenvectors(model, pos, anchors, limit, count: int, nearest: float):
    """The `count` lowest eigenpairs of the Hessian on the unknowns and a proved lower bound
    of its eigenvalues, (values, vectors, bound [N/m]).

    Shift-invert Lanczos at a shift sigma below the whole spectrum, found by the inertia:
    sigma = 2 nearest (the eigenvalue nearest zero), doubled until H - sigma I has no
    negative eigenvalue, which proves lambda_min >= bound = sigma (less the rounding-level
    shift the count needed; -inf if 60 doublings found none); the `count` eigenvalues
    nearest such a sigma are the lowest.
    Each vector's sign is fixed (its largest component positive) and the start vector too
    (`start_vector`), so the choice is deterministic. `model` is the fabric's
    (`dynfab.model.fabric.model.FabricModel`: its structure, Hessian and pattern).
    """
    sigma, bound = 2.0 * min(nearest, -1e-12), -np.inf
    for _ in range(60):
        counted = inertia(model, pos, anchors, limit, shift=-sigma)
        if counted.negatives == 0:
            bound = -counted.shift
            break
        sigma *= 2.0
    H = model.hessian(pos, anchors, limit)
    dissection = ordering.fabric_order(model.structure, model.pattern)
    values, vectors = scipy.sparse.linalg.eigsh(H, k=count, sigma=sigma, which="LM", tol=EIGEN_TOL,
                                                OPinv=shift_inverse(H, sigma, dissection),
                                                v0=start_vector(H.shape[0]))
    order = np.argsort(values)
    values, vectors = values[order], vectors[:, order]
    for k in range(count):
        if vectors[np.argmax(np.abs(vectors[:, k])), k] < 0:
            vectors[:, k] *= -1.0
    return values, vectors, bound


def crossing_mask(fabric) -> np.ndarray:
    """True on the crossing dofs K (2 nodes,): both dofs of every crossing's two nodes, and
    the end nodes' in-plane dofs that move the planes (planes "affine")."""
    mask = np.zeros(fabric.fixed.size, np.bool_)
    for node in (fabric.tie_a, fabric.tie_b[fabric.tie_b >= 0]):
        mask[2 * node] = mask[2 * node + 1] = True
    mask[2 * fabric.plane_nodes_a] = mask[2 * fabric.plane_nodes_b] = True
    return mask


def inertia(model, pos, anchors, limit, shift: float = 0.0) -> Inertia:
    """In(H - (-shift) I) on the free dofs: the negatives of H + shift I (module docstring):
    the sparse route in the pattern's nested-dissection order (`ordering.fabric_order`), else
    the Schur (or, for the periodic cell, dense) route, at the shift asked and then at two
    rounding-level shifts above it. `model` is the fabric's
    (`dynfab.model.fabric.model.FabricModel`: its structure, Hessian and pattern)."""
    fabric = model.structure
    H = model.hessian(pos, anchors, limit)
    scale = float(np.abs(H.diagonal()).max())
    order = ordering.fabric_order(fabric, model.pattern)
    for tau in (shift, shift + 1e3 * EPS * scale, shift + 1e6 * EPS * scale):
        result = sparse_inertia(H, tau, scale, order)
        if result is None:
            # the Schur route knows the planar fabric's blocks; the periodic cell and the
            # spatial fabric (docs/model.md section 11) count densely
            dense = fabric.wrap_stiffness.any() or fabric.rest_position.shape[1] == 3
            result = (_dense_inertia(H, tau, scale) if dense else
                      _inertia(fabric, pos, anchors, limit, tau, scale))
        if result is not None:
            return result
    raise SolverError(f"the stability check could not count the negative eigenvalues of the "
                      f"Hessian ({H.shape[0]} unknowns): a pivot within rounding of zero "
                      f"survived the shifts up to {1e6 * EPS * scale:.3g} N/m at the step's "
                      "state (docs/model.md section 6); the state may lie outside the model "
                      "(a yarn turned past 90 degrees), see its max_slope")


def sparse_inertia(H, tau, scale, order=None):
    """Negatives of (H + H^T)/2 + tau I from `_guarded`'s factors, or None when every guard
    fails (module docstring)."""
    return sparse_factor(H, tau, scale, order)[0]


def sparse_factor(H, tau, scale, order=None):
    """(`sparse_inertia`'s count, the solve x = A^-1 b of its factors, b (n,) or (n, k)),
    A = (H + H^T)/2 + tau I; (None, None) when every guard fails."""
    A = (0.5 * (H + H.T) + tau * scipy.sparse.identity(H.shape[0])).tocsc()
    if A.shape[0] == 0:
        return Inertia(0, tau, 0, "superlu"), lambda b: np.array(b, float)
    guarded = _guarded(A, scale, order)
    if guarded is None:
        return None, None
    negatives, solve, method = guarded
    return Inertia(negatives, tau, 0, method), solve


def _guarded(A, scale, order):
    """(negatives, solve, "pardiso" or "superlu") of the symmetric A's factors that pass
    their guards, or None: with `order`, `ordering.symmetric_factor`'s (PARDISO's L D L^T,
    no pivot perturbed: its D's inertia; else SuperLU's), SuperLU's with `_unsafe`'s guards
    (the negative pivots of U)."""
    try:
        factor = None if order is None else ordering.symmetric_factor(A, order)
    except RuntimeError:
        return None
    if isinstance(factor, pardiso.SymmetricFactor):
        return factor.negatives, factor.solve, "pardiso"
    lu, solve = (factor.lu, factor.solve) if factor is not None else _symmetric_lu(A)
    if lu is None or _unsafe(lu, scale):
        return None
    return int(np.count_nonzero(lu.U.diagonal() < 0.0)), solve, "superlu"


def _symmetric_lu(A):
    """(SuperLU's symmetric-mode factors of A in its minimum degree on A^T + A; their
    solve), or (None, None) where SuperLU fails (an exactly zero pivot with no usable row)."""
    try:
        lu = scipy.sparse.linalg.splu(A, permc_spec="MMD_AT_PLUS_A", diag_pivot_thresh=0.0,
                                      options=dict(SymmetricMode=True))
        return lu, lu.solve
    except RuntimeError:
        return None, None


def _unsafe(lu, scale) -> bool:
    """A guard of the pivots fails (module docstring): an off-diagonal pivot, a pivot within
    64 eps scale of zero, a non-finite factor, or growth above GROWTH."""
    if not np.array_equal(lu.perm_r, lu.perm_c):
        return True
    U = lu.U
    pivots = U.diagonal()
    if not np.all(np.isfinite(U.data)) or np.any(np.abs(pivots) <= 64.0 * EPS * scale):
        return True
    return bool(np.abs(U.data).max() > GROWTH * scale or np.abs(lu.L.data).max() > GROWTH)


def _dense_inertia(H, tau, scale):
    """The periodic cell (its wrap springs and tied cell lengths join the ends of every
    yarn, so H is no longer a band per yarn plus crossing blocks) and the spatial fabric:
    the whole (reduced) Hessian goes to the dense Bunch-Kaufman count; None if a pivot
    block is within rounding of singular, or above DENSE_LIMIT unknowns."""
    if H.shape[0] > DENSE_LIMIT:
        return None
    D = H.toarray() + tau * np.eye(H.shape[0])
    count = dense_negatives(D, 64.0 * EPS * scale)
    return Inertia(count, tau, H.shape[0], "dense") if count >= 0 else None


def _inertia(fabric, pos, anchors, limit, tau, scale):
    fixed = fabric.fixed
    mask = crossing_mask(fabric)
    k_dofs = np.flatnonzero(mask & ~fixed)
    k_index = np.full(fixed.size, -1)
    k_index[k_dofs] = np.arange(k_dofs.size)
    S = np.zeros((k_dofs.size, k_dofs.size))
    negatives = 0
    start = fabric.chain_start
    tiny = 64.0 * EPS * scale
    for y in range(start.size - 1):
        first = 2 * start[y]
        n = 2 * (start[y + 1] - start[y])
        band = np.zeros((n, 2 * BANDWIDTH + 1))
        assembly.yarn_band(pos, fabric, y, band)
        band[:, BANDWIDTH] += tau
        local_k = np.flatnonzero(mask[first:first + n] & ~fixed[first:first + n])
        original = band.copy()
        factor = band
        constrain(factor, np.zeros(n), fixed[first:first + n] | mask[first:first + n])
        count = ldlt_factor(factor, 0.0, tiny)
        if count == TINY_PIVOT:
            return None
        negatives += count
        _add_schur_block(original, factor, local_k, k_index[first + local_k], S,
                         fixed[first:first + n] | mask[first:first + n])
    _add_crossing_blocks(fabric, pos, anchors, limit, k_index, S)
    schur = dense_negatives(S, tiny)
    if schur < 0:
        return None
    return Inertia(negatives + schur, tau, k_dofs.size)


def dense_negatives(S, tiny) -> int:
    """Negative eigenvalues of the symmetric S by Bunch-Kaufman LDL^T (LAPACK sytrf through
    scipy.linalg.ldl; S = P L D L^T P^T is a congruence, so Sylvester's law counts them in
    D's 1x1 and 2x2 blocks). -1 if a block has an eigenvalue within `tiny` of zero.
    Cheaper than the eigenvalues, which it replaces (`python benchmarks/fabric.py --pieces`)."""
    if S.size == 0:
        return 0
    _, d, _ = scipy.linalg.ldl(S, lower=True)
    negatives, i, n = 0, 0, d.shape[0]
    while i < n:
        if i + 1 < n and d[i + 1, i] != 0.0:
            values = np.linalg.eigvalsh(d[i:i + 2, i:i + 2])
            i += 2
        else:
            values = d[i:i + 1, i]
            i += 1
        if np.any(np.abs(values) <= tiny):
            return -1
        negatives += int(np.count_nonzero(values < 0.0))
    return negatives


def _add_schur_block(original, factor, local_k, global_k, S, constrained):
    """S[K_y, K_y] += H_KK(yarn band) - H_KI A^-1 H_IK for one yarn's crossing dofs."""
    n = original.shape[0]
    dense_rows = np.zeros((local_k.size, n))  # H[k, :] of the yarn band
    for r, k in enumerate(local_k):
        for j in range(max(0, k - BANDWIDTH), min(n, k + BANDWIDTH + 1)):
            dense_rows[r, j] = original[k, j - k + BANDWIDTH]
    coupling = dense_rows.copy()
    coupling[:, constrained] = 0.0  # H_KI: only the interior columns
    block = dense_rows[:, local_k]
    for r in range(local_k.size):
        x = coupling[r].copy()
        ldlt_solve(factor, x)  # A^-1 H_Ik (zero on the constrained rows)
        block[r] -= coupling @ x
    S[np.ix_(global_k, global_k)] += block


def _add_crossing_blocks(fabric, pos, anchors, limit, k_index, S):
    """The contact and Huber blocks of every crossing into S (the shift came with the
    yarn bands, which hold every crossing dof's diagonal)."""
    c = fabric.tie_a.size
    tangent, huber = np.zeros(c), np.zeros((c, 3))
    assembly.crossing_blocks(pos, fabric, anchors, limit, tangent, huber)
    za = k_index[2 * fabric.tie_a + 1]
    zb = np.where(fabric.tie_b >= 0, k_index[2 * fabric.tie_b + 1], -1)  # ground: none
    for i in range(c):
        for (p, q), value in (((za[i], za[i]), tangent[i]), ((zb[i], zb[i]), tangent[i]),
                              ((za[i], zb[i]), -tangent[i]), ((zb[i], za[i]), -tangent[i])):
            if p >= 0 and q >= 0:
                S[p, q] += value
        J = assembly.slip_jacobian(fabric, i)
        h = np.array([[huber[i, 0], huber[i, 1]], [huber[i, 1], huber[i, 2]]])
        rows = k_index[assembly.slip_dofs(fabric, i)]
        keep = rows >= 0
        S[np.ix_(rows[keep], rows[keep])] += (J.T @ h @ J)[np.ix_(keep, keep)]
