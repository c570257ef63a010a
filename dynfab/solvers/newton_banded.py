"""The static solver's banded backend: Newton on each chain's exact banded Hessian
(docs/model.md section 6), where every tie is to ground and the chains are independent (the
paper's yarns: `dynfab.model.structure.grounded`).

Each chain (a `dynfab.model.yarn.Yarn` view of the structure) is solved on its own, in numba:
the load step minimises V plus the Huber friction terms over the free dofs, from the
previous state. Friction is solved coupled: at every iteration F_T is re-evaluated from the
current contact forces (Gralen's law), and the Newton matrix carries the derivative of F_T
through R on sliding crossings (`friction.add_limit_coupling`), so the converged state
satisfies Gralen's law exactly and convergence stays quadratic. Steps are globalised by a
backtracking line search on the energy with F_T frozen; when the energy change is lost in
rounding, a step is accepted if it lowers the residual (docs/model.md section 6). An
indefinite matrix (compression, exact bending) is shifted by a multiple of the identity until
its LU pivots are positive.

Its strategies in the friction chain (`dynfab.solvers.friction_chain`): without friction or with
R_0 = 0, "unilateral" (`_newton_on_set` on the unilateral law, stopped as cycling when a
crossing keeps opening and closing); with R_0 > 0, "sets" and "continuation" (the shared
active set, `dynfab.solvers.active_set`, each set solved by `_newton_set_polished`) and
"semismooth" (`_solve_semismooth`, the contact forces as unknowns). Its certificate is the
banded LDL^T of `dynfab.solvers.certificate.certify_yarn` per chain.
"""

from __future__ import annotations

from typing import NamedTuple

import numba
import numpy as np
import scipy.linalg

from dynfab.model import assembly
from dynfab.solvers.active_set import MAX_FLIPS
from dynfab.linalg.banded import BANDWIDTH, band_add, constrain, lu_factor, lu_solve
from dynfab.solvers.certificate import NEGATIVES, certify_yarn, check_accuracy, escape_yarn
from dynfab.model.yarn import Yarn, chain_view
from dynfab.solvers.newton_backend import NewtonBackend
from dynfab.solvers.newton_info import CYCLING as CYCLING_REASON
from dynfab.solvers.newton_info import STALLED as STALLED_REASON
from dynfab.solvers.newton_info import Budget, NewtonInfo
from dynfab.model.step import StepSolution, StepStart
from dynfab.model.structure import chain_count, chain_nodes, chain_ties, dim
from dynfab.model.terms import contact, friction, registry

CONVERGED, ROUNDING_FLOOR, STALLED, MAX_ITERATIONS, CYCLING = range(5)
"""Outcomes of `_newton_on_set`, in info[STATUS]."""
RESIDUAL, ITERATIONS, STATUS, DETAIL = range(4)
"""Fields of the Newton kernels' info array; DETAIL is the cycling crossing or the last shift."""

EPS = np.finfo(np.float64).eps
COUPLED_FIRST = 20
"""Iterations of the coupled Newton tried first on a fixed set (`_newton_set_polished`)."""
ENERGY_ITERATIONS = 30
"""Newton iterations with the energy line search on a fixed set before the coupled,
pivoted Newton takes over (`_newton_set_polished`)."""


@numba.njit(cache=True)
def max_free(grad, fixed):
    """The residual: largest |component| of the force over the free dofs [N]."""
    flat = grad.ravel()
    worst = 0.0
    for i in range(flat.size):
        if not fixed[i]:
            value = abs(flat[i])
            if not value <= worst:  # NaN propagates
                worst = value
    return worst


@numba.njit(cache=True)
def _shifted_direction(band, work, grad, fixed, direction):
    """direction = -(A + mu I)^-1 grad with the smallest mu >= 0 (x 10 steps) giving positive pivots.

    Returns mu [N/m]; -1 if no shift helps (a NaN in the matrix).
    """
    n = direction.size
    max_diag = 0.0
    for i in range(n):
        max_diag = max(max_diag, abs(band[i, BANDWIDTH]))
    shift = 0.0
    flat = grad.ravel()
    for _ in range(40):
        work[:, :] = band
        for i in range(n):
            direction[i] = -flat[i]
            if not fixed[i]:
                work[i, BANDWIDTH] += shift
        constrain(work, direction, fixed)
        if lu_factor(work) < 0:
            lu_solve(work, direction)
            return shift
        shift = max(10.0 * shift, 1e-10 * max_diag)
    return -1.0


