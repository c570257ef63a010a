"""Newton's linear solves on the fabric with the step's last factorisation kept as a
preconditioner (docs/model.md section 11.10, cost).

On the spatial specimens SuperLU's factorisation is most of a Newton iteration's time, and
it grows faster with the crossings than the rest (a triangular solve with the factors costs
a small part of it). Within a load step the Hessians of successive Newton iterations differ
little (a few crossings turn from sticking to sliding, the contact stiffness moves with g),
so the factors of an earlier one, M, precondition the next one, H, well: GMRES on H with M
reaches the linear solve's accuracy in a few iterations, each one triangular solve and one
product with H. Where it does not within KRYLOV_ITERATIONS (a Hessian far from M's: the
secant friction stiffness, a shift, the first iterations of a step), H is factored and its
factors are kept instead.

A direction from GMRES is accepted only where its true residual |H d - b| is within
RELATIVE_RESIDUAL of |b|: an inexact Newton step with forcing term 1e-10 converges as the
exact one to the rounding floor (Dembo, Eisenstat and Steihaug, SIAM J. Numer. Anal. 19,
1982), so the equilibrium and the iterations are those of the exact direction, to rounding.
The kept factors are dropped at each step's start (`SparseNewton.problems`), so that a step
from a given state is computed the same way whether the run was resumed before it or not.
"""

from __future__ import annotations

import numpy as np

from dynfab.linalg import pardiso
from dynfab.model.fabric.ordering import OrderedLU, Ordering, symmetric_factor

KRYLOV_ITERATIONS = 6
"""GMRES iterations (each a triangular solve with the kept factors) before H is factored:
enough for the solves that converge quickly on a bias specimen (the others need many more
or do not converge), and fewer than the triangular solves a factorisation costs there
(docs/model.md section 11.10; docs/results.md, "Solves on kept factors")."""
RELATIVE_RESIDUAL = 1e-10
"""|H d - b| / |b| a preconditioned direction must reach (module docstring), or
ATTAINED_MARGIN times what the kept factors' own solve reached, where that is more."""
ATTAINED_MARGIN = 2.0
"""On large specimens a factorisation may not reach RELATIVE_RESIDUAL on its own matrix (the
150 x 450 mm bias specimen's step-0 Hessian, 60,510 unknowns: docs/model.md section 11.10;
docs/results.md, "Solves on kept factors"). A direction within twice the direct solve's
residual is as exact as the direct one; demanding more only wastes the attempt."""


