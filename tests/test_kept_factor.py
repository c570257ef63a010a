"""The Newton solves on kept factors (dynfab.model.fabric.kept_factor, docs/model.md section 11.10):
GMRES preconditioned by an earlier matrix's factors must give the direction of a direct
solve to its accuracy, and factor where it cannot. The tests of GMRES on kept factors take
SuperLU's (`superlu_alone`): PARDISO's factorisation is cheap enough that the Hessian's
solves factor at once (`test_pardiso_factors_each_hessian_on_its_kept_analysis`)."""

from __future__ import annotations

import numpy as np
import scipy.sparse
import scipy.sparse.linalg

import pytest

from dynfab.model.fabric import kept_factor, ordering

from dynfab.linalg import pardiso


def chain_laplacian(n: int, rng) -> scipy.sparse.csc_matrix:
    """A symmetric positive definite banded matrix with random stiffnesses."""
    k = 1.0 + rng.random(n + 1)
    main = k[:-1] + k[1:]
    return scipy.sparse.diags([-k[1:-1], main, -k[1:-1]], [-1, 0, 1], format="csc")


def test_gmres_reaches_its_target_and_says_when_it_cannot():
    rng = np.random.default_rng(1)
    A = chain_laplacian(200, rng)
    b = rng.standard_normal(200)
    target = 1e-10 * np.linalg.norm(b)
    exact = scipy.sparse.linalg.spsolve(A, b)
    x = kept_factor.gmres(A, b, lambda v: v / A.diagonal(), 200, target)
    assert np.linalg.norm(A @ x - b) <= 1.01 * target
    assert np.allclose(x, exact, rtol=1e-8, atol=0.0)
    assert kept_factor.gmres(A, b, lambda v: v, 3, target) is None


def test_kept_factors_solve_a_nearby_matrix_and_a_far_one_is_factored(superlu_alone):
    """A matrix whose three springs changed (as crossings turning from sticking to sliding:
    M^-1 of it is I plus a rank-3 term, so GMRES converges in four iterations) is solved on
    the kept factors (no new factorisation), to the relative residual the Newton step
    needs; one far from it is factored anew."""
    rng = np.random.default_rng(2)
    n = 300
    A = chain_laplacian(n, rng)
    kept = kept_factor.KeptFactor(ordering.Ordering(np.arange(n)))
    b = rng.standard_normal(n)
    kept.solve(A, b)
    assert (kept.factorisations, kept.krylov_solves) == (1, 0)
    near = A.tolil()
    for i in (10, 150, 290):  # the spring between unknowns i and i + 1 halved
        k = -near[i, i + 1] / 2.0
        near[i, i] -= k
        near[i + 1, i + 1] -= k
        near[i, i + 1] += k
        near[i + 1, i] += k
    near = near.tocsc()
    x = kept.solve(near, b)
    assert (kept.factorisations, kept.krylov_solves) == (1, 1)
    assert np.linalg.norm(near @ x - b) <= kept_factor.RELATIVE_RESIDUAL * np.linalg.norm(b)
    far = (A + scipy.sparse.diags(rng.random(n) * A.diagonal() * 50.0)).tocsc()
    x = kept.solve(far, b)
    assert np.linalg.norm(far @ x - b) <= 1e-12 * np.linalg.norm(b) * np.abs(far).max() * n
    assert kept.factorisations == 2
    kept.drop()
    kept.solve(near, b)
    assert kept.factorisations == 3


def test_without_solves_on_kept_factors_every_solve_factors(superlu_alone):
    """solve_on_kept = False (the planar fabric's term set: a factorisation there costs too
    few triangular solves for GMRES's failed attempts to pay): the nearby matrix that GMRES
    would solve on the kept factors is factored, and the direction is the direct one."""
    rng = np.random.default_rng(2)
    n = 300
    A = chain_laplacian(n, rng)
    near = (A + scipy.sparse.diags(np.where(np.arange(n) == 150, 1e-3, 0.0))).tocsc()
    b = rng.standard_normal(n)
    kept = kept_factor.KeptFactor(ordering.Ordering(np.arange(n)), solve_on_kept=False)
    kept.solve(A, b)
    x = kept.solve(near, b)
    assert (kept.factorisations, kept.krylov_solves) == (2, 0)
    np.testing.assert_allclose(x, scipy.sparse.linalg.spsolve(near, b), rtol=1e-10, atol=0.0)
    reused = kept_factor.KeptFactor(ordering.Ordering(np.arange(n)))
    reused.solve(A, b)
    reused.solve(near, b)
    assert (reused.factorisations, reused.krylov_solves) == (1, 1)   # the default would



