"""The fabric's inertia count by SuperLU's symmetric-mode pivots (`inertia.sparse_inertia`)
against the Haynsworth Schur route (`inertia._inertia`, the reference and fallback) and the
dense eigenvalues of the same Hessian (docs/model.md section 6), and its guards.

- A converged friction step (planes fixed and affine), shifts halfway between consecutive
  eigenvalues across the spectrum: both routes give the dense count.
- A saddle: Newton's solution of held-weft warps pushed in (the state the step's escape
  starts from, negative eigenvalues by the dense spectrum): both routes give the dense count.
- The guards: an exactly zero pivot (the shift cancelling the diagonal entry of an unknown
  SuperLU eliminates before anything coupled to it, in the nested-dissection order and in
  minimum degree) is refused, and sends `inertia` to the Schur route, which still gives the
  dense count;
  an off-diagonal pivot, a tiny pivot and element growth are refused on small matrices.
"""

import numpy as np
import pytest
import scipy.sparse
import scipy.sparse.linalg

from dynfab.model.fabric import inertia, ordering
from dynfab.solvers.static import StaticSolver
from dynfab.model.loading import prescribe_ends
from test_fabric_static import FRICTION, patch_model

EPS = np.finfo(float).eps


def dense_count(H, shift):
    """Eigenvalues of the symmetrised dense H below -shift, and the gap of -shift to the
    nearest one (the count is meaningful while the gap is far above eps ||H||)."""
    values = np.linalg.eigvalsh(0.5 * (H + H.T))
    return int(np.count_nonzero(values < -shift)), float(np.abs(values + shift).min())


def friction_step(planes):
    solver = StaticSolver(patch_model("force", (0.2,), FRICTION, weft_values=(0.05,),
                                            planes=planes))
    state, records = solver.run()
    limit = records[-1]["friction_limit"].ravel()
    return solver, state.positions, solver.initial_state().anchors, limit


def both_routes(solver, pos, anchors, limit, shift):
    H = solver.backend.hessian(pos, anchors, limit)
    scale = float(np.abs(H.diagonal()).max())
    sparse = inertia.sparse_inertia(H, shift, scale)
    schur = inertia._inertia(solver.model.structure, pos, anchors, limit, shift, scale)
    return sparse, schur


