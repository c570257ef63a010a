"""The fabric's static solver: Newton on the exact sparse Hessian (docs/model.md sections 6, 10).

Each load step minimises V plus the Huber friction terms over the free dofs from the
previous state, to a residual (largest free force component) of `static.tolerance`, or to
the rounding floor where that is higher (docs/model.md section 6). The Newton matrix is the exact
Hessian (`dynfab.fabric.assembly`), factored by scipy's sparse LU (SuperLU, in its
symmetric mode where it can: `_sparse_solve`); the loop, the line search and the
friction updates are ours. The unknowns are the free dofs, a periodic cell's tied cell
lengths counted once (`assembly.Pattern.reduce`, `expand`).

Friction (docs/model.md sections 4 and 10): F_T is frozen during each Newton solve, at Gralen's law
of the contact forces the solve starts from; after it, F_T is re-evaluated at the
solution's contact forces and the solve repeated (an outer fixed point on F_T) until
the residual with F_T equal to the law at the solution is within the tolerance. That
fixed point is not a contraction where dF_T/dR dR/dg is large (contact forces near the
onset force R_0, docs/model.md section 4): after FROZEN_UPDATES solves, a Newton on the coupled
problem (F_T through R in the Jacobian, non-symmetric, the residual's norm as merit)
continues from where it stands (and if it fails, more frozen solves, then it again:
`solve_frozen`). Then the anchors are return-mapped (radially,
`dynfab.fabric.friction`).

At the friction onset (docs/model.md section 4: crossings near g = 0, where the contact
tangent and dF_T/dg jump) that can stall. The step is then solved again from its start,
first by the fixed point on F_T under-relaxed (`solve_relaxed`: where many crossings sit
at g ~ 0 with R << R_0 the plain update cycles, crossings opening and closing in turn),
then as the one-yarn solver does (`solve_on_sets`, sharing `dynfab.active_set`): the open/closed
set of the crossings held fixed during each solve (a crossing held open carries no
force at any g; one held closed the unilateral force with the closed side's tangent
across g = 0) and updated where the state contradicts it, first at the scene's R_0, then
by continuation in R_0 from 1e-3 N down to it; with R_0 = 0 (the literal jump law) set
updates that keep switching a crossing stop the step. Either way the state accepted is
consistent with the unilateral law and Gralen's (the residual with F_T from the law at
the solution's R within the tolerance). A step that still fails raises a SolverError
naming the crossing (warp k, weft j) to blame and the residual reached. (The one-yarn
solver's semismooth fallback is not ported: on the fabric it stalled from the step's start
where the relaxed fixed point converges, docs/model.md section 10.)

Globalisation (docs/model.md section 6): a backtracking line search on the energy (F_T frozen);
where the energy change is within its rounding, a step that lowers the residual is
accepted. After a shortened step, and to retry a failed one, sliding crossings get the
secant stiffness F_T/|s| I (a quadratic majorant of the Huber term, as in the one-yarn
solver), so a step cannot overshoot a crossing about to stick again. A step reaching
Kawabata's wall (k_c = inf) has energy +inf and is halved. If the Newton direction is not a descent direction (an indefinite Hessian), the matrix
is shifted by mu I, mu growing tenfold from 1e-10 max|diag|, until it is.

Each converged step is certified by the model side (`dynfab.certificate.certify_patch`,
docs/model.md section 6): the number of negative eigenvalues of the Hessian with F_T
frozen (`dynfab.fabric.inertia`), and the eigenvalue nearest zero (the smallest when there
is no negative one). From a saddle the step leaves along the lowest eigenvectors
(`dynfab.certificate.escape_patch`) and is solved again (`_certified`), as the one-yarn
solver does along its LDL^T's negative-pivot directions (docs/model.md section 6).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse
import scipy.sparse.linalg

from dynfab.active_set import (CONTINUATION_FACTORS, CONTINUATION_START, DIRECT_ITERATIONS,
                               DIRECT_SET_UPDATES, MAX_FLIPS, MAX_SET_UPDATES, onset_stages,
                               update_set)
from dynfab.certificate import (MAX_ESCAPES, certify_patch, check_patch_accuracy, escape_patch,
                                patch_stability)
from dynfab.errors import SolverError
from dynfab.fabric import assembly, contact, friction, ordering
from dynfab.fabric.model import FabricState, run_load_path
from dynfab.step import StepSolution
from dynfab.structure import Structure, chain_count
from dynfab.terms import contact as contact_1d
from dynfab.terms import friction as gralen
from dynfab.terms.contact import CLOSED, OPEN

EPS = np.finfo(np.float64).eps
FROZEN_UPDATES = 3
"""Newton solves with F_T frozen per load step before the coupled Newton takes over: the
fixed point on F_T contracts slowly near the friction onset, so a few frozen solves then
the coupled Newton take fewer iterations than more frozen solves (docs/model.md, fabric
decisions); 1 left the coupled Newton too far from the solution on the small-load path of
tests/test_fabric_energy.py."""
MAX_FROZEN = 50
"""Further frozen solves when the coupled Newton fails."""
HALVINGS = 60
"""Line-search halvings (8 at the rounding floor, where a step is lost in rounding)."""
COUPLED_FIRST = 20
"""Iterations of the coupled Newton on a fixed open/closed set before `solve_frozen` is tried
from the same start (`FabricStaticSolver._solve_fixed_set`)."""
FALLBACK_BUDGET = 150
"""Newton iterations of a step's active-set fallback, in units of `max_iterations`: after
them it stops with its failure. The hardest 4 x 4 steps tried needed 23,125 (a 60-step
equal biaxial path, step 14) and 17,756 (weft ends compressed, step 4) of the 30,000 this
gives at max_iterations = 200; an 8 x 8 patch at 0.1 mN per warp found no state in 6,017."""
RELAXED_BUDGET = 10
"""Newton iterations of the relaxed fixed point on F_T (`solve_relaxed`), in units of
`max_iterations`, taken from the fallback's FALLBACK_BUDGET: an 8 x 8 patch at 0.1 mN per
warp (R_0 = 1e-5 N) needed 140 (25 solves, then the coupled Newton)."""
RELAXATION_START = 0.5
"""The first weight w of the relaxed update F_T <- F_T + w (law(R) - F_T)."""
RELAXATION_MIN = 1.0 / 64.0
"""The smallest weight: on that patch w = 0.3 still wandered after 60 solves, w = 0.05
contracted the laws' residual by about 0.955 per solve."""
RELAXATION_PATIENCE = 5
"""Relaxed solves without a new lowest residual of the laws after which w is halved."""
RELAXED_COUPLED_EVERY = 25
"""Relaxed solves between attempts of the coupled Newton (COUPLED_FIRST iterations) from the
state reached: once the open/closed set has settled it converges in a few iterations."""
CYCLING_REASON, ONSET_REASON = "cycling", "onset"
"""Why a step failed, in `NewtonInfo.reason` (the message of `FabricStaticSolver.step`)."""