def test_a_jacobian_far_from_the_hessian_is_factored_in_its_order_not_pivoted(superlu_alone):
    """solve_near(A, b, B) with A far from B (a non-symmetric part as large as B's springs,
    as the coupled friction Jacobian where many crossings' limits move with their contact):
    GMRES on B's factors does not converge in KRYLOV_ITERATIONS, so A itself is factored in
    the kept order (a third factorisation after the kept one and B's) and solved to the
    relative residual asked for."""
    rng = np.random.default_rng(3)
    n = 300
    B = chain_laplacian(n, rng)
    A = (B + scipy.sparse.diags(3.0 * rng.random(n - 1), 1, format="csc")).tocsc()
    b = rng.standard_normal(n)
    kept = kept_factor.KeptFactor(ordering.Ordering(np.arange(n)))
    kept.solve(B, b)
    assert kept_factor.gmres(A, b, kept.lu.solve, kept_factor.KRYLOV_ITERATIONS,
                             kept_factor.RELATIVE_RESIDUAL * np.linalg.norm(b)) is None
    x = kept.solve_near(A, b, B)
    assert kept.factorisations == 3
    assert np.linalg.norm(A @ x - b) <= kept_factor.RELATIVE_RESIDUAL * np.linalg.norm(b)


def test_a_looser_forcing_term_is_met_on_the_kept_factors_without_factoring(superlu_alone):
    """The coupled Newton's directions ask for a relative residual of 1e-6 (an inexact Newton
    forcing term, dynfab.solvers.newton_sparse.COUPLED_FORCING), not the Hessian's 1e-10, which its
    factors cannot reach on the large specimens. With a small non-symmetric part (the seed
    and size chosen so that 6 GMRES iterations on B's factors reach 1e-6 but not 1e-10,
    both asserted), solve_near meets the looser target on the kept factors alone."""
    rng = np.random.default_rng(4)
    n = 300
    B = chain_laplacian(n, rng)
    b = rng.standard_normal(n)
    A = (B + scipy.sparse.diags(3e-4 * rng.random(n - 1), 1, format="csc")).tocsc()
    kept = kept_factor.KeptFactor(ordering.Ordering(np.arange(n)))
    kept.solve(B, b)
    assert kept_factor.gmres(A, b, kept.lu.solve, kept_factor.KRYLOV_ITERATIONS,
                             kept_factor.RELATIVE_RESIDUAL * np.linalg.norm(b)) is None
    x = kept.solve_near(A, b, B, relative_residual=1e-6)
    assert (kept.factorisations, kept.krylov_solves) == (1, 1)
    assert np.linalg.norm(A @ x - b) <= 1e-6 * np.linalg.norm(b)


def test_an_ill_conditioned_matrix_is_solved_on_kept_factors_as_exactly_as_directly(superlu_alone):
    """Where the factors cannot reach RELATIVE_RESIDUAL on their own matrix (springs spread
    over eight decades: the direct solve leaves about 1e-7 of |b|, as the 150 x 450 mm
    specimen's Hessian leaves 2.3e-9), a nearby matrix is solved on them to ATTAINED_MARGIN
    times what they attained (no new factorisation), which is what a direct solve of it
    leaves; the 1e-10 target alone would refuse that direction and factor."""
    rng = np.random.default_rng(5)
    n = 300
    k = 10.0 ** (-8.0 * rng.random(n + 1))
    A = scipy.sparse.diags([-k[1:-1], k[:-1] + k[1:], -k[1:-1]], [-1, 0, 1], format="csc")
    b = rng.standard_normal(n)
    kept = kept_factor.KeptFactor(ordering.Ordering(np.arange(n)))
    kept.solve(A, b)
    assert kept.attained > 100.0 * kept_factor.RELATIVE_RESIDUAL
    near = A.tolil()
    half = -near[150, 151] / 2.0  # the spring between unknowns 150 and 151 halved
    near[150, 150] -= half
    near[151, 151] -= half
    near[150, 151] += half
    near[151, 150] += half
    near = near.tocsc()
    x = kept.solve(near, b)
    assert (kept.factorisations, kept.krylov_solves) == (1, 1)
    residual = np.linalg.norm(near @ x - b) / np.linalg.norm(b)
    assert residual <= kept_factor.ATTAINED_MARGIN * kept.attained
    direct = ordering.OrderedLU(near, ordering.Ordering(np.arange(n))).solve(b)
    assert np.linalg.norm(near @ direct - b) / np.linalg.norm(b) > 0.1 * residual


@pytest.mark.skipif(not pardiso.available(), reason="MKL (PARDISO) is not installed")
def test_pardiso_factors_each_hessian_on_its_kept_analysis(monkeypatch):
    """With PARDISO, `solve` factors every matrix (no GMRES attempt: `KeptFactor._cheap`),
    a matrix of the same pattern on the kept factor's analysis (the same handle,
    `SymmetricFactor.refactor`), and each direction is the direct one."""
    monkeypatch.setattr(pardiso, "MIN_UNKNOWNS", 0)  # a small matrix too
    rng = np.random.default_rng(2)
    n = 300
    A = chain_laplacian(n, rng)
    near = (A + scipy.sparse.diags(np.where(np.arange(n) == 150, 1e-3, 0.0))).tocsc()
    b = rng.standard_normal(n)
    kept = kept_factor.KeptFactor(ordering.Ordering(np.arange(n)))
    kept.solve(A, b)
    first = kept.lu
    assert isinstance(first, pardiso.SymmetricFactor)
    x = kept.solve(near, b)
    assert (kept.factorisations, kept.krylov_solves) == (2, 0)
    assert kept.lu is first
    np.testing.assert_allclose(x, scipy.sparse.linalg.spsolve(near, b), rtol=1e-10, atol=0.0)