@numba.njit(cache=True)
def _total_energy(pos, yarn, P, anchors, friction_limit, terms, branch=None):
    assembly.energies(pos, yarn, P, anchors, friction_limit, terms, branch)
    return terms.sum()


@numba.njit(cache=True)
def _line_search(pos, direction, slope, residual, yarn, P, anchors, friction_limit, fixed,
                 trial, grad, terms, halvings, branch=None):
    """Backtrack on the energy (F_T frozen) from step 1, at most `halvings` times; returns the
    accepted step or 0.

    Armijo: E(t) <= E(0) + 1e-4 t slope. Where |E(t) - E(0)| is within the rounding
    of the energy sum, the energy cannot judge: accept if the residual falls.
    """
    e0 = _total_energy(pos, yarn, P, anchors, friction_limit, terms, branch)
    rounding = 64.0 * EPS * (np.abs(terms).sum() + abs(P) * abs(pos[-1, 0]))
    d = direction.reshape(pos.shape)
    t = 1.0
    for _ in range(halvings):
        trial[:, :] = pos + t * d
        e1 = _total_energy(trial, yarn, P, anchors, friction_limit, terms, branch)
        if e1 - e0 <= 1e-4 * t * slope:
            return t
        if abs(e1 - e0) <= rounding:
            assembly.gradient(trial, yarn, P, anchors, friction_limit, grad, branch)
            if max_free(grad, fixed) < residual:
                return t
        t *= 0.5
    return 0.0


@numba.njit(cache=True)
def _free_norm(grad, fixed):
    """The 2-norm of the force over the free dofs [N]."""
    flat = grad.ravel()
    total = 0.0
    for i in range(flat.size):
        if not fixed[i]:
            total += flat[i] * flat[i]
    return np.sqrt(total)


@numba.njit(cache=True)
def _residual_line_search(pos, direction, yarn, P, anchors, fixed, trial, grad, branch,
                          halvings):
    """Backtrack from step 1 on the residual's 2-norm with F_T re-evaluated at each trial
    (the coupled problem's merit, docs/model.md section 4); returns the accepted step or 0.

    Accepts |f(t)| <= (1 - 1e-4 t) |f(0)|: the coupled Newton direction is a descent
    direction of |f|^2 where the Jacobian is exact.
    """
    force, limit, tangent = assembly.contact_state_of(pos, yarn, branch)
    assembly.gradient(pos, yarn, P, anchors, limit, grad, branch)
    norm0 = _free_norm(grad, fixed)
    d = direction.reshape(pos.shape)
    t = 1.0
    for _ in range(halvings):
        trial[:, :] = pos + t * d
        assembly.contact_state(trial, yarn, force, limit, tangent, branch)
        assembly.gradient(trial, yarn, P, anchors, limit, grad, branch)
        if _free_norm(grad, fixed) <= (1.0 - 1e-4 * t) * norm0:
            return t
        t *= 0.5
    return 0.0


@numba.njit(cache=True)
def _newton_on_set(pos, yarn, P, fixed, anchors, tolerance, max_iterations, info, branch):
    """Newton on one load step from `pos`, in place; outcome in info.

    `branch` None: the unilateral contact, with the open/closed flip count that
    detects cycling (the literal jump law). `branch` an array: each crossing held
    on its branch (`dynfab.model.terms.contact`), a smooth problem (docs/model.md section 4).
    """
    n = pos.size
    c = yarn.crossing_node.size
    grad, trial = np.zeros_like(pos), np.empty_like(pos)
    band, work = np.zeros((n, 2 * BANDWIDTH + 1)), np.zeros((n, 2 * BANDWIDTH + 1))
    direction, terms = np.zeros(n), assembly.energy_vector()
    contact_force, friction_limit, tangent = np.zeros(c), np.zeros(c), np.zeros(c)
    was_closed, flips = np.zeros(c, np.bool_), np.zeros(c, np.int64)
    previous = np.inf
    cut = False  # the last step was shortened: use the secant friction stiffness
    info[STATUS], info[DETAIL] = MAX_ITERATIONS, 0.0
    for iteration in range(max_iterations + 1):
        assembly.contact_state(pos, yarn, contact_force, friction_limit, tangent, branch)
        assembly.gradient(pos, yarn, P, anchors, friction_limit, grad, branch)
        residual = max_free(grad, fixed)
        info[RESIDUAL], info[ITERATIONS] = residual, iteration
        if residual <= tolerance:
            info[STATUS] = CONVERGED
            return
        if iteration == max_iterations or not np.isfinite(residual):
            return
        for j in range(c):
            closed = tangent[j] > 0.0
            if iteration > 0 and closed != was_closed[j]:
                flips[j] += 1
            was_closed[j] = closed
            if yarn.active[friction.INDEX] and flips[j] > MAX_FLIPS:
                info[STATUS], info[DETAIL] = CYCLING, j
                return
        assembly.hessian(pos, yarn, anchors, friction_limit, tangent, True, band, cut, branch)
        floor = 4.0 * EPS * np.abs(band[:, BANDWIDTH]).max() * np.abs(pos).max()
        if residual <= floor and residual > 0.5 * previous:
            info[STATUS] = ROUNDING_FLOOR
            return
        previous = residual
        info[DETAIL] = _shifted_direction(band, work, grad, fixed, direction)
        slope = np.dot(grad.ravel(), direction)
        if not slope < 0.0:  # the coupling made it uphill for the frozen energy: drop it
            assembly.hessian(pos, yarn, anchors, friction_limit, tangent, False, band, cut, branch)
            info[DETAIL] = _shifted_direction(band, work, grad, fixed, direction)
            slope = np.dot(grad.ravel(), direction)
        # At the rounding floor a Newton step can only be lost in rounding: a few halvings
        # tell, sixty would only cost time.
        t = _line_search(pos, direction, slope, residual, yarn, P, anchors, friction_limit,
                         fixed, trial, grad, terms, 8 if residual <= floor else 60, branch)
        if t == 0.0:
            info[STATUS] = ROUNDING_FLOOR if residual <= floor else STALLED
            return
        pos[:, :] = trial
        cut = t < 1.0