def _sparse_solve(A, rhs, symmetric=True, order=None):
    """A^-1 rhs by SuperLU, or None if A is singular.

    A symmetric matrix is factored in SuperLU's symmetric mode (diagonal pivots): with
    `order`, the fabric's nested-dissection order (`dynfab.fabric.ordering`), else SuperLU's
    minimum degree on A^T + A; both are faster than the default column ordering with
    partial pivoting on the fabric's Hessians, and nested dissection the fastest on large
    patches (`python benchmarks/fabric.py --pieces` measures them). If a pivot vanishes
    there, the default, pivoted factorisation is tried.
    """
    if symmetric:
        try:
            if order is not None:
                return ordering.OrderedLU(A, order).solve(rhs)
            return scipy.sparse.linalg.splu(A, permc_spec="MMD_AT_PLUS_A", diag_pivot_thresh=0.0,
                                            options=dict(SymmetricMode=True)).solve(rhs)
        except RuntimeError:
            pass
    try:
        return scipy.sparse.linalg.splu(A).solve(rhs)
    except RuntimeError:  # exactly singular
        return None


@dataclass
class NewtonInfo:
    residual: float = np.inf
    """Largest free force component [N] at the end."""
    iterations: int = 0
    at_floor: bool = False
    """Stopped at the rounding floor above the tolerance (docs/model.md section 6)."""
    floor: float = 0.0
    """The residual's rounding floor [N], 4 eps max|H_ii| max|r|, at the last iteration."""
    converged: bool = False
    crossing: int = -1
    """A failure's crossing to blame (0-based c = k n_we + j), -1 if none."""
    reason: str = ""
    """A failure's kind: CYCLING_REASON, ONSET_REASON or "" (no convergence)."""