@pytest.mark.parametrize("planes", ["fixed", "affine"])
def test_sparse_count_matches_schur_and_dense_across_the_spectrum(planes, factoriser):
    # Sylvester on P A P^T = L D L^T: the negative pivots are the eigenvalues below -shift.
    # Shifts halfway between consecutive eigenvalues (gap checked far above eps ||H||).
    solver, pos, anchors, limit = friction_step(planes)
    H = solver.backend.hessian(pos, anchors, limit).toarray()
    eigenvalues = np.linalg.eigvalsh(0.5 * (H + H.T))
    n = eigenvalues.size
    for m in (0, 1, 5, 17, 60, n // 2, n - 3, n):
        if m == 0:
            shift = -0.5 * eigenvalues[0]
        elif m == n:
            shift = -2.0 * eigenvalues[-1]
        else:
            assert eigenvalues[m] - eigenvalues[m - 1] > 1e6 * EPS * np.abs(eigenvalues).max()
            shift = -0.5 * (eigenvalues[m - 1] + eigenvalues[m])
        sparse, schur = both_routes(solver, pos, anchors, limit, shift)
        assert sparse is not None, f"the sparse route refused the shift below eigenvalue {m}"
        assert sparse.negatives == m and sparse.method == "superlu"
        assert schur.negatives == m
        result = inertia.inertia(solver.model, pos, anchors, limit, shift=shift)
        assert result.method == factoriser and result.negatives == m and result.shift == shift


def test_sparse_count_of_a_saddle_under_compression():
    # Held wefts, warps pushed in (docs/model.md section 6): Newton's equilibrium before the
    # escape is a saddle (tests/test_fabric_static.py); counted at it, both routes agree
    # with the dense spectrum, which has negatives.
    solver = StaticSolver(patch_model("displacement", (-3e-4,), None, hold="weft"))
    state = solver.initial_state()
    pos, anchors = state.positions.copy(), state.anchors.copy()
    prescribe_ends(solver.model.structure, pos, solver.model.yarn_loads(-3e-4, 0.0))
    info, limit = solver.backend.equilibrium(pos, np.zeros(solver.model.yarns), anchors)
    assert info.converged
    H = solver.backend.hessian(pos, anchors, limit).toarray()
    count, gap = dense_count(H, 0.0)
    assert count > 0 and gap > 1e6 * EPS * np.abs(H).max()
    sparse, schur = both_routes(solver, pos, anchors, limit, 0.0)
    assert sparse is not None and sparse.negatives == count
    assert schur.negatives == count
    assert inertia.inertia(solver.model, pos, anchors, limit).negatives == count


def minimum_degree_first(A):
    """The unknown SuperLU eliminates first in its minimum degree order on A^T + A (which
    depends on the pattern alone): its pivot is A_jj itself."""
    lu = scipy.sparse.linalg.splu(A, permc_spec="MMD_AT_PLUS_A", diag_pivot_thresh=0.0,
                                  options=dict(SymmetricMode=True))
    return int(np.flatnonzero(lu.perm_c == 0)[0])


def dissection_unmodified(solver, A, order):
    """An unknown j whose pivot in the nested-dissection factorisation is A_jj itself (every
    unknown coupled to it is eliminated after it, so no update reaches it), while the Schur
    route's band LDL^T of its yarn eliminates it after the free, non-crossing unknown j - 1
    coupled to it (whose update changes its pivot there). The first unknown eliminated in
    nested dissection is the first of its yarn's band too (both start in a corner), so the
    test looks further, at the first unknown of another part of the dissection."""
    n = A.shape[0]
    elimination = ordering.OrderedLU(A, order).elimination
    position = np.empty(n, int)
    position[elimination] = np.arange(n)
    G = A.tocsr()
    dof = np.flatnonzero(solver.backend.pattern.index >= 0)  # unknown -> dof: no ties when clamped
    yarn = np.searchsorted(solver.model.structure.chain_start, dof // 2, side="right")
    band_only = ~inertia.crossing_mask(solver.model.structure)[dof]
    for j in elimination[1:]:
        coupled = G.indices[G.indptr[j]:G.indptr[j + 1]]
        coupled = coupled[coupled != j]
        if (j > 0 and np.all(position[coupled] > position[j]) and band_only[j]
                and band_only[j - 1] and yarn[j - 1] == yarn[j] and G[j, j - 1] != 0.0):
            return int(j)
    raise AssertionError("no unknown with an unmodified dissection pivot inside a band")


@pytest.mark.parametrize("ordered", [True, False], ids=["nested_dissection", "minimum_degree"])
def test_an_exactly_zero_pivot_falls_back_to_the_schur_route(ordered):
    # The unknown chosen has the pivot A_jj itself in the sparse route's factorisation (the
    # ordering depends on the pattern alone, so it is the same for every shift); the shift
    # -A_jj makes that pivot exactly zero (x - x = 0 in floating point): the sparse route
    # must refuse it and, in the order `inertia` uses, `inertia` must count by the Schur
    # route at the same shift, still the dense count.
    solver, pos, anchors, limit = friction_step("fixed")
    H = solver.backend.hessian(pos, anchors, limit)
    A = (0.5 * (H + H.T)).tocsc()
    order = ordering.fabric_order(solver.model.structure, solver.backend.pattern) if ordered else None
    first = dissection_unmodified(solver, A, order) if ordered else minimum_degree_first(A)
    shift = -A[first, first]
    assert shift + A[first, first] == 0.0
    scale = float(np.abs(H.diagonal()).max())
    assert inertia.sparse_inertia(H, shift, scale, order) is None
    if not ordered:
        return
    count, gap = dense_count(H.toarray(), shift)
    assert gap > 1e6 * EPS * scale  # the shifted matrix itself is far from singular
    result = inertia.inertia(solver.model, pos, anchors, limit, shift=shift)
    assert result.method == "schur" and result.shift == shift and result.negatives == count


@pytest.mark.parametrize("matrix, why", [
    ([[0.0, 1.0], [1.0, 0.0]], "zero diagonal: an off-diagonal pivot or none"),
    ([[1.0, 0.0], [0.0, 1e-20]], "a pivot within 64 eps scale of zero"),
    ([[1e-9, 1.0], [1.0, 1e-9]], "element growth: L_21 = 1e9 whichever dof goes first"),
])
def test_the_guards_refuse(matrix, why):
    H = scipy.sparse.csc_matrix(np.array(matrix))
    assert inertia.sparse_inertia(H, 0.0, float(np.abs(H.diagonal()).max())) is None, why