@numba.njit(cache=True)
def _closures(pos, yarn):
    """g_j [m] of every crossing."""
    g = np.zeros(yarn.crossing_node.size)
    for j in range(g.size):
        g[j] = contact.closure(pos, yarn.crossing_node[j], yarn.crossing_side[j], yarn.gap_offset[j])
    return g



@numba.njit(cache=True)
def _natural_residual(pos, yarn, P, anchors, fixed):
    """The residual [N] of the unilateral law (no set) at `pos`, F_T from the law."""
    _, limit, _ = assembly.contact_state_of(pos, yarn)
    grad = np.zeros_like(pos)
    assembly.gradient(pos, yarn, P, anchors, limit, grad)
    return max_free(grad, fixed)


@numba.njit(cache=True)
def _set_state(pos, yarn, P, anchors, fixed, branch, grad, band):
    """Residual [N] (grad filled) and, in band, the coupled Jacobian with fixed dofs
    constrained, of the fixed-set problem; returns (residual, rounding floor [N])."""
    _, limit, tangent = assembly.contact_state_of(pos, yarn, branch)
    assembly.gradient(pos, yarn, P, anchors, limit, grad, branch)
    assembly.hessian(pos, yarn, anchors, limit, tangent, True, band, False, branch)
    floor = 4.0 * EPS * np.abs(band[:, BANDWIDTH]).max() * np.abs(pos).max()
    rhs = -grad.ravel().copy()
    constrain(band, rhs, fixed)
    return max_free(grad, fixed), floor, rhs


def _pivoted_solve(band, rhs):
    """A x = rhs by banded LU with partial pivoting (LAPACK gbsv): the coupled Jacobian is
    not symmetric, and near the friction onset its unpivoted LU meets non-positive pivots,
    whose shift would spoil the Newton step. None if A is singular."""
    n, u = rhs.size, BANDWIDTH
    ab = np.zeros((2 * u + 1, n))
    for k in range(-u, u + 1):  # ab[u + i - j, j] = A[i, j], A[i, j] = band[i, j - i + u]
        if k >= 0:
            ab[u - k, k:] = band[:n - k, u + k]
        else:
            ab[u - k, :n + k] = band[-k:, u + k]
    try:
        return scipy.linalg.solve_banded((u, u), ab, rhs, check_finite=False)
    except np.linalg.LinAlgError:
        return None


