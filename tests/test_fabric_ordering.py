"""The nested-dissection ordering of the fabric's Hessian (`dynfab.model.fabric.ordering`) and the
factorisations that use it (docs/model.md sections 6, 10).

- The order is a permutation of the unknowns (clamped with fixed and affine planes, the
  periodic cell with its tied cell lengths and wrap springs).
- A solve with it equals the dense solve to rounding: within the forward-error bound
  cond(A) x the backward error of the factorisation.
- The inertia from its pivots equals the dense spectrum's count: a converged friction
  step shifted across its spectrum, and a compressed patch at a saddle (indefinite).
- The fill of the ordered factor grows like n log n, not faster, over patch sizes
  (nested dissection's bound on a two-dimensional graph, George 1973); minimum degree's
  fill on the same patterns does grow faster (the test can fail).
- The nearest eigenvalue through the ordered shift-invert equals the dense one.
"""

import numpy as np
import pytest
import scipy.sparse
import scipy.sparse.linalg

from dynfab.model.fabric import inertia, ordering

from dynfab.linalg import pardiso
from dynfab.model.fabric.model import FabricModel
from dynfab.solvers.newton_sparse import _sparse_solve
from dynfab.solvers.static import StaticSolver
from dynfab.reports.fabric_data import paper_patch_scene
from dynfab.model.loading import prescribe_ends
from test_fabric_periodic import cell
from test_fabric_static import FRICTION, patch_model

EPS = np.finfo(float).eps


def friction_step(**more):
    """A converged friction load step of the small test fabric: (solver, H, order)."""
    solver = StaticSolver(patch_model("force", (0.2,), FRICTION, weft_values=(0.05,),
                                            **more))
    state, records = solver.run()
    limit = records[-1]["friction_limit"].ravel()
    H = solver.backend.hessian(state.positions, state.anchors, limit)
    return solver, H, ordering.fabric_order(solver.model.structure, solver.backend.pattern)


def compressed_saddle():
    """Warps pushed in with the wefts free: Newton's equilibrium on the symmetric path is a
    saddle (negative eigenvalues by the dense spectrum, checked where used)."""
    solver = StaticSolver(patch_model("displacement", (-3e-4,), None))
    state = solver.initial_state()
    pos, anchors = state.positions.copy(), state.anchors.copy()
    prescribe_ends(solver.model.structure, pos, solver.model.yarn_loads(-3e-4, 0.0))
    info, limit = solver.backend.equilibrium(pos, np.zeros(solver.model.yarns), anchors)
    assert info.converged
    H = solver.backend.hessian(pos, anchors, limit)
    return solver, H, ordering.fabric_order(solver.model.structure, solver.backend.pattern)


def as_woven_hessian(solver):
    state = solver.initial_state()
    return solver.backend.hessian(state.positions, state.anchors, np.zeros(solver.model.structure.tie_a.size))


@pytest.mark.parametrize("case", ["fixed", "affine", "periodic"])
def test_the_order_is_a_permutation_of_the_unknowns(case):
    if case == "periodic":  # tied cell lengths, wrap springs, moving planes
        solver = cell(2, 4, "force", FRICTION)
    else:
        solver = StaticSolver(patch_model("force", (0.2,), FRICTION, planes=case))
    H = as_woven_hessian(solver)
    order = ordering.fabric_order(solver.model.structure, solver.backend.pattern)
    assert order.order.dtype.kind == "i"
    assert np.array_equal(np.sort(order.order), np.arange(solver.backend.pattern.free_count))
    # computed once per pattern: found again from the Hessian of another state
    state, _ = solver.step(solver.initial_state(), (0.1, 0.05) if case == "periodic" else (0.2, 0.05))
    again = solver.backend.hessian(state.positions, state.anchors, np.zeros(solver.model.structure.tie_a.size))
    assert ordering.known_order(again) is order
    assert ordering.fabric_order(solver.model.structure, solver.backend.pattern) is order


def backward_error_bound(A, lu):
    """cond_2(A) times the backward error of the LU solve, bounded by m eps || |L| |U| || /
    ||A|| (m the largest number of terms in one inner product of the factorisation, the
    longest row of L or column of U; Higham, Accuracy and Stability, Thm 9.3 in norm form),
    doubled for the dense solve it is compared with (itself within cond eps)."""
    dense = A.toarray()
    values = np.abs(np.linalg.eigvalsh(dense))
    cond = values.max() / values.min()
    L, U = abs(lu.L), abs(lu.U)
    m = max(np.diff(lu.L.tocsr().indptr).max(), np.diff(lu.U.tocsc().indptr).max())
    growth = scipy.sparse.linalg.norm(L @ U, np.inf) / np.abs(dense).sum(axis=1).max()
    return 2.0 * cond * m * EPS * max(growth, 1.0)


