"""The static solver's sparse backend: Newton on the exact sparse Hessian of the whole
structure (docs/model.md sections 6, 10), for any structure (chains tied to each other, the
woven fabric; or tied to ground: `dynfab.solvers.static` then takes the banded backend).

Each load step minimises V plus the Huber friction terms over the free dofs from the
previous state, to a residual (largest free force component) of `static.tolerance`, or to
the rounding floor where that is higher (docs/model.md section 6). The Newton matrix is the
exact Hessian (`dynfab.model.fabric.assembly`, the structure's), factored by MKL PARDISO's
L D L^T where MKL is installed, else scipy's sparse LU (SuperLU, in its symmetric mode where
it can: `_sparse_solve`, `dynfab.model.fabric.ordering.symmetric_factor`); the loop, the line search
and the friction updates are ours. The unknowns are the free dofs, a periodic cell's tied
cell lengths counted once (`assembly.Pattern.reduce`, `expand`).

Its strategies in the friction chain (`dynfab.solvers.friction_chain`, docs/model.md sections 4 and
10):

- "unilateral" (`solve_frozen`): F_T is frozen during each Newton solve, at Gralen's law of
  the contact forces the solve starts from; after it, F_T is re-evaluated at the solution's
  contact forces and the solve repeated (an outer fixed point on F_T) until the residual with
  F_T equal to the law at the solution is within the tolerance. That fixed point is not a
  contraction where dF_T/dR dR/dg is large (contact forces near the onset force R_0): after
  FROZEN_UPDATES solves, a Newton on the coupled problem (F_T through R in the Jacobian,
  non-symmetric, the residual's norm as merit: `coupled_newton`) continues from where it
  stands (and if it fails, more frozen solves, then it again).
- "relaxed" (`solve_relaxed`, R_0 > 0): where many crossings sit at g ~ 0 with R << R_0 the
  plain update cycles, crossings opening and closing in turn; the fixed point on F_T
  under-relaxed lets the open/closed set settle.
- "sets" and "continuation": the shared active set (`dynfab.solvers.active_set`), each set solved by
  `_solve_fixed_set` (the coupled Newton, then the frozen solves): a crossing held open
  carries no force at any g, one held closed the unilateral force with the closed side's
  tangent across g = 0.

Every Newton solve (`newton`, `coupled_newton`) holds the lateral contacts of a spatial
structure on an active set of their own, updated between solves of the same call
(`on_lateral_set`, docs/model.md 11.5).

(The banded backend's semismooth fallback is not offered: on the fabric it stalled from the
step's start where the relaxed fixed point converges, docs/model.md section 10.) The anchors
are return-mapped by the model (`dynfab.model.fabric.friction`, radially).

Globalisation (docs/model.md section 6): a backtracking line search on the energy (F_T
frozen); where the energy change is within its rounding, a step that lowers the residual is
accepted. After a shortened step the crossings it took across their Huber kink (`kinked`),
and to retry a failed one every crossing, get the secant stiffness F_T/|s| I when sliding (a
quadratic majorant of the Huber term, as on the banded backend), so a step cannot overshoot
a crossing about to stick again; each crossing's block returns to the exact Hessian's
through blends of the two whose weight falls by SECANT_GROWTH after each full step that
left it clear of its kink (`next_secant_weights`, `SparseNewton.newton`). A step reaching
Kawabata's wall (k_c = inf) has energy +inf and is halved. If the Newton direction is not a
descent direction (an indefinite Hessian), the matrix is shifted by mu I, mu growing tenfold
from 1e-10 max|diag|, until it is.

Its certificate is the sparse route of `dynfab.solvers.certificate` (`certify_patch`,
`escape_patch`): the inertia of the Hessian with F_T frozen from SuperLU's factorisation
(`dynfab.model.fabric.inertia`), the eigenvalue nearest zero, the error bound.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import numpy as np
import scipy.sparse
import scipy.sparse.linalg

from dynfab.solvers import active_set
from dynfab.solvers.certificate import certify_patch, check_patch_accuracy, escape_patch
from dynfab.errors import SolverError
from dynfab.model.fabric import contact, ordering, spatial
from dynfab.linalg import pardiso
from dynfab.model.fabric.friction import STICK
from dynfab.model.fabric.kept_factor import KeptFactor
from dynfab.model.terms.kinematics import terms_of
from dynfab.solvers.friction_chain import friction_chain
from dynfab.solvers.newton_backend import NewtonBackend
from dynfab.solvers.newton_info import Budget, NewtonInfo, within
from dynfab.model.step import StepSolution, StepStart
from dynfab.model.structure import Structure
from dynfab.model.terms import contact as contact_1d
from dynfab.model.terms import friction as gralen
from dynfab.model.terms.contact import CLOSED, OPEN

EPS = np.finfo(np.float64).eps
FROZEN_UPDATES = 3
"""Newton solves with F_T frozen per load step before the coupled Newton takes over: the
fixed point on F_T contracts slowly near the friction onset, so a few frozen solves then
the coupled Newton take fewer iterations than more frozen solves (docs/model.md, fabric
decisions); 1 left the coupled Newton too far from the solution on the small-load path of
tests/test_fabric_energy.py."""
FROZEN_RATIO = 0.1
"""A frozen solve of `solve_frozen` that is not the last stops once its residual is below
this fraction of the residual with F_T updated to the law at its iterate (and that fraction
above the tolerance and the rounding floor): the update would undo the iterations after it.
On the bias specimens this saves 4 to 5 Newton iterations a step, which ran the first
frozen solves to the rounding floor (docs/model.md section 11.10)."""
MAX_FROZEN = 50
"""Further frozen solves when the coupled Newton fails."""
HALVINGS = 60
"""Line-search halvings (8 at the rounding floor, where a step is lost in rounding)."""
SECANT_GROWTH = 4.0
"""A crossing's weight lambda of the secant friction model in Newton's matrix, H = H_exact +
lambda (H_secant - H_exact) on its Huber block (`next_secant_weights`), falls by this after
each full step that did not take it across its kink."""
SECANT_FLOOR = 1e-3
"""Below this lambda a crossing's block is the exact Hessian's again (quadratic convergence)."""
KINK_TURN = 0.5
"""cos of the largest turn of a sliding crossing's slip over one Newton step that leaves its
exact Huber block in charge (`kinked`: 60 degrees)."""
COUPLED_FORCING = 1e-6
"""|J d + g| / |g| a coupled Newton direction d must reach (an inexact Newton step's forcing
term: the next residual is at most this fraction of |g| plus Newton's quadratic term, so
convergence stays quadratic down to a millionth of the step's first residual; Dembo,
Eisenstat and Steihaug, SIAM J. Numer. Anal. 19, 1982). The Hessian's 1e-10 (the kept
factors') cannot be reached there: on the 150 x 450 mm bias specimen (60,510 unknowns)
neither the Jacobian's own factors nor the pivoted LU reach it, where GMRES on the
Hessian's factors gets below this one within KRYLOV_ITERATIONS (docs/model.md section 11.10;
docs/results.md, "Solves on kept factors")."""
LATERAL_UPDATES = 12
"""Lateral contact sets one Newton solve tries before it releases them to the unilateral law
(`SparseNewton.on_lateral_set`; as the crossings' MAX_FLIPS)."""
COUPLED_FIRST = 20
"""Iterations of the coupled Newton on a fixed open/closed set before `solve_frozen` is tried
from the same start (`SparseNewton._solve_fixed_set`)."""
RELAXED_BUDGET = 10
"""Newton iterations of the relaxed fixed point on F_T (`solve_relaxed`), in units of
`max_iterations`, taken from the fallbacks' budget (`dynfab.solvers.friction_chain`; the step that
set it: docs/model.md, "The friction onset in the fabric's static solver")."""
RELAXATION_START = 0.5
"""The first weight w of the relaxed update F_T <- F_T + w (law(R) - F_T)."""
RELAXATION_MIN = 1.0 / 64.0
"""The smallest weight (why: docs/model.md, "The friction onset in the fabric's static
solver")."""
RELAXATION_PATIENCE = 5
"""Relaxed solves without a new lowest residual of the laws after which w is halved."""
RELAXED_COUPLED_EVERY = 25
"""Relaxed solves between attempts of the coupled Newton (COUPLED_FIRST iterations) from the
state reached: once the open/closed set has settled it converges in a few iterations."""


def kinked(before, after, limit, stick) -> np.ndarray:
    """Which crossings a Newton step takes across their Huber kink, from the slips `before`
    to `after` (T, 3) [m] (`crossing_slips`), F_T = `limit` (T,) [N], k_t = `stick` (T,)
    [N/m]: sliding before (k_t |S| > F_T > 0) and the step's straight path in S passing within
    the stick radius F_T / k_t of zero, or turning by more than acos(KINK_TURN). There the
    exact Hessian, which has no stiffness along a sliding slip, misjudges the Huber term
    (docs/model.md 11.10)."""
    radius = np.where(limit > 0.0, limit / stick, 0.0)
    n0, n1 = np.linalg.norm(before, axis=1), np.linalg.norm(after, axis=1)
    step = after - before
    length2 = np.maximum((step * step).sum(axis=1), np.finfo(float).tiny)
    along = np.clip(-(before * step).sum(axis=1) / length2, 0.0, 1.0)
    closest = np.linalg.norm(before + along[:, None] * step, axis=1)
    turned = (before * after).sum(axis=1) < KINK_TURN * n0 * n1
    return (limit > 0.0) & (n0 > radius) & ((closest < radius) | turned)


def next_secant_weights(weights, shortened: bool, kinks) -> np.ndarray:
    """Each crossing's secant weight in Newton's next matrix (`SparseNewton.newton`), from
    `weights` (T,) after a step the line search `shortened` or not, `kinks` (T,) the crossings
    the full step took across their kink (`kinked`): after a shortened step those get 1 (if
    there are none, every weight grows: 0 to 1, others times SECANT_GROWTH, at most 1), the
    others keep theirs; after a full step the crossings it did not take across their kink
    fall by SECANT_GROWTH, to 0 below SECANT_FLOOR, the others keep theirs."""
    out = np.array(weights, float)
    if shortened:
        if kinks.any():
            out[kinks] = 1.0
        else:
            out = np.where(out == 0.0, 1.0, np.minimum(1.0, SECANT_GROWTH * out))
        return out
    out[~kinks] /= SECANT_GROWTH
    out[out < SECANT_FLOOR] = 0.0
    return out


def _sparse_solve(A, rhs, symmetric=True, order=None, kept=None):
    """A^-1 rhs by a sparse factorisation, or None if A is singular.

    A symmetric matrix with `order` (the fabric's nested-dissection order) is factored by
    `ordering.symmetric_factor` (PARDISO's L D L^T where MKL is installed, else SuperLU in
    that order); without one, in SuperLU's symmetric mode (diagonal pivots) in its minimum
    degree on A^T + A; both are faster than the default column ordering with
    partial pivoting on the fabric's Hessians, and nested dissection the fastest on large
    patches (docs/results.md, "Woven fabric: cost", the orderings). If a pivot vanishes
    there, the default, pivoted factorisation is tried. `kept` (a `KeptFactor` in `order`):
    solve by GMRES on its factors where that converges (`dynfab.model.fabric.kept_factor`).
    """
    if symmetric:
        try:
            if kept is not None:
                return kept.solve(A, rhs)
            if order is not None:
                return ordering.symmetric_factor(A, order).solve(rhs)
            return scipy.sparse.linalg.splu(A, permc_spec="MMD_AT_PLUS_A", diag_pivot_thresh=0.0,
                                            options=dict(SymmetricMode=True)).solve(rhs)
        except RuntimeError:
            pass
    try:
        return scipy.sparse.linalg.splu(A).solve(rhs)
    except RuntimeError:  # exactly singular
        return None



@dataclass(frozen=True)
class SetLaw:
    """The contact and friction laws a Newton solve holds (docs/model.md section 4): each
    crossing's branch, OPEN or CLOSED (`dynfab.model.terms.contact`; None: the unilateral law),
    and R_0 [N] (None: the scene's)."""

    branch: np.ndarray | None = None
    onset: float | None = None


def _onset(law: SetLaw | None) -> float:
    """R_0 [N] of `law` for every tie, or -1: each tie's own (`gralen.tie_limits`)."""
    return -1.0 if law is None or law.onset is None else law.onset


def held_lateral_set(structure: Structure, branch) -> Structure:
    """`structure` with each lateral contact held on `branch` (L,) (OPEN or CLOSED,
    `dynfab.model.terms.contact`; the column `spatial.BRANCH` of `lateral_law`, docs/model.md
    11.5)."""
    law = structure.lateral_law.copy()
    law[:, spatial.BRANCH] = branch
    return structure._replace(lateral_law=law)


def scene_onset(structure: Structure) -> float:
    """The R_0 [N] the friction onset's continuation ends at (docs/model.md section 4): the
    ties' one R_0 (a ValueError if their laws differ)."""
    values = np.unique(structure.tie_friction_law[:, 2])
    if values.size > 1:
        raise ValueError("the continuation in R_0 needs one R_0 for every tie")
    return float(values[0]) if values.size else 0.0


class PatchProblem(NamedTuple):
    """The whole structure's load step, one group (`SparseNewton.problems`)."""

    index: int
    positions: np.ndarray
    """(n, 2) [m], solved in place."""
    P: np.ndarray
    """(Y,) [N] the end force along each chain."""
    anchors: np.ndarray
    """(T, 2) [m] the friction anchors held during the step."""


class SparseNewton(NewtonBackend):
    """The sparse backend of `dynfab.solvers.static.StaticSolver` (module docstring): the whole
    structure one group; `dynfab.solvers.newton_backend` states the contract. Its pieces (energy,
    gradient, Hessian, the Newton solves, the fixed points on F_T) take positions, end loads
    and anchors, as the tests and benchmarks use them."""

    reports = ("friction_solves", "negative_eigenvalues")

    def __init__(self, model, **options):
        super().__init__(model, **options)
        self.terms = terms_of(self.structure)
        """The structure's term set: planar or spatial (`dynfab.model.terms.kinematics`)."""
        self.pattern = self.terms.pattern_of(self.structure)
        """The order of the Hessian's entries and its unknowns (`assembly.pattern_of`)."""
        self.dim = self.structure.rest_position.shape[1]
        self.free = ~self.structure.fixed
        self._newton_count = 0  # Newton iterations of the step so far
        self._terms = np.zeros(len(self.terms.TERMS))
        self.kept = None
        """The Newton solves' `KeptFactor` (`_direction`), dropped at each step's start."""

    # ------------------------------------------------------------------ the step

    def problems(self, start: StepStart) -> list[PatchProblem]:
        """The step as one group, its positions a copy of the start's."""
        self._newton_count = 0
        if self.kept is not None:
            self.kept.drop()
        return [PatchProblem(0, start.positions.copy(), start.chain_loads, start.anchors)]

    def solution(self, start: StepStart, problems, fields) -> StepSolution:
        """The positions and F_T from Gralen's law at them; each field repeated for every
        group of the model (`RunModel.groups`: one on a fabric)."""
        pos = problems[0].positions
        groups = len(getattr(self.model, "groups", [0]))
        fields = {name: np.repeat(value, groups) for name, value in fields.items()}
        return StepSolution(pos, self.friction_limits(pos), fields)

    def strategies(self, problem: PatchProblem) -> tuple[str, ...]:
        """"unilateral"; with friction the active set after it, with R_0 > 0 the relaxed fixed
        point before it and the continuation after (docs/model.md, "Decisions": the friction
        chain)."""
        if not self.structure.has_friction:
            return ("unilateral",)
        if scene_onset(self.structure) > 0.0:
            return ("unilateral", "relaxed", "sets", "continuation")
        return ("unilateral", "sets")

    def equilibrium(self, pos, P, anchors) -> tuple[NewtonInfo, np.ndarray]:
        """The friction chain alone from `pos`, in place (no certificate): (info, F_T from the
        law at the solution); raises `SolverError` as a step would."""
        info = friction_chain(self, PatchProblem(0, pos, P, anchors))
        return info, self.friction_limits(pos)

    # ------------------------------------------------------------------ strategies

    def unilateral(self, problem: PatchProblem, budget: Budget) -> NewtonInfo:
        """`solve_frozen` on the unilateral law."""
        info, _, info.solves = self.solve_frozen(problem.positions, problem.P, problem.anchors)
        return info

    def relaxed(self, problem: PatchProblem, budget: Budget) -> NewtonInfo:
        """`solve_relaxed`."""
        info, info.solves = self.solve_relaxed(problem.positions, problem.P, problem.anchors,
                                               budget)
        return info

    # ------------------------------------------------------------------ active-set primitives

    def set_solve(self, problem: PatchProblem, branch, onset: float, max_iterations: int,
                  direct: bool) -> NewtonInfo:
        """`_solve_fixed_set` on the set `branch` at R_0 = `onset`."""
        info, info.solves = self._solve_fixed_set(problem.positions, problem.P, problem.anchors,
                                                  SetLaw(branch, onset), max_iterations)
        return info

    def closures_of(self, problem: PatchProblem) -> np.ndarray:
        return self.closures(problem.positions)

    def law_residual_of(self, problem: PatchProblem, onset: float) -> float:
        return self.law_residual(problem.positions, problem.P, problem.anchors, onset)

    def onset(self, problem: PatchProblem) -> float:
        return scene_onset(self.structure)

    # ------------------------------------------------------------------ failure words

    def group_name(self, problem: PatchProblem) -> str:
        """The model's name of its one group ("fabric"), else "structure"."""
        name = getattr(self.model, "group_name", None)
        groups = len(getattr(self.model, "groups", [0]))
        return name(0) if name is not None and groups == 1 else "structure"

    def crossing_name(self, problem: PatchProblem, c: int) -> str:
        """Tie c as the model counts it (`crossing_name`: "(warp k, weft j)"), else "tie t"
        (1-based)."""
        name = getattr(self.model, "crossing_name", None)
        return name(c) if name is not None else f"tie {c + 1}"

    def yarn_name(self, y: int) -> str:
        """Chain y as the model counts it (`yarn_name`), else "chain y" (1-based): where an
        error bound is largest (`dynfab.solvers.certificate.patch_location`)."""
        name = getattr(self.model, "yarn_name", None)
        return name(y) if name is not None else f"chain {y + 1}"

    def friction_constant(self, problem: PatchProblem, c: int) -> float:
        return float(self.structure.tie_friction_law[c, 1])

    def worst_crossing(self, problem: PatchProblem) -> tuple[int, float]:
        if self.structure.tie_a.size == 0:
            return -1, 0.0
        return self._worst_crossing(problem.positions, problem.P, problem.anchors)

    # ------------------------------------------------------------------ certificate

    def certify(self, problem: PatchProblem, info: NewtonInfo):
        """`certify_patch` at the solution, F_T from the law there (the sparse route,
        docs/model.md section 6)."""
        self.say("stability check (inertia of the Hessian)")
        pos = problem.positions
        return certify_patch(self, pos, problem.anchors, self.friction_limits(pos))

    def escape(self, problem: PatchProblem, checked):
        pos = problem.positions
        return escape_patch(self, pos, problem.P, problem.anchors, self.friction_limits(pos),
                            checked)

    def check_accuracy(self, problem: PatchProblem, checked, stability, k: int,
                       info: NewtonInfo) -> None:
        check_patch_accuracy(self, checked, stability, problem.positions, info.residual,
                             self.tolerance, self.accuracy, info.at_floor, "static.accuracy")

    # ------------------------------------------------------------------ pieces

    def closures(self, pos) -> np.ndarray:
        """g of every crossing (C,) [m] (docs/model.md (10.5))."""
        f = self.structure
        z = pos[:, -1]
        z_b = np.where(f.tie_b >= 0, z[np.maximum(f.tie_b, 0)], 0.0)
        return f.tie_gap_offset - f.tie_side * (z[f.tie_a] - z_b)

    def contact_forces(self, pos, law: SetLaw | None = None) -> np.ndarray:
        """R of every crossing (C,) [N]: the unilateral law, or on `law`'s branches (an open
        crossing carries none)."""
        f = self.structure
        out = np.zeros(f.tie_a.size)
        contact.forces(pos, f, out)
        if law is not None and law.branch is not None:
            out[law.branch == OPEN] = 0.0
        return out

    def friction_limits(self, pos, law: SetLaw | None = None) -> np.ndarray:
        """F_T from Gralen's law at the contact forces of `pos` (0 without friction), with
        `law`'s branches and R_0 (default: the unilateral law, the scene's R_0)."""
        f = self.structure
        out = np.zeros(f.tie_a.size)
        if f.has_friction:
            gralen.tie_limits(self.contact_forces(pos, law), f.tie_friction_law, _onset(law), out)
        return out

    def energy(self, pos, P, anchors, limit, law: SetLaw | None = None) -> float:
        total = self.terms.total_energy(pos, self.structure, P, anchors, limit, self._terms)
        if law is None or law.branch is None:
            return total
        opened, g = self._opened(pos, law)
        laws = self.structure.tie_contact_law[opened]
        lost = sum(contact.crossing_energy(value, row) for value, row in zip(g, laws))
        self._terms[self.terms.CONTACT] -= lost
        return total - lost

    def gradient(self, pos, P, anchors, limit, law: SetLaw | None = None) -> np.ndarray:
        grad = np.zeros_like(pos)
        self.terms.gradient(pos, self.structure, P, anchors, limit, grad)
        if law is not None and law.branch is not None:
            f = self.structure
            opened, g = self._opened(pos, law)
            R = np.array([contact.force(value, row)
                          for value, row in zip(g, f.tie_contact_law[opened])])
            np.add.at(grad[:, -1], f.tie_a[opened], f.tie_side[opened] * R)
            to_node = f.tie_b[opened] >= 0
            np.add.at(grad[:, -1], f.tie_b[opened][to_node], -(f.tie_side[opened] * R)[to_node])
        return grad

    def hessian(self, pos, anchors, limit, secant: float = 0.0,
                law: SetLaw | None = None) -> scipy.sparse.csc_matrix:
        """The Hessian on the free dofs, F_T frozen, the sliding crossings' blocks moved towards
        their secant stiffness by the weight `secant` (`friction.huber_hessian`); on `law`'s
        branches, the contact tangent of `branch_tangents`."""
        H = self.terms.sparse_hessian(self.structure, pos, anchors, limit, secant)
        if law is None or law.branch is None:
            return H
        natural = np.zeros(self.structure.tie_a.size)
        contact.tangents(pos, self.structure, natural)
        change = self.branch_tangents(pos, law) - natural
        return (H + self._contact_blocks(change)).tocsc()

    def branch_tangents(self, pos, law: SetLaw | None = None) -> np.ndarray:
        """dR/dg per crossing (C,) [N/m] on `law`'s branches (`dynfab.model.terms.contact`): 0 when
        open; closed, the unilateral tangent, or for g <= 0 the closed side's k_0 (the Newton
        matrix of a crossing held closed keeps its contact stiffness across g = 0)."""
        f = self.structure
        out = np.zeros(f.tie_a.size)
        contact.tangents(pos, f, out)
        if law is not None and law.branch is not None:
            out[law.branch == OPEN] = 0.0
            shut = (law.branch == CLOSED) & ~(self.closures(pos) > 0.0)
            out[shut] = [contact_1d.tangent(0.0, row) for row in f.tie_contact_law[shut]]
        return out

    def _opened(self, pos, law: SetLaw):
        """(mask, closures) of the crossings `law` holds open although g > 0."""
        g = self.closures(pos)
        opened = (law.branch == OPEN) & (g > 0.0)
        return opened, g[opened]

    def _contact_blocks(self, tangent) -> scipy.sparse.csc_matrix:
        """sum_c tangent_c [[1, -1], [-1, 1]] on (z_a, z_b) of each crossing, on the unknowns."""
        f = self.structure
        c = np.flatnonzero(tangent)
        index = self.pattern.index
        d = self.dim
        za = index[d * f.tie_a[c] + d - 1]
        zb = np.where(f.tie_b[c] >= 0, index[d * np.maximum(f.tie_b[c], 0) + d - 1], -1)  # ground
        t = tangent[c]
        rows = np.concatenate([za, za, zb, zb])
        cols = np.concatenate([za, zb, za, zb])
        values = np.concatenate([t, -t, -t, t])
        keep = (rows >= 0) & (cols >= 0)
        n = self.pattern.free_count
        return scipy.sparse.csc_matrix((values[keep], (rows[keep], cols[keep])), shape=(n, n))

    def residual(self, grad) -> float:
        """The largest force component on the unknowns [N] (a tied family's cell length
        carries the sum of its yarns' end forces)."""
        r = np.abs(self.pattern.reduce(grad))
        return float(r.max()) if r.size else 0.0

    def law_residual(self, pos, P, anchors, onset: float | None = None) -> float:
        """The residual [N] of the unilateral law with F_T = Gralen's law at the contact forces
        of `pos` (R_0 `onset`, default the scene's): how far `pos` is from a state consistent
        with the laws (docs/model.md section 4)."""
        law = None if onset is None else SetLaw(None, onset)
        return self.residual(self.gradient(pos, P, anchors, self.friction_limits(pos, law)))

    # ------------------------------------------------------------------ Newton

    def _kept_factor(self) -> KeptFactor:
        """The Newton solves' `KeptFactor` in the pattern's nested-dissection order."""
        order = ordering.fabric_order(self.structure, self.pattern)
        if self.kept is None or self.kept.ordering is not order:
            self.kept = KeptFactor(order, self.terms.SOLVE_ON_KEPT_FACTORS)
        return self.kept

    def _direction(self, H, g):
        """-H^-1 g by sparse LU in the pattern's nested-dissection order
        (`ordering.fabric_order`), H shifted by mu I until the step is a descent direction;
        by GMRES on the last factors where that converges (`kept_factor`)."""
        kept = self._kept_factor()
        diag = np.abs(H.diagonal()).max()
        shift = 0.0
        eye = scipy.sparse.identity(H.shape[0], format="csc")
        for _ in range(40):
            A = (H + shift * eye if shift else H.copy()).tocsc()
            if not pardiso.takes(A.shape[0]):
                # SuperLU would carry them through its factors (frictionless friction blocks);
                # PARDISO keeps its analysis while the pattern, zeros included, stays
                A.eliminate_zeros()
            d = _sparse_solve(A, -g, kept=kept)
            if d is not None and np.all(np.isfinite(d)) and g @ d < 0.0:
                return d
            shift = max(10.0 * shift, 1e-10 * diag)
        raise SolverError(f"{self.group_name(None)}: no descent direction (the Hessian holds a "
                          "NaN)")

    def _line_search(self, pos, d, slope, residual, P, anchors, limit, halvings, law=None):
        """Armijo on the energy from step 1; within its rounding, accept a lower residual.
        The rounding (`rounding_scale`, which costs more than an energy) is computed only
        once a step fails Armijo's test: most Newton steps pass it at t = 1."""
        e0 = self.energy(pos, P, anchors, limit, law)
        terms = np.abs(self._terms).sum()
        rounding = None
        t = 1.0
        for _ in range(halvings):
            trial = pos + t * d
            e1 = self.energy(trial, P, anchors, limit, law)
            if e1 - e0 <= 1e-4 * t * slope:
                return trial, t
            if rounding is None:
                rounding = 64.0 * EPS * (terms + self.terms.rounding_scale(pos, self.structure,
                                                                           P, limit))
            if abs(e1 - e0) <= rounding:
                if self.residual(self.gradient(trial, P, anchors, limit, law)) < residual:
                    return trial, t
            t *= 0.5
        return None

    def _iteration_start(self, info, pos, grad, iteration, previous, max_iterations, hessian):
        """The prologue of a Newton iteration shared by `newton` and `coupled_newton`: the
        residual of `grad` into info; None when the solve ends here (converged, out of
        iterations, non-finite, or at the rounding floor 4 eps max|H_ii| max|r|: the residual
        below it and no longer halving, docs/model.md section 6), else the Newton matrix
        `hessian()` to go on with."""
        residual = self.residual(grad)
        info.residual, info.iterations = residual, iteration
        if residual <= self.tolerance:
            info.converged = True
            return None
        if iteration == max_iterations or not np.isfinite(residual):
            return None
        H = hessian()
        info.floor = 4.0 * EPS * np.abs(H.diagonal()).max() * np.abs(pos).max()
        if info.floor >= residual > 0.5 * previous:
            info.converged = info.at_floor = True
            return None
        self._newton_count += 1
        self.say(f"Newton iteration {self._newton_count}, residual {residual:.3g} N "
                 f"(tolerance {self.tolerance:.3g} N)")
        return H


    def newton(self, pos, P, anchors, limit, law=None, max_iterations=None,
               update_first=False) -> NewtonInfo:
        """Minimise V + sum H (F_T frozen) from `pos`, in place (docs/model.md section 6), the
        contact on `law`'s branches (None: unilateral), the lateral contacts on their active
        set (`on_lateral_set`). `update_first`: converged already where F_T's update to the
        law would matter more (`_update_first`, FROZEN_RATIO)."""
        return self.on_lateral_set(pos, lambda: self._newton(pos, P, anchors, limit, law,
                                                             max_iterations, update_first))

    def on_lateral_set(self, pos, solve) -> NewtonInfo:
        """`solve()` (a Newton loop on `pos`) with each lateral contact held OPEN or CLOSED
        (docs/model.md 11.5), from the set the unilateral law gives at `pos`; while a
        converged state contradicts its set (a closed contact with w - d < 0, an open one
        with w - d > 0), the set is updated (the crossings' `active_set.update_set`, every
        contradicted contact switched at once) and the solve goes on from there. A set every
        update proposes was tried (or LATERAL_UPDATES of them) releases the contacts to the
        unilateral law for a last solve, whose kink the line search takes. Returns the last
        solve's info with every solve's iterations."""
        natural = self.structure
        if natural.lateral_stencil.shape[0] == 0:
            return solve()
        gaps = np.empty(natural.lateral_stencil.shape[0])
        self.terms.lateral_gaps(pos, natural, gaps)
        branch = active_set.natural_set(gaps)
        seen = {branch.tobytes()}
        iterations, settled = 0, False
        try:
            for _ in range(LATERAL_UPDATES):
                self.structure = held_lateral_set(natural, branch)
                info = solve()
                iterations += info.iterations
                if not info.converged:
                    settled = True  # a failure the caller's fallbacks take
                    break
                self.terms.lateral_gaps(pos, natural, gaps)
                switched = active_set.update_set(gaps, branch, seen, all_first=True)
                if switched is None:  # every set the updates propose was tried
                    break
                if switched.size == 0:  # consistent: the unilateral law's solution
                    settled = True
                    break
                self.say(f"lateral contacts: {switched.size} switched between open and closed")
            if not settled:
                self.structure = natural
                info = solve()
                iterations += info.iterations
        finally:
            self.structure = natural
        info.iterations = iterations
        return info

    def _newton(self, pos, P, anchors, limit, law=None, max_iterations=None,
                update_first=False) -> NewtonInfo:
        """`newton`'s loop on the lateral set the structure holds.

        Newton's matrix is the exact Hessian with each crossing's Huber block blended with
        its secant friction model by the crossing's weight lambda (`hessian`'s `secant`,
        docs/model.md 11.10): 1 for the crossings a step the line search shortened took
        across their kink (`kinked`: the exact Hessian has no stiffness along a sliding
        crossing's slip), falling by SECANT_GROWTH after each full step that left them
        clear of it (`next_secant_weights`); every crossing's 1 to retry a failed step."""
        info = NewtonInfo()
        max_iterations = self.max_iterations if max_iterations is None else max_iterations
        previous = np.inf
        friction = self.structure.has_friction and self.structure.tie_a.size > 0
        secant = np.zeros(self.structure.tie_a.size)  # lambda per crossing
        for iteration in range(max_iterations + 1):
            grad = self.gradient(pos, P, anchors, limit, law)
            if update_first and iteration and self._update_first(pos, P, anchors, grad, info, law):
                info.iterations = iteration
                return info
            H = self._iteration_start(info, pos, grad, iteration, previous, max_iterations,
                                      lambda: self.hessian(pos, anchors, limit, secant, law))
            if H is None:
                return info
            residual, floor = info.residual, info.floor
            previous = residual
            trial = self._newton_step(pos, grad, H, residual, floor, P, anchors, limit, law)
            if trial is None and friction and secant.min() < 1.0:
                secant[:] = 1.0  # a Huber kink in the way: retry on the secant model
                trial = self._newton_step(pos, grad, self.hessian(pos, anchors, limit, 1.0, law),
                                          residual, floor, P, anchors, limit, law)
            if trial is None:
                info.converged = info.at_floor = residual <= floor
                return info
            trial, t = trial
            if friction:
                secant = next_secant_weights(secant, t < 1.0,
                                             self._kinks(pos, trial, t, anchors, limit))
            pos[:, :] = trial
        return info

    def _kinks(self, pos, trial, t, anchors, limit) -> np.ndarray:
        """`kinked` of the full Newton step of which pos -> trial is the fraction t."""
        before, after = (np.empty((self.structure.tie_a.size, 3)) for _ in range(2))
        self.terms.crossing_slips(pos, self.structure, anchors, before)
        self.terms.crossing_slips(pos + (trial - pos) / t, self.structure, anchors, after)
        return kinked(before, after, limit, self.structure.tie_friction_law[:, STICK])

    def _update_first(self, pos, P, anchors, grad, info, law) -> bool:
        """Whether a frozen solve at `pos` (its gradient `grad`) may stop for F_T's update:
        its residual below FROZEN_RATIO of the law's residual at `pos`, that fraction above
        the tolerance and the last iteration's rounding floor; sets info then."""
        residual = self.residual(grad)
        bar = FROZEN_RATIO * self.law_residual_at(pos, P, anchors, law)
        if not (residual <= bar and bar > max(self.tolerance, info.floor)):
            return False
        info.residual, info.converged = residual, True
        return True

    def law_residual_at(self, pos, P, anchors, law=None) -> float:
        """The residual [N] at `pos` with F_T from the law at it, on `law`'s branches."""
        return self.residual(self.gradient(pos, P, anchors, self.friction_limits(pos, law), law))

    def _newton_step(self, pos, grad, H, residual, floor, P, anchors, limit, law=None):
        """(new positions, step length) of a line-searched Newton step on H, or None."""
        g = self.pattern.reduce(grad)
        d_free = self._direction(H, g)
        d = self.pattern.expand(d_free)
        return self._line_search(pos, d.reshape(pos.shape), g @ d_free, residual, P, anchors,
                                 limit, 8 if residual <= floor else HALVINGS, law)


    # ------------------------------------------------------------------ the fixed points on F_T

    def solve_relaxed(self, pos, P, anchors, budget: Budget) -> tuple[NewtonInfo, int]:
        """The friction onset's first fallback (docs/model.md section 10, fabric decisions), in
        place: the fixed point on F_T under-relaxed, F_T <- F_T + w (law(R) - F_T) between
        Newton solves with F_T frozen. Where many crossings sit at g ~ 0 with R << R_0 the
        plain update (w = 1) falls into a 2-cycle, crossings opening and closing in turn
        (dF_T/dR = beta ell r_f / R_0 there); w starts at RELAXATION_START and halves
        whenever RELAXATION_PATIENCE solves bring no new lowest residual of the laws, down
        to RELAXATION_MIN. Every RELAXED_COUPLED_EVERY solves the coupled Newton
        (`coupled_newton`, COUPLED_FIRST iterations) is tried from the state reached: it
        converges once the open/closed set has settled. Accepted only when the residual
        with F_T from the law at the solution is within the tolerance; at most
        RELAXED_BUDGET x max_iterations Newton iterations, taken from the fallback's
        budget. Returns (info, solves)."""
        allowed = min(budget.left, RELAXED_BUDGET * self.max_iterations)
        limit = self.friction_limits(pos)
        weight, best, since = RELAXATION_START, np.inf, 0
        iterations = solves = 0
        info = NewtonInfo()
        while iterations < allowed:
            info = self.newton(pos, P, anchors, limit)
            iterations += max(info.iterations, 1)
            solves += 1
            if not info.converged:
                break
            law = self.friction_limits(pos)
            info.residual = self.residual(self.gradient(pos, P, anchors, law))
            if within(info.residual, info, self.tolerance):
                break
            if info.residual < best:
                best, since = info.residual, 0
            else:
                since += 1
                if since == RELAXATION_PATIENCE:
                    weight, since = max(0.5 * weight, RELAXATION_MIN), 0
            if solves % RELAXED_COUPLED_EVERY == 0:
                trial = pos.copy()
                coupled = self.coupled_newton(trial, P, anchors, None, COUPLED_FIRST)
                iterations += coupled.iterations
                if coupled.converged:
                    pos[:, :], info = trial, coupled
                    break
            limit = limit + weight * (law - limit)
        else:
            info.converged = False
        budget.spend(iterations)
        info.iterations = iterations
        return info, solves

    def solve_frozen(self, pos, P, anchors, law=None, max_iterations=None):
        """Newton solves with F_T frozen, F_T updated between them to the law at the
        solution, until consistent; after FROZEN_UPDATES of them the coupled Newton
        (`coupled_newton`) from where they stand. If that fails, the frozen solves go on
        from the state before it (the fixed point converges, slowly, where the coupled
        Newton's merit stalls at a kink), up to MAX_FROZEN, and the coupled Newton is tried
        again (module docstring). The contact on `law`'s branches with its R_0 (None: the
        unilateral law). Returns (info, F_T, solves)."""
        limit = self.friction_limits(pos, law)
        iterations, outer = 0, 0
        for frozen in (FROZEN_UPDATES, MAX_FROZEN):
            for _ in range(frozen):
                outer += 1
                info = self.newton(pos, P, anchors, limit, law, max_iterations,
                                   update_first=self.structure.has_friction)
                iterations += info.iterations
                if not info.converged:
                    break
                if not self.structure.has_friction:
                    return info, limit, outer
                limit = self.friction_limits(pos, law)
                info.residual = self.residual(self.gradient(pos, P, anchors, limit, law))
                if within(info.residual, info, self.tolerance):
                    info.iterations = iterations
                    return info, limit, outer
            if not self.structure.has_friction:
                break
            start = pos.copy()
            outer += 1
            coupled = self.coupled_newton(pos, P, anchors, law, max_iterations)
            iterations += coupled.iterations
            if coupled.converged:
                coupled.iterations = iterations
                return coupled, self.friction_limits(pos, law), outer
            pos[:, :] = start
            limit = self.friction_limits(pos, law)
        info.iterations = iterations
        info.converged = False
        return info, limit, outer


    def _solve_fixed_set(self, pos, P, anchors, law, max_iterations=None):
        """One set's equilibrium, in place: the coupled Newton (COUPLED_FIRST iterations,
        quadratic near the solution, where a stage or a set update starts), and if it fails,
        from the same start, `solve_frozen` on the set (robust farther away). Returns (info,
        solves)."""
        start = pos.copy()
        info = self.coupled_newton(pos, P, anchors, law, min(COUPLED_FIRST, max_iterations or
                                                             COUPLED_FIRST))
        if info.converged:
            return info, 1
        pos[:, :] = start
        more, _, outer = self.solve_frozen(pos, P, anchors, law, max_iterations)
        more.iterations += info.iterations
        return more, outer + 1

    def coupling(self, pos, anchors, limit, law=None) -> scipy.sparse.csc_matrix:
        """d(dH/ds)/dz through F_T(R(g)) on the free dofs: the non-symmetric part of the
        coupled friction Jacobian (`dynfab.model.terms.friction.add_limit_coupling` in 2D), on
        `law`'s branches with its R_0.

        On a sliding crossing dH/ds = F_T s/|s|, so its rows (x_a, y_b) gain
        (s/|s|) dF_T/dR dR/dg dg/dz with dg/dz_a = -sigma, dg/dz_b = +sigma; sticking
        crossings (dH/ds = k_t s) have none.
        """
        f = self.structure
        c = f.tie_a.size
        tangent = self.branch_tangents(pos, law)
        R = self.contact_forces(pos, law)
        onset = _onset(law)
        rows, cols, values = [], [], []
        d = self.dim
        for i in range(c):
            if not (tangent[i] > 0.0 and limit[i] > 0.0):
                continue
            dofs, units = self.terms.coupling_rows(f, pos, anchors, limit, i)
            if dofs.size == 0:
                continue
            slope = gralen.tie_limit_slope(R[i], f.tie_friction_law, onset, i) * tangent[i]
            z_dofs = [(d * f.tie_a[i] + d - 1, -f.tie_side[i])]
            if f.tie_b[i] >= 0:
                z_dofs.append((d * f.tie_b[i] + d - 1, f.tie_side[i]))
            # rows: J^T (s / |s|), J the slip's Jacobian (its nodes and the plane nodes)
            for row, unit in zip(dofs, units):
                for col, dg in z_dofs:
                    rows.append(row)
                    cols.append(col)
                    values.append(unit * slope * dg)
        index = self.pattern.index
        rows, cols = index[np.array(rows, int)], index[np.array(cols, int)]
        keep = (rows >= 0) & (cols >= 0)
        n = self.pattern.free_count
        return scipy.sparse.csc_matrix((np.array(values)[keep], (rows[keep], cols[keep])),
                                       shape=(n, n))

    def _coupled_direction(self, H, J, g):
        """-J^-1 g to COUPLED_FORCING for the coupled Jacobian J = H + coupling: GMRES
        preconditioned by the factors of H, or of J in H's order (`KeptFactor.solve_near`:
        J is H plus a small non-symmetric part), else SuperLU with pivoting on J (said on
        the live line: a minute at 60,000 unknowns); None if J is singular."""
        H = H.tocsc(copy=True)  # its index arrays may be the pattern's own
        H.eliminate_zeros()
        d = self._kept_factor().solve_near(J, -g, H, COUPLED_FORCING)
        if d is not None:
            return d
        self.say("coupled Newton: the Jacobian factored with pivoting (GMRES on its and the "
                 "Hessian's factors did not converge)")
        return _sparse_solve(J, -g, symmetric=False)

    def coupled_newton(self, pos, P, anchors, law=None, max_iterations=None) -> NewtonInfo:
        """Newton on the coupled problem (F_T = F_T(R) at every iterate), in place, the
        contact on `law`'s branches with its R_0 (None: unilateral, the scene's R_0), the
        lateral contacts on their active set (`on_lateral_set`)."""
        return self.on_lateral_set(pos, lambda: self._coupled_newton(pos, P, anchors, law,
                                                                     max_iterations))

    def _coupled_newton(self, pos, P, anchors, law=None, max_iterations=None) -> NewtonInfo:
        """`coupled_newton`'s loop on the lateral set the structure holds.

        The Jacobian is the Hessian plus `coupling` (not symmetric: SuperLU pivots), and
        steps are backtracked on the 2-norm of the free residual with F_T re-evaluated at
        each trial (docs/model.md section 4's merit for the coupled problem): accepted when it falls
        by 1e-4 t of itself.
        """
        info = NewtonInfo()
        max_iterations = self.max_iterations if max_iterations is None else max_iterations
        previous = np.inf
        for iteration in range(max_iterations + 1):
            limit = self.friction_limits(pos, law)
            grad = self.gradient(pos, P, anchors, limit, law)
            H = self._iteration_start(info, pos, grad, iteration, previous, max_iterations,
                                      lambda: self.hessian(pos, anchors, limit, law=law))
            if H is None:
                return info
            residual, floor = info.residual, info.floor
            previous = residual
            g = self.pattern.reduce(grad)
            J = (H + self.coupling(pos, anchors, limit, law)).tocsc()
            d_free = self._coupled_direction(H, J, g)
            if d_free is None:
                return info
            d = self.pattern.expand(d_free).reshape(pos.shape)
            norm0, t = np.linalg.norm(g), 1.0
            for _ in range(8 if residual <= floor else HALVINGS):
                trial = pos + t * d
                trial_grad = self.gradient(trial, P, anchors, self.friction_limits(trial, law),
                                           law)
                if np.linalg.norm(self.pattern.reduce(trial_grad)) <= (1.0 - 1e-4 * t) * norm0:
                    break
                t *= 0.5
            else:
                info.converged = info.at_floor = residual <= floor
                return info
            pos[:, :] = trial
        return info


    def _worst_crossing(self, pos, P, anchors) -> tuple[int, float]:
        """(c, force [N]): the crossing whose two nodes carry the largest component of the
        unilateral law's residual at `pos` (F_T from the law)."""
        f = self.structure
        grad = self.gradient(pos, P, anchors, self.friction_limits(pos))
        force = np.where(f.fixed.reshape(-1, self.dim), 0.0, np.abs(grad)).max(axis=1)
        worst = np.maximum(force[f.tie_a], np.where(f.tie_b >= 0, force[np.maximum(f.tie_b, 0)],
                                                    0.0))
        c = int(np.argmax(worst))
        return c, float(worst[c])