def _newton_fixed_set(pos, yarn, P, fixed, anchors, tolerance, max_iterations, info, branch):
    """Newton on the fixed-set problem (smooth but for the Huber stick/slip switch), in place.

    The coupled Jacobian (friction limit through R) solved with pivoting; steps judged by
    the residual's 2-norm with F_T re-evaluated (`_residual_line_search`). Outcome in info
    as `_newton_on_set`.
    """
    grad, trial = np.zeros_like(pos), np.empty_like(pos)
    band = np.zeros((pos.size, 2 * BANDWIDTH + 1))
    previous = np.inf
    info[STATUS], info[DETAIL] = MAX_ITERATIONS, 0.0
    for iteration in range(max_iterations + 1):
        residual, floor, rhs = _set_state(pos, yarn, P, anchors, fixed, branch, grad, band)
        info[RESIDUAL], info[ITERATIONS] = residual, iteration
        if residual <= tolerance:
            info[STATUS] = CONVERGED
            return
        if iteration == max_iterations or not np.isfinite(residual):
            return
        if residual <= floor and residual > 0.5 * previous:
            info[STATUS] = ROUNDING_FLOOR
            return
        previous = residual
        direction = _pivoted_solve(band, rhs)
        if direction is None:
            info[STATUS] = STALLED
            return
        t = _residual_line_search(pos, direction, yarn, P, anchors, fixed, trial, grad, branch,
                                  8 if residual <= floor else 60)
        if t == 0.0:
            info[STATUS] = ROUNDING_FLOOR if residual <= floor else STALLED
            return
        pos[:, :] = trial


def _newton_set_polished(pos, yarn, P, fixed, anchors, tolerance, max_iterations, info, branch,
                         energy_first=False):
    """Newton on the fixed-set problem.

    First `_newton_fixed_set` (the coupled Newton, pivoted, residual merit: quadratic
    near the solution, where a continuation stage or set update starts). If it fails,
    from the same start, `_newton_on_set` (energy line search with the secant friction
    stiffness, robust far from the solution) for ENERGY_ITERATIONS, then
    `_newton_fixed_set` again: the frozen-energy direction is of little use where the
    friction limit's slope near the onset is large. With `energy_first` (a step's first
    attempt, from the previous step's state), `_newton_on_set` comes first: away from
    the onset it finds the sticking crossings in fewer iterations (docs/results.md, "The
    energy line search first").
    """
    start = pos.copy()
    iterations = 0
    if energy_first:
        _newton_on_set(pos, yarn, P, fixed, anchors, tolerance, max_iterations, info, branch)
    else:
        _newton_fixed_set(pos, yarn, P, fixed, anchors, tolerance,
                          min(max_iterations, COUPLED_FIRST), info, branch)
    if int(info[STATUS]) in (CONVERGED, ROUNDING_FLOOR):
        return
    iterations = int(info[ITERATIONS])
    if energy_first and np.isfinite(info[RESIDUAL]):
        _newton_fixed_set(pos, yarn, P, fixed, anchors, tolerance, max_iterations, info, branch)
        info[ITERATIONS] += iterations
        return
    pos[:, :] = start
    _newton_on_set(pos, yarn, P, fixed, anchors, tolerance, min(max_iterations, ENERGY_ITERATIONS),
                   info, branch)
    iterations += int(info[ITERATIONS])
    if int(info[STATUS]) in (CONVERGED, ROUNDING_FLOOR) or not np.isfinite(info[RESIDUAL]):
        info[ITERATIONS] = iterations
        return
    _newton_fixed_set(pos, yarn, P, fixed, anchors, tolerance, max_iterations, info, branch)
    info[ITERATIONS] += iterations



# --------------------------------------------------------------------------
# Semismooth Newton with the contact forces as unknowns (docs/model.md sections 3-4).

SEMISMOOTH_ITERATIONS = 200
"""Newton iterations of one semismooth solve (`_semismooth`)."""
BRACKET_GROWTH = 4.0
"""Factor by which the held contact force grows while bracketing the root (`_onset_root`)."""
BRACKET_STEPS = 40
"""Held forces tried while bracketing, then bisection/secant steps on the bracket."""
ONSET_ROOTS = 4
"""Crossings treated one after another by `_onset_root` before giving up."""


def _semismooth_state(pos, yarn, P, anchors, R, hold):
    """Force residual (grad, F_T from max(R, 0)) and the min-form complementarity
    Phi_j = min(R_j, k_0 (c(R_j) - g_j)) [N] at (pos, R); crossing `hold` (>= 0) has its
    R prescribed (Phi 0). Returns grad, F_T, g, c(R), Phi, k_0."""
    c = R.size
    law = yarn.contact_law
    k0 = contact.tangent(0.0, law)
    limit = np.array([friction.limit(max(r, 0.0), yarn.friction_alpha, yarn.friction_constant,
                                     yarn.friction_onset) for r in R])
    grad = np.zeros_like(pos)
    assembly.gradient(pos, yarn, P, anchors, limit, grad, np.full(c, contact.OPEN, np.int64))
    grad[yarn.crossing_node, 1] -= yarn.crossing_side * R
    g = _closures(pos, yarn)
    cR = np.array([contact.closure_from_force(r, law) for r in R])
    phi = np.minimum(R, k0 * (cR - g))
    if hold >= 0:
        phi[hold] = 0.0
    return grad, limit, g, cR, phi, k0