class KeptFactor:
    """The factors of the last matrix factored (PARDISO's where it is available, else
    SuperLU's in a fixed `Ordering`: `ordering.symmetric_factor`; a non-symmetric one's by
    SuperLU, `ordering.OrderedLU`), used to solve later matrices by preconditioned GMRES."""

    def __init__(self, ordering: Ordering, solve_on_kept: bool = True):
        self.ordering = ordering
        self.solve_on_kept = solve_on_kept
        """Whether `solve` tries GMRES on the kept factors before it factors (where a
        factorisation costs few triangular solves, the failed attempts cost more than the
        others save); `solve_near` always does."""
        self.lu: OrderedLU | pardiso.SymmetricFactor | None = None
        self._analysed: pardiso.SymmetricFactor | None = None
        """The last PARDISO factor, whose analysis the next matrix of its pattern reuses."""
        self.factorisations = 0
        """Factorisations so far (for the benchmark)."""
        self.krylov_solves = 0
        """Solves by GMRES on the kept factors so far."""
        self.attained = 0.0
        """|A x - b| / |b| of the direct solve with the kept factors on their own matrix (0
        where not measured)."""

    def drop(self) -> None:
        """Forget the kept factors (a step's start)."""
        self.lu = None
        self.attained = 0.0

    def solve(self, A, rhs) -> np.ndarray:
        """A^-1 rhs: GMRES preconditioned by the kept factors where it converges, else A
        factored (and kept). Raises RuntimeError where SuperLU does (a zero pivot)."""
        found = self._on_kept(A, rhs) if self.solve_on_kept and not self._cheap() else None
        if found is not None:
            return found
        self._factor(A)
        x = self.lu.solve(rhs)
        if self.solve_on_kept and norm(rhs) > 0.0:
            self.attained = norm(A @ x - rhs) / norm(rhs)
        return x

    def _cheap(self) -> bool:
        """Whether the kept factors are PARDISO's, whose factorisation costs about as much as
        a failed GMRES attempt (far fewer triangular solves' worth than SuperLU's on a bias
        specimen: docs/model.md section 11.10; docs/results.md, "Solves on kept factors"):
        `solve` then factors at once."""
        return isinstance(self.lu, pardiso.SymmetricFactor)

    def solve_near(self, A, rhs, B, relative_residual: float = RELATIVE_RESIDUAL
                   ) -> np.ndarray | None:
        """A^-1 rhs to `relative_residual` of |rhs| for a matrix A near the symmetric B (the
        coupled friction Jacobian near the Hessian): GMRES preconditioned by the kept
        factors, else by B's factored (and kept), else by A's own, factored in the same
        order (A has B's pattern, so its fill and cost are B's: far less than SuperLU's
        pivoted factorisation of A, docs/model.md section 11.10; docs/results.md, "Solves on
        kept factors"); None where none converges."""
        found = self._on_kept(A, rhs, relative_residual)
        for matrix in (B, A):
            if found is not None:
                return found
            try:
                self._factor(matrix, symmetric=matrix is B)
            except RuntimeError:
                continue
            found = self._on_kept(A, rhs, relative_residual)
        return found

    def _on_kept(self, A, rhs, relative_residual: float = RELATIVE_RESIDUAL
                 ) -> np.ndarray | None:
        """A^-1 rhs by GMRES on the kept factors (`_preconditioned`), None without them or
        where it does not converge."""
        found = None if self.lu is None else self._preconditioned(A, rhs, relative_residual)
        self.krylov_solves += found is not None
        return found

    def _factor(self, A, symmetric: bool = True) -> None:
        """Factor A and keep its factors (none kept where SuperLU raises RuntimeError)."""
        self.lu = None
        self.attained = 0.0
        if symmetric:
            self.lu = symmetric_factor(A, self.ordering, self._analysed)
            if isinstance(self.lu, pardiso.SymmetricFactor):
                self._analysed = self.lu
        else:
            self.lu = OrderedLU(A, self.ordering)
        self.factorisations += 1

    def _preconditioned(self, A, rhs, relative_residual: float) -> np.ndarray | None:
        """GMRES on A x = rhs right-preconditioned by the kept factors, from x = 0, or None
        where its true residual is not within `relative_residual` of |rhs| (or
        ATTAINED_MARGIN x `attained`, where more) in KRYLOV_ITERATIONS (`gmres`)."""
        target = max(relative_residual, ATTAINED_MARGIN * self.attained) * norm(rhs)
        # GMRES's own residual to half the target: the true one differs from it by rounding
        found = gmres(A, rhs, self.lu.solve, KRYLOV_ITERATIONS, 0.5 * target)
        if found is None or not np.all(np.isfinite(found)) or norm(A @ found - rhs) > target:
            return None
        return found


def inner(a, b) -> float:
    """a . b without BLAS: on a shared machine numpy's BLAS dot of a specimen's vector costs
    far more than einsum, its OpenBLAS threads waiting for a core (docs/results.md, "Solves
    on kept factors")."""
    return float(np.einsum("i,i", a, b))


def norm(a) -> float:
    """|a| (2-norm) without BLAS (`inner`)."""
    return float(np.sqrt(inner(a, a)))


def gmres(A, b, precondition, iterations: int, target: float) -> np.ndarray | None:
    """x with |A x - b| <= target by right-preconditioned GMRES (Saad and Schultz, SIAM J.
    Sci. Stat. Comput. 7, 1986; modified Gram-Schmidt Arnoldi): x = M^-1 y, y in the Krylov
    space of A M^-1 from x = 0, at most `iterations` products with `precondition` (M^-1);
    None where the least-squares residual does not reach `target`."""
    beta = norm(b)
    if beta == 0.0:
        return np.zeros_like(b)
    V, Z = [b / beta], []
    H = np.zeros((iterations + 1, iterations))
    for k in range(iterations):
        Z.append(precondition(V[k]))
        w = A @ Z[k]
        for i in range(k + 1):
            H[i, k] = inner(w, V[i])
            w = w - H[i, k] * V[i]
        H[k + 1, k] = norm(w)
        e = np.zeros(k + 2)
        e[0] = beta
        y, *_ = np.linalg.lstsq(H[:k + 2, :k + 1], e, rcond=None)
        if np.linalg.norm(H[:k + 2, :k + 1] @ y - e) <= target or H[k + 1, k] == 0.0:
            return sum(y[i] * Z[i] for i in range(k + 1))
        V.append(w / H[k + 1, k])
    return None
