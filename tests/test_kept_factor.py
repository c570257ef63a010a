"""The Newton solves on kept factors (dynfab.fabric.kept_factor, docs/model.md section 11.10):
GMRES preconditioned by an earlier matrix's factors must give the direction of a direct
solve to its accuracy, and factor where it cannot."""

from __future__ import annotations

import numpy as np
import scipy.sparse
import scipy.sparse.linalg

from dynfab.fabric import kept_factor, ordering


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


def test_kept_factors_solve_a_nearby_matrix_and_a_far_one_is_factored():
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


def test_without_solves_on_kept_factors_every_solve_factors():
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