def _semismooth_merit(grad, phi, fixed):
    """sqrt(|force over the free dofs|^2 + |Phi|^2) [N]."""
    f = grad.ravel()[~fixed]
    return np.sqrt(f @ f + phi @ phi)


def _semismooth_system(pos, yarn, anchors, R, hold, state, band):
    """The semismooth Newton matrix with the dR_j eliminated, and its right side.

    Per crossing, the active branch of Phi_j: closed (k_0 (c(R) - g) < R) linearises
    c(R) = g, dR = t (dg - r) with t = 1/c'(R), r = c(R) - g (smooth for R of either
    sign); open gives dR = -R. dR enters the z force (-s dR) and, on a sliding crossing,
    the friction force through dF_T/dR (its right limit at R = 0; R stays >= 0).
    Returns (rhs, t, r, closed).
    """
    grad, limit, g, cR, phi, k0 = state
    c = R.size
    law = yarn.contact_law
    assembly.hessian(pos, yarn, anchors, limit, np.zeros(c), False, band, False,
                     np.full(c, contact.OPEN, np.int64))
    rhs = -grad.ravel().copy()
    t, r, closed = np.zeros(c), np.zeros(c), np.zeros(c, np.bool_)
    for j in range(c):
        if j == hold:
            continue
        n, s = yarn.crossing_node[j], yarn.crossing_side[j]
        slip = pos[n, 0] - anchors[j]
        sliding = friction.is_sliding(slip, limit[j], yarn.stick_stiffness)
        # dF_T/dR from the right at R = 0: R stays >= 0 (`_semismooth`), and a closed
        # crossing at R = 0 can only move into R > 0
        slope = np.sign(slip) * friction.limit_slope(max(R[j], 1e-300), yarn.friction_alpha,
                                                     yarn.friction_constant, yarn.friction_onset)
        if R[j] > k0 * (cR[j] - g[j]):
            closed[j], t[j], r[j] = True, contact.tangent(R[j], law), cR[j] - g[j]
            band_add(band, 2 * n + 1, 2 * n + 1, t[j])
            rhs[2 * n + 1] -= s * t[j] * r[j]
            if sliding:
                band_add(band, 2 * n, 2 * n + 1, -s * slope * t[j])
                rhs[2 * n] += slope * t[j] * r[j]
        else:
            rhs[2 * n + 1] -= s * R[j]
            if sliding:
                rhs[2 * n] += slope * R[j]
    return rhs, t, r, closed


def _semismooth(pos, yarn, P, fixed, anchors, R, tolerance, max_iterations, hold=-1):
    """Semismooth Newton on (positions, R) in place (docs/model.md section 4: "a semismooth Newton
    on the complementarity form"); returns (iterations, converged).

    Unknowns: the free positions and the contact forces R_j; equations: the force balance
    with F_T = F_T(max(R, 0)) and 0 <= R_j perp c(R_j) - g_j >= 0 in min-form. The set of
    closed crossings is the one each iteration's Phi picks (a primal-dual active set).
    Trial forces are projected onto R >= 0 (a closed crossing at R = 0 moves into R > 0,
    with dF_T/dR from the right; without it, closed crossings stalled at R < 0, g ~ 0,
    where F_T(max(R, 0)) gives the Newton matrix no friction to balance), and steps are
    backtracked on the merit |(force, Phi)|. Converged when the unilateral law's
    own residual (R from g, F_T from that R: `_natural_residual`) is within the tolerance,
    so the state is consistent with the laws; with `hold` >= 0 that crossing's R stays
    as given and the criterion is the force and Phi residual instead.
    """
    band = np.zeros((pos.size, 2 * BANDWIDTH + 1))
    for iteration in range(max_iterations + 1):
        state = _semismooth_state(pos, yarn, P, anchors, R, hold)
        grad, phi = state[0], state[4]
        if hold < 0:
            done = _natural_residual(pos, yarn, P, anchors, fixed) <= tolerance
        else:
            done = max(max_free(grad, fixed), np.abs(phi).max()) <= tolerance
        if done:
            return iteration, True
        if iteration == max_iterations or not np.all(np.isfinite(grad)):
            return iteration, False
        rhs, t, r, closed = _semismooth_system(pos, yarn, anchors, R, hold, state, band)
        constrain(band, rhs, fixed)
        direction = _pivoted_solve(band, rhs)
        if direction is None:
            return iteration, False
        d = direction.reshape(pos.shape)
        dz = -yarn.crossing_side * d[yarn.crossing_node, 1]  # dg
        dR = np.where(closed, t * (dz - r), -R)
        if hold >= 0:
            dR[hold] = 0.0
        merit = _semismooth_merit(grad, phi, fixed)
        step = 1.0
        for _ in range(60):
            trial, trial_R = pos + step * d, np.maximum(R + step * dR, 0.0)
            trial_state = _semismooth_state(trial, yarn, P, anchors, trial_R, hold)
            if _semismooth_merit(trial_state[0], trial_state[4], fixed) <= (1.0 - 1e-4 * step) * merit:
                break
            step *= 0.5
        else:
            return iteration, False
        pos[:, :], R[:] = trial, trial_R
    return max_iterations, False