@dataclass(frozen=True)
class SetLaw:
    """The contact and friction laws a Newton solve holds (docs/model.md section 4): each
    crossing's branch, OPEN or CLOSED (`dynfab.terms.contact`; None: the unilateral law),
    and R_0 [N] (None: the scene's)."""

    branch: np.ndarray | None = None
    onset: float | None = None


def _onset(law: SetLaw | None) -> float:
    """R_0 [N] of `law` for every tie, or -1: each tie's own (`gralen.tie_limits`)."""
    return -1.0 if law is None or law.onset is None else law.onset


def scene_onset(structure: Structure) -> float:
    """The R_0 [N] the friction onset's continuation ends at (docs/model.md section 4): the
    ties' one R_0 (a ValueError if their laws differ)."""
    values = np.unique(structure.tie_friction_law[:, 2])
    if values.size > 1:
        raise ValueError("the continuation in R_0 needs one R_0 for every tie")
    return float(values[0]) if values.size else 0.0


def _within(residual: float, info: NewtonInfo, tolerance: float) -> bool:
    """A residual [N] within the tolerance, or within the rounding floor the solve of `info`
    stopped at."""
    return residual <= max(tolerance, info.floor if info.at_floor else 0.0)


def _started(info: NewtonInfo) -> NewtonInfo:
    """An intermediate continuation stage's outcome: a start for the next stage."""
    info.converged = True
    return info