@pytest.mark.parametrize("case", ["friction", "saddle"])
def test_solves_equal_the_dense_solve_to_rounding(case):
    solver, H, order = friction_step() if case == "friction" else compressed_saddle()
    A = (0.5 * (H + H.T)).tocsc()
    rhs = np.random.default_rng(5).standard_normal(A.shape[0])
    factor = ordering.OrderedLU(A, order)
    assert factor.diagonal_pivots
    x = factor.solve(rhs)
    expected = np.linalg.solve(A.toarray(), rhs)
    error = np.abs(x - expected).max() / np.abs(expected).max()
    assert error <= backward_error_bound(order.permuted(A), factor.lu)


@pytest.mark.parametrize("case", ["friction", "saddle"])
def test_the_newton_solve_is_backward_stable(case, factoriser):
    # The Newton direction's solve (`_sparse_solve` with the order) is
    # `ordering.symmetric_factor`'s: SuperLU's above, or PARDISO's L D L^T. Either is
    # backward stable: the normwise backward error |A x - b| / (|A| |x| + |b|) (Rigal and
    # Gaches 1967) within gamma_n = n eps / (1 - n eps), the first-order bound of a
    # factorisation without element growth (Higham, Accuracy and Stability, Thm 7.1, 9.4).
    solver, H, order = friction_step() if case == "friction" else compressed_saddle()
    A = (0.5 * (H + H.T)).tocsc()
    rhs = np.random.default_rng(5).standard_normal(A.shape[0])
    factor = ordering.symmetric_factor(A, order)
    assert (type(factor).__name__ == "SymmetricFactor") == (factoriser == "pardiso")
    x = _sparse_solve(A, rhs, order=order)
    assert np.array_equal(x, factor.solve(rhs))
    n = A.shape[0]
    norm_A = scipy.sparse.linalg.norm(A, np.inf)
    backward = np.abs(A @ x - rhs).max() / (norm_A * np.abs(x).max() + np.abs(rhs).max())
    assert backward <= n * EPS / (1.0 - n * EPS)


def dense_count(H, shift):
    """Eigenvalues of the symmetrised dense H below -shift, and the gap of -shift to the
    nearest one (the count is meaningful while the gap is far above eps ||H||)."""
    values = np.linalg.eigvalsh(0.5 * (H + H.T))
    return int(np.count_nonzero(values < -shift)), float(np.abs(values + shift).min())