def _contact_forces(pos, yarn):
    """R_j [N] from the unilateral law at `pos`."""
    law = yarn.contact_law
    return np.array([contact.force_from_closure(g, law) for g in _closures(pos, yarn)])


def _onset_root(pos, yarn, P, fixed, anchors, R, tolerance, j):
    """Crossing j's contact force as a scalar root, the others relaxed (docs/model.md section 4), in
    place.

    With R_j held, `_semismooth` relaxes the rest and gives the closure g_j(R_j); the law
    asks c(R_j) = g_j(R_j) with R_j > 0, or g_j(0) <= 0 (open). phi(R_j) = c(R_j) - g_j(R_j)
    rises with R_j (friction lowers the closure, docs/model.md section 4), so a bracket grown from
    R_0 / 100 and then regula falsi alternating with bisection find the root, each
    relaxation from the last. Returns (whether a root or R_j = 0 was found, the Newton
    iterations of all relaxations); the state is then the start of a free `_semismooth`.
    """
    law = yarn.contact_law
    iterations = [0]

    def phi(force):
        R[j] = force
        done, ok = _semismooth(pos, yarn, P, fixed, anchors, R, tolerance, SEMISMOOTH_ITERATIONS, j)
        iterations[0] += done
        return contact.closure_from_force(force, law) - _closures(pos, yarn)[j], ok

    f_low, ok = phi(0.0)
    if not ok:
        return False, iterations[0]
    if f_low >= 0.0:  # open: R_j = 0 is consistent
        return True, iterations[0]
    low, saved = 0.0, (pos.copy(), R.copy())
    high = max(yarn.friction_onset, 1e-12) / 100.0
    for _ in range(BRACKET_STEPS):
        f_high, ok = phi(high)
        if not ok:  # a relaxation too far from the last one: a shorter step from it
            pos[:, :], R[:] = saved
            high = low + 0.25 * (high - low)
            continue
        if f_high >= 0.0:
            break
        low, f_low, saved = high, f_high, (pos.copy(), R.copy())
        high = high * BRACKET_GROWTH
    else:
        return False, iterations[0]
    for k in range(BRACKET_STEPS):
        middle = (0.5 * (low + high) if k % 2 else
                  (low * f_high - high * f_low) / (f_high - f_low))
        state = (pos.copy(), R.copy())
        f_middle, ok = phi(middle)
        if not ok:  # keep the last converged relaxation: the free solve starts from it
            pos[:, :], R[:] = state
            break
        if f_middle < 0.0:
            low, f_low = middle, f_middle
        else:
            high, f_high = middle, f_middle
        if abs(f_middle) * contact.tangent(middle, law) <= tolerance or high - low <= 4 * EPS * high:
            break
    return True, iterations[0]


def _solve_semismooth(pos, yarn, P, fixed, anchors, tolerance, max_iterations, info) -> bool:
    """The onset fallback (docs/model.md section 4), in place: `_semismooth` from the step's start;
    if it stalls, `_onset_root` on the crossing whose complementarity is violated most, then
    `_semismooth` again, at most ONSET_ROOTS times. Returns True when converged (info set)."""
    R = _contact_forces(pos, yarn)
    start, start_R = pos.copy(), R.copy()
    allowed = min(max_iterations, SEMISMOOTH_ITERATIONS)
    iterations, converged = _semismooth(pos, yarn, P, fixed, anchors, R, tolerance, allowed)
    if not converged:
        # the crossings whose complementarity the stalled state violates, worst first, each
        # bracketed from the step's start (the stalled state can sit on a spurious branch)
        phi = np.abs(_semismooth_state(pos, yarn, P, anchors, R, -1)[4])
        phi[~np.isfinite(phi)] = np.inf
        for j in np.argsort(-phi)[:ONSET_ROOTS]:
            pos[:, :], R[:] = start, start_R
            found, more = _onset_root(pos, yarn, P, fixed, anchors, R, tolerance, int(j))
            iterations += more
            if not found:
                continue
            more, converged = _semismooth(pos, yarn, P, fixed, anchors, R, tolerance, allowed)
            iterations += more
            if converged:
                break
    if converged:
        info[RESIDUAL] = _natural_residual(pos, yarn, P, anchors, fixed)
        info[ITERATIONS], info[STATUS] = iterations, CONVERGED
    return converged