class FabricStaticSolver:
    """Solves a fabric's load steps one after another (docs/model.md sections 6, 10)."""

    def __init__(self, model, status=None):
        self.model = model
        """The fabric's model (`dynfab.fabric.model.FabricModel`): its structure, load path,
        Hessian, load prescription and observables, and the scene's static options."""
        self.status = status
        """Called as status(text) within a step, once per Newton iteration (its count in the
        step and residual) and before the stability check (the progress line), or None."""
        self._newton_count = 0  # Newton iterations of the step so far
        self.fabric: Structure = model.structure
        self.pattern = assembly.pattern_of(self.fabric)
        self.free = ~self.fabric.fixed
        self.yarns = chain_count(self.fabric)
        self.tolerance = model.scene.static.tolerance
        """Newton's residual tolerance [N] (docs/model.md section 6), or the rounding floor
        where higher."""
        self.max_iterations = model.scene.static.max_iterations
        self.accuracy = model.scene.static.accuracy
        """Largest accepted error bound of a step relative to its largest displacement
        (docs/model.md, "Stability and accuracy of a converged step")."""
        self._terms = np.zeros(len(assembly.TERMS))
        self._budget = 0  # Newton iterations left to the active-set fallback (`solve_on_sets`)

    # ------------------------------------------------------------------ state

    def initial_state(self) -> FabricState:
        """As woven, anchors at zero slip, nothing dissipated (`as_woven_state`)."""
        return self.model.initial_state()

    # ------------------------------------------------------------------ pieces

    def closures(self, pos) -> np.ndarray:
        """g of every crossing (C,) [m] (docs/model.md (10.5))."""
        f = self.fabric
        z = pos[:, 1]
        z_b = np.where(f.tie_b >= 0, z[np.maximum(f.tie_b, 0)], 0.0)
        return f.tie_gap_offset - f.tie_side * (z[f.tie_a] - z_b)

    def contact_forces(self, pos, law: SetLaw | None = None) -> np.ndarray:
        """R of every crossing (C,) [N]: the unilateral law, or on `law`'s branches (an open
        crossing carries none)."""
        f = self.fabric
        out = np.zeros(f.tie_a.size)
        contact.forces(pos, f, out)
        if law is not None and law.branch is not None:
            out[law.branch == OPEN] = 0.0
        return out

    def friction_limits(self, pos, law: SetLaw | None = None) -> np.ndarray:
        """F_T from Gralen's law at the contact forces of `pos` (0 without friction), with
        `law`'s branches and R_0 (default: the unilateral law, the scene's R_0)."""
        f = self.fabric
        out = np.zeros(f.tie_a.size)
        if f.has_friction:
            gralen.tie_limits(self.contact_forces(pos, law), f.tie_friction_law, _onset(law), out)
        return out

    def energy(self, pos, P, anchors, limit, law: SetLaw | None = None) -> float:
        total = assembly.total_energy(pos, self.fabric, P, anchors, limit, self._terms)
        if law is None or law.branch is None:
            return total
        opened, g = self._opened(pos, law)
        laws = self.fabric.tie_contact_law[opened]
        lost = sum(contact.crossing_energy(value, row) for value, row in zip(g, laws))
        self._terms[assembly.CONTACT] -= lost
        return total - lost

    def gradient(self, pos, P, anchors, limit, law: SetLaw | None = None) -> np.ndarray:
        grad = np.zeros_like(pos)
        assembly.gradient(pos, self.fabric, P, anchors, limit, grad)
        if law is not None and law.branch is not None:
            f = self.fabric
            opened, g = self._opened(pos, law)
            R = np.array([contact.force(value, row)
                          for value, row in zip(g, f.tie_contact_law[opened])])
            np.add.at(grad[:, 1], f.tie_a[opened], f.tie_side[opened] * R)
            to_node = f.tie_b[opened] >= 0
            np.add.at(grad[:, 1], f.tie_b[opened][to_node], -(f.tie_side[opened] * R)[to_node])
        return grad

    def hessian(self, pos, anchors, limit, secant=False,
                law: SetLaw | None = None) -> scipy.sparse.csc_matrix:
        """The Hessian on the free dofs, F_T frozen (`secant`: see `friction.huber_hessian`);
        on `law`'s branches, the contact tangent of `branch_tangents`."""
        H = assembly.sparse_hessian(self.fabric, pos, anchors, limit, secant)
        if law is None or law.branch is None:
            return H
        natural = np.zeros(self.fabric.tie_a.size)
        contact.tangents(pos, self.fabric, natural)
        change = self.branch_tangents(pos, law) - natural
        return (H + self._contact_blocks(change)).tocsc()

    def branch_tangents(self, pos, law: SetLaw | None = None) -> np.ndarray:
        """dR/dg per crossing (C,) [N/m] on `law`'s branches (`dynfab.terms.contact`): 0 when
        open; closed, the unilateral tangent, or for g <= 0 the closed side's k_0 (the Newton
        matrix of a crossing held closed keeps its contact stiffness across g = 0)."""
        f = self.fabric
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
        f = self.fabric
        c = np.flatnonzero(tangent)
        index = self.pattern.index
        za = index[2 * f.tie_a[c] + 1]
        zb = np.where(f.tie_b[c] >= 0, index[2 * np.maximum(f.tie_b[c], 0) + 1], -1)  # ground: none
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

    def _direction(self, H, g):
        """-H^-1 g by sparse LU in the pattern's nested-dissection order
        (`ordering.fabric_order`), H shifted by mu I until the step is a descent direction."""
        order = ordering.fabric_order(self.fabric, self.pattern)
        diag = np.abs(H.diagonal()).max()
        shift = 0.0
        eye = scipy.sparse.identity(H.shape[0], format="csc")
        for _ in range(40):
            A = (H + shift * eye if shift else H.copy()).tocsc()
            A.eliminate_zeros()  # else carried through the factors (frictionless friction blocks)
            d = _sparse_solve(A, -g, order=order)
            if d is not None and np.all(np.isfinite(d)) and g @ d < 0.0:
                return d
            shift = max(10.0 * shift, 1e-10 * diag)
        raise SolverError("fabric: no descent direction (the Hessian holds a NaN)")

    def _line_search(self, pos, d, slope, residual, P, anchors, limit, halvings, law=None):
        """Armijo on the energy from step 1; within its rounding, accept a lower residual."""
        e0 = self.energy(pos, P, anchors, limit, law)
        rounding = 64.0 * EPS * (np.abs(self._terms).sum()
                                 + assembly.rounding_scale(pos, self.fabric, P, limit))
        t = 1.0
        for _ in range(halvings):
            trial = pos + t * d
            e1 = self.energy(trial, P, anchors, limit, law)
            if e1 - e0 <= 1e-4 * t * slope:
                return trial, t
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

    def say(self, text: str) -> None:
        """Pass `text` to `status`, if set."""
        if self.status is not None:
            self.status(text)

    def newton(self, pos, P, anchors, limit, law=None, max_iterations=None) -> NewtonInfo:
        """Minimise V + sum H (F_T frozen) from `pos`, in place (docs/model.md section 6), the
        contact on `law`'s branches (None: unilateral)."""
        info = NewtonInfo()
        max_iterations = self.max_iterations if max_iterations is None else max_iterations
        previous = np.inf
        cut = False  # the last step was shortened: the secant friction stiffness
        for iteration in range(max_iterations + 1):
            grad = self.gradient(pos, P, anchors, limit, law)
            H = self._iteration_start(info, pos, grad, iteration, previous, max_iterations,
                                      lambda: self.hessian(pos, anchors, limit, cut, law))
            if H is None:
                return info
            residual, floor = info.residual, info.floor
            previous = residual
            trial = self._newton_step(pos, grad, H, residual, floor, P, anchors, limit, law)
            if trial is None and not cut and self.fabric.has_friction:
                cut = True  # a Huber kink in the way: retry on the secant model
                trial = self._newton_step(pos, grad, self.hessian(pos, anchors, limit, True, law),
                                          residual, floor, P, anchors, limit, law)
            if trial is None:
                info.converged = info.at_floor = residual <= floor
                return info
            trial, t = trial
            cut = t < 1.0
            pos[:, :] = trial
        return info

    def _newton_step(self, pos, grad, H, residual, floor, P, anchors, limit, law=None):
        """(new positions, step length) of a line-searched Newton step on H, or None."""
        g = self.pattern.reduce(grad)
        d_free = self._direction(H, g)
        d = self.pattern.expand(d_free)
        return self._line_search(pos, d.reshape(pos.shape), g @ d_free, residual, P, anchors,
                                 limit, 8 if residual <= floor else HALVINGS, law)

    def solve(self, pos, P, anchors) -> tuple[NewtonInfo, np.ndarray, int]:
        """One load step's equilibrium from `pos`, in place, consistent with the contact and
        friction laws (docs/model.md section 4): `solve_frozen` on the unilateral law; if it
        fails with friction, from the same start, the open/closed active set with its
        continuation in R_0 (`solve_on_sets`). Returns (info, F_T, solves); a failure's info
        names the crossing to blame (`NewtonInfo.crossing`)."""
        start = pos.copy()
        info, limit, outer = self.solve_frozen(pos, P, anchors)
        if info.converged or not self.fabric.has_friction:
            return info, limit, outer
        iterations = info.iterations
        pos[:, :] = start
        self._budget = FALLBACK_BUDGET * self.max_iterations
        if scene_onset(self.fabric) > 0.0:
            info, more = self.solve_relaxed(pos, P, anchors)
            iterations += info.iterations
            outer += more
            if info.converged:
                info.iterations = iterations
                return info, self.friction_limits(pos), outer
            pos[:, :] = start
        info, more = self.solve_on_sets(pos, P, anchors)
        info.iterations += iterations
        return info, self.friction_limits(pos), outer + more

    def solve_relaxed(self, pos, P, anchors) -> tuple[NewtonInfo, int]:
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
        budget = min(self._budget, RELAXED_BUDGET * self.max_iterations)
        limit = self.friction_limits(pos)
        weight, best, since = RELAXATION_START, np.inf, 0
        iterations = solves = 0
        info = NewtonInfo()
        while iterations < budget:
            info = self.newton(pos, P, anchors, limit)
            iterations += max(info.iterations, 1)
            solves += 1
            if not info.converged:
                break
            law = self.friction_limits(pos)
            info.residual = self.residual(self.gradient(pos, P, anchors, law))
            if _within(info.residual, info, self.tolerance):
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
        self._budget -= iterations
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
                info = self.newton(pos, P, anchors, limit, law, max_iterations)
                iterations += info.iterations
                if not info.converged:
                    break
                if not self.fabric.has_friction:
                    return info, limit, outer
                limit = self.friction_limits(pos, law)
                info.residual = self.residual(self.gradient(pos, P, anchors, limit, law))
                if _within(info.residual, info, self.tolerance):
                    info.iterations = iterations
                    return info, limit, outer
            if not self.fabric.has_friction:
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

    # ------------------------------------------------------------------ the onset

    def solve_on_sets(self, pos, P, anchors) -> tuple[NewtonInfo, int]:
        """The friction onset's fallback (docs/model.md section 4, and the fabric decisions),
        in place: the open/closed set of the crossings held fixed during each solve and
        updated between solves until the state agrees with it (`_solve_set`), first at the
        scene's R_0 (DIRECT_SET_UPDATES updates, Newton solves of at most DIRECT_ITERATIONS),
        then by continuation in R_0 from CONTINUATION_START down to the scene's R_0
        (`dynfab.active_set.onset_stages`), each stage from the last one's state and set, with
        the factors CONTINUATION_FACTORS in turn. With R_0 = 0 (the literal jump law) there
        is no continuation: the set updates at R_0 = 0 (at most MAX_FLIPS) either agree or
        cycle, and a cycle names the crossing switched most often. All of it within what is
        left of the step's FALLBACK_BUDGET x max_iterations Newton iterations (`solve` sets
        it; `solve_relaxed` takes its share first). Returns (info, solves)."""
        f = self.fabric
        start = pos.copy()
        target = scene_onset(f)
        branch = self._natural_set(pos)
        info, outer = self._solve_set(pos, P, anchors, branch, target,
                                      DIRECT_SET_UPDATES if target > 0.0 else MAX_FLIPS, True,
                                      DIRECT_ITERATIONS)
        if info.converged or target == 0.0:
            return info, outer
        iterations, first = info.iterations, info
        for factor in CONTINUATION_FACTORS:
            pos[:, :] = start
            branch = self._natural_set(pos)
            for onset in onset_stages(target, factor):
                info, more = self._solve_set(pos, P, anchors, branch, onset, MAX_SET_UPDATES,
                                             onset == target)
                iterations += info.iterations
                outer += more
                if not np.isfinite(info.residual) or self._budget <= 0:
                    break
            # solved only by the last stage: an intermediate one is a start, not the answer
            info.converged = info.converged and onset == target
            if info.converged or self._budget <= 0:
                break
        info.iterations = iterations
        if not info.converged:
            info.reason = ONSET_REASON
            info.crossing = first.crossing if info.crossing < 0 else info.crossing
            if np.isfinite(info.residual):  # the laws' residual at the scene's R_0
                info.residual = self.law_residual(pos, P, anchors)
        return info, outer

    def _natural_set(self, pos) -> np.ndarray:
        """The open/closed set the unilateral law gives at `pos`: CLOSED where g > 0."""
        return np.where(self.closures(pos) > 0.0, CLOSED, OPEN).astype(np.int64)

    def _solve_set(self, pos, P, anchors, branch, onset, max_updates, final,
                   max_iterations=None):
        """Solves on fixed sets at R_0 = `onset`, `branch` updated in place between them
        (`dynfab.active_set.update_set`) until consistent: converged on its set with the
        unilateral law's residual (F_T from the law at R_0 = `onset`) within the tolerance,
        each Newton solve at most `max_iterations` long (default the scene's).
        A solve that ends short of the tolerance still updates the set, while its state is
        finite. An intermediate stage (not `final`) is only the next stage's start and always
        succeeds. Returns (info, solves): a failure's info names the crossing to blame (the
        one switched most often, or the one nearest g = 0), why, and the laws' residual
        (`law_residual`) at the state reached."""
        seen = {branch.tobytes()}
        outer = iterations = 0
        flips = np.zeros(branch.size, np.int64)
        info = NewtonInfo()
        for _ in range(max_updates):
            law = SetLaw(branch.copy(), onset)
            info, more = self._solve_fixed_set(pos, P, anchors, law, max_iterations)
            self._budget -= info.iterations
            iterations += info.iterations
            outer += more
            info.iterations = iterations
            g = self.closures(pos)
            if not np.isfinite(info.residual):
                break
            residual = self.law_residual(pos, P, anchors, onset)
            if info.converged and _within(residual, info, self.tolerance):
                info.residual = residual
                return info, outer
            if self._budget <= 0:  # FALLBACK_BUDGET spent
                break
            switched = update_set(g, branch, seen)
            if switched is None:  # every set the updates propose was tried
                if not final:
                    return _started(info), outer
                info.reason = CYCLING_REASON
                break
            if switched.size == 0:
                if not final:
                    return _started(info), outer
                break
            flips[switched] += 1
        else:
            if not final:
                return _started(info), outer
            info.reason = CYCLING_REASON
        info.converged = False
        # the crossing switched most often (of equals the highest c), else the one nearest g = 0
        info.crossing = (int(flips.size - 1 - np.argmax(flips[::-1])) if flips.any()
                         else int(np.argmin(np.abs(self.closures(pos)))))
        if np.isfinite(info.residual):  # the residual reached: of the laws, not of the set
            info.residual = self.law_residual(pos, P, anchors, onset)
        return info, outer

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
        coupled friction Jacobian (`dynfab.terms.friction.add_limit_coupling` in 2D), on
        `law`'s branches with its R_0.

        On a sliding crossing dH/ds = F_T s/|s|, so its rows (x_a, y_b) gain
        (s/|s|) dF_T/dR dR/dg dg/dz with dg/dz_a = -sigma, dg/dz_b = +sigma; sticking
        crossings (dH/ds = k_t s) have none.
        """
        f = self.fabric
        c = f.tie_a.size
        tangent = self.branch_tangents(pos, law)
        R = self.contact_forces(pos, law)
        onset = _onset(law)
        px, py = assembly.planes(pos, f)
        rows, cols, values = [], [], []
        for i in range(c):
            sx, sy = friction.slip(pos, anchors, f, px, py, i)
            norm = np.hypot(sx, sy)
            stick = f.tie_friction_law[i, friction.STICK]
            if not (tangent[i] > 0.0 and limit[i] > 0.0 and stick * norm >= limit[i]):
                continue
            slope = gralen.tie_limit_slope(R[i], f.tie_friction_law, onset, i) * tangent[i]
            z_dofs = [(2 * f.tie_a[i] + 1, -f.tie_side[i])]
            if f.tie_b[i] >= 0:
                z_dofs.append((2 * f.tie_b[i] + 1, f.tie_side[i]))
            # rows: J^T (s / |s|), J the slip's Jacobian (its nodes and the plane nodes)
            J = assembly.slip_jacobian(f, i)
            for row, unit in zip(assembly.slip_dofs(f, i), J.T @ np.array([sx, sy]) / norm):
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

    def coupled_newton(self, pos, P, anchors, law=None, max_iterations=None) -> NewtonInfo:
        """Newton on the coupled problem (F_T = F_T(R) at every iterate), in place, the
        contact on `law`'s branches with its R_0 (None: unilateral, the scene's R_0).

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
            d_free = _sparse_solve((H + self.coupling(pos, anchors, limit, law)).tocsc(), -g,
                                   symmetric=False)
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

    # ------------------------------------------------------------------ steps

    name = "static"

    def attrs(self) -> dict:
        """Root attributes of the result file describing the solver and its options."""
        return {"solver": self.name, "static_tolerance": self.tolerance,
                "static_max_iterations": self.max_iterations, "static_accuracy": self.accuracy}

    def step(self, state: FabricState, load):
        """Solve the step under `load` = (warp value, weft value) from `state` (not modified);
        returns (new state, record) (`dynfab.solver.Solver`) or raises SolverError."""
        model = self.model
        start = model.start_of_step(state, load)
        pos, anchors, P = start.positions, start.anchors, start.chain_loads
        self._newton_count = 0
        info, limit, outer = self.solve(pos, P, anchors)
        if not info.converged:
            raise SolverError(self._failure(pos, P, anchors, info, outer))
        info, limit, outer, escapes, checked = self._certified(pos, P, anchors, info, limit,
                                                               outer)
        stability = patch_stability(checked, info.residual, escapes)
        check_patch_accuracy(model, checked, stability, pos, info.residual, self.tolerance,
                             self.accuracy, info.at_floor, "static.accuracy")
        fields = dict(residual=[info.residual], iterations=[info.iterations],
                      friction_solves=[outer], rounding_floor=[info.at_floor],
                      negative_eigenvalues=[checked.negatives], **stability.fields())
        return model.finish_step(state, start, StepSolution(pos, limit, fields))

    def _worst_crossing(self, pos, P, anchors) -> tuple[int, float]:
        """(c, force [N]): the crossing whose two nodes carry the largest component of the
        unilateral law's residual at `pos` (F_T from the law)."""
        f = self.fabric
        grad = self.gradient(pos, P, anchors, self.friction_limits(pos))
        force = np.where(f.fixed.reshape(-1, 2), 0.0, np.abs(grad)).max(axis=1)
        worst = np.maximum(force[f.tie_a], np.where(f.tie_b >= 0, force[np.maximum(f.tie_b, 0)],
                                                    0.0))
        c = int(np.argmax(worst))
        return c, float(worst[c])

    def _failure(self, pos, P, anchors, info: NewtonInfo, outer: int) -> str:
        """The one line of a step that reached no state consistent with the laws, naming
        the crossing to blame and the residual reached (docs/model.md section 4)."""
        f, tolerance = self.fabric, self.tolerance
        reached = f"residual {info.residual:.3g} N, tolerance {tolerance:.3g} N"
        if info.reason == CYCLING_REASON:
            return (f"fabric: crossing {self.model.crossing_name(info.crossing)} keeps opening and "
                    f"closing at g = 0, where Gralen's friction limit jumps by beta*ell*r_f = "
                    f"{f.tie_friction_law[info.crossing, 1]:.3g} N (R_0 = {scene_onset(f):.3g} N); no "
                    f"open/closed state consistent with the contact and friction laws was "
                    f"found ({reached})")
        if info.reason == ONSET_REASON:
            return (f"fabric: crossing {self.model.crossing_name(info.crossing)} at the friction onset "
                    f"(R_0 = {scene_onset(f):.3g} N): no open/closed state consistent with the "
                    f"contact and friction laws was found, also by continuation in R_0 from "
                    f"{CONTINUATION_START:.3g} N ({info.iterations} Newton iterations, at most "
                    f"{FALLBACK_BUDGET} x static.max_iterations; {reached})")
        c, force = self._worst_crossing(pos, P, anchors)
        return (f"fabric: no convergence ({info.iterations} Newton iterations, {outer} friction "
                f"solves); {reached}; the largest residual at a crossing: {force:.3g} N at "
                f"crossing {self.model.crossing_name(c)}")

    def _certified(self, pos, P, anchors, info, limit, outer):
        """The step's certificate (`dynfab.certificate.certify_patch`), and the escape from a
        saddle (`dynfab.certificate.escape_patch`, docs/model.md section 6), in place: from
        an escape the step is solved again and certified again, at most MAX_ESCAPES times.
        If no direction lowers the energy the state is accepted and reported as a saddle.
        Returns (info, F_T, solves, escapes, certificate)."""
        escapes = 0
        while True:
            self.say("stability check (inertia of the Hessian)")
            checked = certify_patch(self.model, pos, anchors, limit)
            if checked.negatives == 0 or escapes == MAX_ESCAPES:
                return info, limit, outer, escapes, checked
            escaped = escape_patch(self.model, pos, P, anchors, limit, checked)
            if escaped is None:
                return info, limit, outer, escapes, checked
            pos[:, :] = escaped
            escapes += 1
            iterations = info.iterations
            info, limit, more = self.solve(pos, P, anchors)
            info.iterations += iterations
            outer += more
            if not info.converged:
                return info, limit, outer, escapes, checked

    def run(self, state: FabricState | None = None):
        """Every load step of the model in sequence; returns (final state, records)."""
        return run_load_path(self, state)