def test_inertia_across_the_spectrum_equals_the_dense_count():
    # Sylvester on P A P^T = L D L^T in the dissection order: the negative pivots are the
    # eigenvalues below -shift; shifts halfway between consecutive eigenvalues, where they
    # are apart (gap far above eps ||H||: identical yarns share eigenvalues), at counts
    # spread over the spectrum.
    solver, H, order = friction_step(planes="affine")
    values = np.linalg.eigvalsh(0.5 * (H + H.T).toarray())
    scale = float(np.abs(H.diagonal()).max())
    n = values.size
    apart = 1 + np.flatnonzero(np.diff(values) > 1e6 * EPS * np.abs(values).max())
    counts = {0, n} | {int(apart[np.argmin(np.abs(apart - m))]) for m in (1, 7, 40, n // 2, n - 2)}
    for m in sorted(counts):
        if m == 0:
            shift = -0.5 * values[0]
        elif m == n:
            shift = -2.0 * values[-1]
        else:
            shift = -0.5 * (values[m - 1] + values[m])
        result = inertia.sparse_inertia(H, shift, scale, order)
        assert result is not None and result.negatives == m


def test_inertia_of_a_compressed_saddle_equals_the_dense_count():
    solver, H, order = compressed_saddle()
    count, gap = dense_count(H.toarray(), 0.0)
    scale = float(np.abs(H.diagonal()).max())
    assert count > 0 and gap > 1e6 * EPS * scale
    result = inertia.sparse_inertia(H, 0.0, scale, order)
    assert result is not None and result.negatives == count


def test_the_nearest_eigenvalue_through_the_ordered_inverse_equals_the_dense_one():
    # ARPACK's relative tolerance EIGEN_TOL on the eigenvalue of the inverse, 1 / lambda:
    # the same relative accuracy on lambda (a few times it for rounding).
    for solver, H, order in (friction_step(), compressed_saddle()):
        values = np.linalg.eigvalsh(0.5 * (H + H.T).toarray())
        nearest = values[np.argmin(np.abs(values))]
        got = inertia.nearest_eigenvalue(H, order)
        assert got == pytest.approx(nearest, rel=10 * inertia.EIGEN_TOL)
        assert inertia.nearest_eigenvalue(H) == got  # the order found from H's pattern


def structural_matrix(H):
    """A matrix with H's sparsity pattern and no zero or cancelling value: -1 off the
    diagonal, the degree + 1 on it (a diagonally dominant M-matrix, so SPD and factored
    without pivoting). SuperLU drops entries that come out exactly zero (a contact block
    out of contact), so the Hessian's own fill depends on the state; this one's is the
    pattern's."""
    A = scipy.sparse.csc_matrix(H, copy=True)
    A.data[:] = -1.0
    A.setdiag(0.0)
    A.eliminate_zeros()
    degree = -np.asarray(A.sum(axis=0)).ravel()
    return (A + scipy.sparse.diags(degree + 1.0)).tocsc()


SIZES = (4, 8, 16, 32)
"""n x n patches of the benchmark (8 segments per half-wave): 504 to 32,704 unknowns."""


def fills(order_of):
    """(unknowns, nnz(L + U)) on each patch of SIZES, the factor of `structural_matrix` in
    the order `order_of(solver, A)` gives (None: SuperLU's minimum degree on A^T + A)."""
    out = []
    for n in SIZES:
        solver = StaticSolver(FabricModel.from_scene(paper_patch_scene(
            n, n, 8, load={"control": "force", "values": [0.0]})))
        state = solver.initial_state()
        A = structural_matrix(solver.backend.hessian(state.positions, state.anchors,
                                             np.zeros(n * n)))
        order = order_of(solver, A)
        if order is None:
            lu = scipy.sparse.linalg.splu(A, permc_spec="MMD_AT_PLUS_A", diag_pivot_thresh=0.0,
                                          options=dict(SymmetricMode=True))
            out.append((A.shape[0], lu.L.nnz + lu.U.nnz))
        else:
            out.append((A.shape[0], ordering.OrderedLU(A, order).fill))
    return np.array(out, float)


def growth_increments(table):
    """g_k = F(n_k+1) / n_k+1 - F(n_k) / n_k over consecutive patches (n_k+1 = 4 n_k).

    The bound: nested dissection on a two-dimensional graph whose separators hold
    O(sqrt(m)) of a part's m unknowns (here a line across the part cuts each yarn of one
    family once, 4 dofs per yarn: sqrt(m / 2) of a square part's m = 32 s^2 dofs, s yarn
    pitches a side) fills each part's separator block and its border with the enclosing
    separators, O(m) per part, so O(n) per level of the dissection and
    F(n) = a n log2 n + b n + o(n) over its log2 n levels. Then F(4n) / 4n - F(n) / n
    = 2 a: the increment is constant across sizes. Fill growing as c n^1.5 (the band of a
    natural order, or minimum degree on a grid) gives F / n = c sqrt(n), an increment
    c sqrt(n) that doubles from one size to the next."""
    per_unknown = table[:, 1] / table[:, 0]
    return np.diff(per_unknown)


def test_the_ordered_fill_grows_like_n_log_n():
    # Constant increments (n log n) against doubling ones (n^1.5): each increment at most
    # sqrt(2) times the one before, the geometric midpoint of the two hypotheses' ratios.
    dissection = growth_increments(fills(
        lambda solver, A: ordering.fabric_order(solver.model.structure, solver.backend.pattern)))
    assert np.all(dissection > 0.0)
    assert np.all(dissection[1:] <= np.sqrt(2.0) * dissection[:-1]), dissection
    # the test can fail: minimum degree's fill on the same patterns grows faster
    minimum_degree = growth_increments(fills(lambda solver, A: None))
    assert np.any(minimum_degree[1:] > np.sqrt(2.0) * minimum_degree[:-1]), minimum_degree


def test_a_matrix_below_pardiso_s_size_is_factored_by_superlu():
    # Below pardiso.MIN_UNKNOWNS PARDISO's fixed costs outweigh its speed (its docstring's
    # measurements), so SuperLU factors there whether MKL is installed or not.
    solver, H, order = friction_step()
    A = (0.5 * (H + H.T)).tocsc()
    assert A.shape[0] < pardiso.MIN_UNKNOWNS
    assert isinstance(ordering.symmetric_factor(A, order), ordering.OrderedLU)