# --------------------------------------------------------------------------
# The backend.


class YarnProblem(NamedTuple):
    """One chain's share of a load step (`BandedNewton.problems`)."""

    index: int
    """The chain's index in the structure (the one-yarn model's yarn)."""
    positions: np.ndarray
    """(N+1, 2) [m], solved in place: a view of the step's positions."""
    P: float
    """The end force along the chain [N] (0 under displacement control)."""
    anchors: np.ndarray
    """(C,) [m] the friction anchors of its crossings, held during the step."""
    yarn: Yarn
    fixed: np.ndarray
    """Its held dofs (2 (N+1),) bool."""
    ties: np.ndarray
    """The structure's tie of each of its crossings (C,), int64."""


class YarnCertificate(NamedTuple):
    """`certify_yarn`'s result and the directions of its negative pivots (`escape_yarn`)."""

    result: np.ndarray
    directions: np.ndarray

    @property
    def negatives(self) -> int:
        return int(self.result[NEGATIVES])


def _outcome(info, solves: int = 1) -> NewtonInfo:
    """A Newton kernel's info array as a `NewtonInfo`."""
    status = int(info[STATUS])
    return NewtonInfo(residual=info[RESIDUAL], iterations=int(info[ITERATIONS]),
                      converged=status == CONVERGED or status == ROUNDING_FLOOR,
                      at_floor=status == ROUNDING_FLOOR,
                      crossing=int(info[DETAIL]) if status == CYCLING else -1,
                      reason=(CYCLING_REASON if status == CYCLING else
                              STALLED_REASON if status == STALLED else ""),
                      solves=solves)


class BandedNewton(NewtonBackend):
    """The banded backend of `dynfab.solvers.static.StaticSolver` (module docstring): each chain of
    a grounded structure solved on its own; `dynfab.solvers.newton_backend` states the contract."""

    def __init__(self, model, **options):
        super().__init__(model, **options)
        s = self.structure
        yarns = getattr(model, "yarns", None)
        self.yarns = yarns if yarns is not None else tuple(
            chain_view(s, y, registry.active_mask(model.scene)) for y in range(chain_count(s)))
        """Each chain as the kernels' `Yarn` (the one-yarn model's own views)."""
        d = dim(s)
        self._chains = [(chain_nodes(s, y), chain_ties(s, y)) for y in range(chain_count(s))]
        self._fixed = [s.fixed[d * nodes.start:d * nodes.stop] for nodes, _ in self._chains]
        self._info = np.zeros(4)  # the kernels' info array, reused

    # ------------------------------------------------------------------ the step

    def problems(self, start: StepStart) -> list[YarnProblem]:
        """Each chain's share of the step, its positions a view of a copy of the start's."""
        positions = start.positions.copy()
        return [YarnProblem(y, positions[nodes], float(start.chain_loads[y]),
                            start.anchors[ties, 0], self.yarns[y], self._fixed[y], ties)
                for y, (nodes, ties) in enumerate(self._chains)]

    def solution(self, start: StepStart, problems, fields) -> StepSolution:
        """The solved chains as the structure's positions; F_T from them is the model's."""
        positions = np.concatenate([p.positions for p in problems]) if problems else \
            start.positions.copy()
        return StepSolution(positions, None, fields)

    def strategies(self, problem: YarnProblem) -> tuple[str, ...]:
        """"unilateral" without friction or with R_0 = 0; else the active set, its
        continuation and the semismooth Newton (docs/model.md, "Decisions": the friction
        chain)."""
        yarn = problem.yarn
        if not (yarn.active[friction.INDEX] and yarn.crossing_node.size):
            return ("unilateral",)
        if yarn.friction_onset > 0.0:
            return ("sets", "continuation", "semismooth")
        return ("unilateral", "sets")

    # ------------------------------------------------------------------ strategies

    def unilateral(self, problem: YarnProblem, budget: Budget) -> NewtonInfo:
        """`_newton_on_set` on the unilateral law (CYCLING names the crossing)."""
        p, info = problem, self._info
        _newton_on_set(p.positions, p.yarn, p.P, p.fixed, p.anchors, self.tolerance,
                       self.max_iterations, info, None)
        return _outcome(info)

    def semismooth(self, problem: YarnProblem, budget: Budget) -> NewtonInfo:
        """`_solve_semismooth` from the step's start (not begun where the budget is spent)."""
        p, info = problem, self._info
        if not budget.spent and _solve_semismooth(p.positions, p.yarn, p.P, p.fixed, p.anchors, self.tolerance,
                             self.max_iterations, info):
            return _outcome(info)
        return NewtonInfo(residual=_natural_residual(p.positions, p.yarn, p.P, p.anchors,
                                                     p.fixed))

    # ------------------------------------------------------------------ active-set primitives

    def _at_onset(self, yarn: Yarn, onset: float) -> Yarn:
        return yarn if onset == yarn.friction_onset else yarn._replace(friction_onset=onset)

    def set_solve(self, problem: YarnProblem, branch, onset: float, max_iterations: int,
                  direct: bool) -> NewtonInfo:
        """`_newton_set_polished` on the set `branch` at R_0 = `onset`; `direct` (from the
        previous step's state): the energy Newton first."""
        p, info = problem, self._info
        _newton_set_polished(p.positions, self._at_onset(p.yarn, onset), p.P, p.fixed,
                             p.anchors, self.tolerance, max_iterations, info, branch, direct)
        return _outcome(info)

    def closures_of(self, problem: YarnProblem) -> np.ndarray:
        return _closures(problem.positions, problem.yarn)

    def law_residual_of(self, problem: YarnProblem, onset: float) -> float:
        p = problem
        return _natural_residual(p.positions, self._at_onset(p.yarn, onset), p.P, p.anchors,
                                 p.fixed)

    def onset(self, problem: YarnProblem) -> float:
        return problem.yarn.friction_onset

    # ------------------------------------------------------------------ failure words

    def group_name(self, problem: YarnProblem) -> str:
        return f"yarn {problem.index + 1}"

    def crossing_name(self, problem: YarnProblem, j: int) -> str:
        """Crossing j of the chain as the model counts it (`crossing_name`), else "tie t"."""
        t = int(problem.ties[j])
        name = getattr(self.model, "crossing_name", None)
        return name(t) if name is not None else f"tie {t + 1}"

    def friction_constant(self, problem: YarnProblem, j: int) -> float:
        return problem.yarn.friction_constant

    def worst_crossing(self, problem: YarnProblem) -> tuple[int, float]:
        """(j, force [N]): the crossing whose node carries the largest free component of the
        unilateral law's residual; (-1, 0) without crossings."""
        p = problem
        if p.yarn.crossing_node.size == 0:
            return -1, 0.0
        _, limit, _ = assembly.contact_state_of(p.positions, p.yarn)
        grad = np.zeros_like(p.positions)
        assembly.gradient(p.positions, p.yarn, p.P, p.anchors, limit, grad)
        per_node = np.where(p.fixed.reshape(-1, 2), 0.0, np.abs(grad)).max(axis=1)
        j = int(np.argmax(per_node[p.yarn.crossing_node]))
        return j, float(per_node[p.yarn.crossing_node[j]])

    # ------------------------------------------------------------------ certificate

    def certify(self, problem: YarnProblem, info: NewtonInfo) -> YarnCertificate:
        """`certify_yarn` at the solution (the banded LDL^T, docs/model.md section 6)."""
        p = problem
        return YarnCertificate(*certify_yarn(p.positions, p.yarn, p.anchors, p.fixed,
                                             info.residual))

    def escape(self, problem: YarnProblem, checked: YarnCertificate):
        p = problem
        return escape_yarn(p.positions, p.yarn, p.P, p.anchors, checked.result,
                           checked.directions)

    def check_accuracy(self, problem: YarnProblem, checked, stability, k: int,
                       info: NewtonInfo) -> None:
        """`dynfab.solvers.certificate.check_accuracy` on the chain's displacements."""
        check_accuracy(f"yarn {k + 1}", stability.error_estimate[k],
                       stability.scale(problem.positions, problem.yarn.rest_position),
                       info.residual, self.tolerance, self.accuracy, info.at_floor, "float64",
                       "static.accuracy", stability.shift[k])
