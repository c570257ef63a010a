"""The static reference solver: Newton on the exact banded Hessian (docs/model.md section 6).

Each load step minimises V plus the Huber friction terms over the free dofs,
from the previous state. Friction is solved coupled: at every iteration F_T
is re-evaluated from the current contact forces (Gralen's law), and the
Newton matrix carries the derivative of F_T through R on sliding crossings
(`friction.add_limit_coupling`), so the converged state satisfies Gralen's
law exactly and convergence stays quadratic. Steps are globalised by a
backtracking line search on the energy with F_T frozen; when the energy
change is lost in rounding, a step is accepted if it lowers the residual
(docs/model.md section 6). An indefinite matrix (compression, exact bending) is shifted
by a multiple of the identity until its LU pivots are positive.
"""

from __future__ import annotations

import numba
import numpy as np
import scipy.linalg

from dynfab import assembly
from dynfab.active_set import (CONTINUATION_FACTORS, CONTINUATION_START, DIRECT_ITERATIONS,
                               DIRECT_SET_UPDATES, MAX_FLIPS, MAX_SET_UPDATES, onset_stages,
                               update_set)
from dynfab.banded import BANDWIDTH, band_add, constrain, lu_factor, lu_solve
from dynfab.certificate import (MAX_ESCAPES, NEGATIVES, StepStability, certify_yarn, check_accuracy,
                                escape_yarn)
from dynfab.errors import SolverError
from dynfab.step import StepSolution
from dynfab.terms import contact, friction

CONVERGED, ROUNDING_FLOOR, STALLED, MAX_ITERATIONS, CYCLING, ONSET_FAILED = range(6)
"""Outcomes of `newton`, in info[STATUS]."""
RESIDUAL, ITERATIONS, STATUS, DETAIL = range(4)
"""Fields of `newton`'s info array; DETAIL is the cycling crossing or the last shift."""

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
    c = yarn.crossing_node.size
    force, limit, tangent = np.zeros(c), np.zeros(c), np.zeros(c)
    assembly.contact_state(pos, yarn, force, limit, tangent, branch)
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
    on its branch (`dynfab.terms.contact`), a smooth problem (docs/model.md section 4).
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


def _natural_set(pos, yarn) -> np.ndarray:
    """The open/closed set the unilateral law gives at `pos`: CLOSED where g > 0."""
    return np.where(_closures(pos, yarn) > 0.0, contact.CLOSED, contact.OPEN).astype(np.int64)


@numba.njit(cache=True)
def _natural_residual(pos, yarn, P, anchors, fixed):
    """The residual [N] of the unilateral law (no set) at `pos`, F_T from the law."""
    c = yarn.crossing_node.size
    force, limit, tangent = np.zeros(c), np.zeros(c), np.zeros(c)
    grad = np.zeros_like(pos)
    assembly.contact_state(pos, yarn, force, limit, tangent)
    assembly.gradient(pos, yarn, P, anchors, limit, grad)
    return max_free(grad, fixed)


def _update_set(pos, yarn, branch, seen) -> np.ndarray:
    """`update_set` at the closures of `pos`."""
    return update_set(_closures(pos, yarn), branch, seen)


@numba.njit(cache=True)
def _set_state(pos, yarn, P, anchors, fixed, branch, grad, band):
    """Residual [N] (grad filled) and, in band, the coupled Jacobian with fixed dofs
    constrained, of the fixed-set problem; returns (residual, rounding floor [N])."""
    c = yarn.crossing_node.size
    force, limit, tangent = np.zeros(c), np.zeros(c), np.zeros(c)
    assembly.contact_state(pos, yarn, force, limit, tangent, branch)
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


def _solve_set(pos, yarn, P, fixed, anchors, tolerance, max_iterations, info, branch,
               max_updates=None, final=True, energy_first=False) -> int:
    """Newton on fixed sets, updating the set between solves until it is consistent.

    A solve that ends short of the tolerance still updates the set (its state shows
    which crossings are on the wrong branch), as long as the state is finite. Returns
    -1 on success (converged, set consistent); an intermediate stage, not `final`, is only
    the next stage's start and always succeeds. Else the crossing to blame
    (the last one switched, or the one nearest to g = 0), info holding the last Newton
    outcome.
    """
    seen = {branch.tobytes()}
    iterations = 0
    blame = 0
    for _ in range(MAX_SET_UPDATES if max_updates is None else max_updates):
        SET_NEWTON(pos, yarn, P, fixed, anchors, tolerance, max_iterations, info, branch,
                   energy_first)
        iterations += int(info[ITERATIONS])
        info[ITERATIONS] = iterations
        converged = int(info[STATUS]) in (CONVERGED, ROUNDING_FLOOR)
        nearest = int(np.argmin(np.abs(_closures(pos, yarn))))
        if not np.isfinite(info[RESIDUAL]):
            return nearest
        if converged and _natural_residual(pos, yarn, P, anchors, fixed) <= tolerance:
            # consistent to within the tolerance: the crossings the set contradicts sit so
            # near g = 0 that the unilateral law's forces differ by less than it
            info[RESIDUAL] = _natural_residual(pos, yarn, P, anchors, fixed)
            return -1
        switched = _update_set(pos, yarn, branch, seen)
        if switched is None:  # every set the updates propose was tried
            if not final:
                return -1
            info[STATUS] = CYCLING
            return blame
        if switched.size == 0:
            return -1 if converged or not final else nearest
        blame = int(switched[-1])
    if not final:
        return -1
    info[STATUS] = CYCLING
    return blame


def _continuation(pos, yarn, P, fixed, anchors, tolerance, max_iterations, info) -> int:
    """Solve with R_0 lowered from CONTINUATION_START to the scene's value, each stage from
    the last one's state and set (docs/model.md section 4); returns -1 or the crossing to blame.

    R_0 falls by a factor per stage, CONTINUATION_FACTORS[0]; if the last stage fails,
    the whole continuation is redone from the step's start with the next, finer factor.
    """
    target = yarn.friction_onset
    start = pos.copy()
    iterations, blame = 0, 0
    for factor in CONTINUATION_FACTORS:
        pos[:, :] = start
        branch = _natural_set(pos, yarn)
        for onset in onset_stages(target, factor):
            blame = _solve_set(pos, yarn._replace(friction_onset=onset), P, fixed, anchors,
                               tolerance, max_iterations, info, branch,
                               final=onset == target)
            iterations += int(info[ITERATIONS])
        info[ITERATIONS] = iterations
        if blame < 0:
            return -1
    return blame


def newton(pos, yarn, P, fixed, anchors, tolerance, max_iterations, info):
    """Solve one load step in place from `pos`; outcome in info (RESIDUAL, ITERATIONS, STATUS, DETAIL).

    `P` is the end load [N] (0 under displacement control, x_N then fixed in
    `fixed` and set by the caller). `anchors` stay fixed (incremental form).

    With friction and an onset force R_0 > 0 (docs/model.md section 4) the open/closed set of
    the crossings is held fixed during each Newton solve and updated between
    solves until it agrees with the state (`_solve_set`); if that fails from the
    previous state, the step is solved again from it by continuation in R_0, from
    CONTINUATION_START down to the scene's value, each stage from the last. The
    final state is consistent with the set, so the unilateral law gives the same
    forces and F_T equals the law at the solution's R. If the continuation fails
    too, the step is solved from the previous state by the semismooth Newton with
    the contact forces as unknowns (`_solve_semismooth`), which reaches states the
    set updates cannot (a crossing with R < R_0 next to one that is open; docs/model.md,
    "Decisions", friction onset). DETAIL of a
    failure names the crossing. Without it, one Newton solve on the unilateral law, stopped as
    CYCLING when a crossing keeps opening and closing.
    """
    if not (yarn.active[friction.INDEX] and yarn.friction_onset > 0.0 and yarn.crossing_node.size > 0):
        _newton_on_set(pos, yarn, P, fixed, anchors, tolerance, max_iterations, info, None)
        return
    start = pos.copy()
    branch = _natural_set(pos, yarn)
    if _solve_set(pos, yarn, P, fixed, anchors, tolerance, min(max_iterations, DIRECT_ITERATIONS),
                  info, branch, DIRECT_SET_UPDATES, energy_first=True) < 0:
        return
    pos[:, :] = start
    iterations = int(info[ITERATIONS])
    blame = _continuation(pos, yarn, P, fixed, anchors, tolerance, max_iterations, info)
    info[ITERATIONS] += iterations
    if blame < 0:
        return
    iterations, residual = int(info[ITERATIONS]), info[RESIDUAL]
    pos[:, :] = start
    if _solve_semismooth(pos, yarn, P, fixed, anchors, tolerance, max_iterations, info):
        info[ITERATIONS] += iterations
        return
    pos[:, :] = start
    info[RESIDUAL], info[ITERATIONS] = residual, iterations
    info[STATUS], info[DETAIL] = ONSET_FAILED, blame


class StaticSolver:
    """Solves a model's load steps one after another with `newton` (docs/model.md section 6).

    Every converged step is certified (`dynfab.certificate`): a saddle is left along a
    direction of negative curvature and solved again (at most MAX_ESCAPES times), and the
    step's position error bound must be within `accuracy` of its displacements.
    `certify=False` skips the escape (the step still reports its stability). `status`, if
    given, is called as status(text) after each yarn of a step (its Newton iterations and
    residual): a yarn's Newton runs compiled (numba), in milliseconds, and cannot report.
    """

    name = "static"

    def __init__(self, model, *, tolerance: float | None = None, max_iterations: int | None = None,
                 accuracy: float | None = None, certify: bool = True, status=None):
        self.model = model
        self.status = status
        self.tolerance = model.scene.static.tolerance if tolerance is None else tolerance
        self.max_iterations = (model.scene.static.max_iterations if max_iterations is None
                               else max_iterations)
        self.accuracy = model.scene.static.accuracy if accuracy is None else accuracy
        self.certify = certify
        self.fixed = model.fixed_dofs()

    def attrs(self) -> dict:
        """Root attributes describing the solver, for the result file."""
        return {"solver": self.name, "static_tolerance": self.tolerance,
                "static_max_iterations": self.max_iterations, "static_accuracy": self.accuracy}

    def step(self, state, load_value: float):
        """Relax every yarn under `load_value`; returns (new state, record) or raises SolverError."""
        start = self.model.start_of_step(state, load_value)
        yarns = self.model.yarn_count
        positions = start.positions.reshape(yarns, -1, 2).copy()  # solved in place, yarn by yarn
        P = load_value if self.model.control == "force" else 0.0
        info = np.zeros(4)
        residual, iterations = np.zeros(yarns), np.zeros(yarns, np.int64)
        at_floor, stability = np.zeros(yarns, np.bool_), StepStability(yarns)
        for k, yarn in enumerate(self.model.yarns):
            result, iterations[k], stability.buckled[k] = self._solve_certified(
                positions[k], k, yarn, P, state.anchors[k], info)
            residual[k] = info[RESIDUAL]
            at_floor[k] = info[STATUS] == ROUNDING_FLOOR
            stability.record(k, result, residual[k])
            check_accuracy(f"yarn {k + 1}", stability.error_estimate[k],
                           stability.scale(positions[k], yarn.rest_position), residual[k],
                           self.tolerance, self.accuracy, at_floor[k], "float64",
                           "static.accuracy", stability.shift[k])
            if self.status is not None:
                self.status(f"yarn {k + 1} of {yarns} solved, {iterations[k]} Newton "
                            f"iterations, residual {residual[k]:.3g} N")
        fields = {"residual": residual, "iterations": iterations, "rounding_floor": at_floor,
                  **stability.fields()}
        return self.model.finish_step(state, start,
                                      StepSolution(positions.reshape(-1, 2), None, fields))


    def _solve_certified(self, pos, k: int, yarn, P: float, anchors, info):
        """`newton` on yarn k in place, certified: from a saddle, escape (`dynfab.certificate`)
        and solve again, at most MAX_ESCAPES times. Returns (certificate, Newton iterations,
        whether a saddle was left); info holds the last solve's outcome."""
        newton(pos, yarn, P, self.fixed, anchors, self.tolerance, self.max_iterations, info)
        _raise_on_failure(info, k, yarn, self.tolerance)
        iterations, buckled = int(info[ITERATIONS]), False
        result, directions = certify_yarn(pos, yarn, anchors, self.fixed, info[RESIDUAL])
        for _ in range(MAX_ESCAPES if self.certify else 0):
            if result[NEGATIVES] <= 0:
                break
            escaped = escape_yarn(pos, yarn, P, anchors, result, directions)
            if escaped is None:
                break
            pos[:, :], buckled = escaped, True
            newton(pos, yarn, P, self.fixed, anchors, self.tolerance, self.max_iterations, info)
            _raise_on_failure(info, k, yarn, self.tolerance)
            iterations += int(info[ITERATIONS])
            result, directions = certify_yarn(pos, yarn, anchors, self.fixed, info[RESIDUAL])
        return result, iterations, buckled


def _raise_on_failure(info, yarn_index: int, yarn, tolerance: float) -> None:
    """SolverError with one clear line unless the step converged (or met the rounding floor)."""
    status, residual = int(info[STATUS]), info[RESIDUAL]
    where = f"yarn {yarn_index + 1}"
    if status in (CONVERGED, ROUNDING_FLOOR):
        return
    if status == CYCLING:
        j = int(info[DETAIL])
        raise SolverError(
            f"{where}: crossing {j + 1} (node {yarn.crossing_node[j]}) keeps opening and closing at "
            f"g = 0, where Gralen's friction limit jumps by beta*ell*r_f = {yarn.friction_constant:.3g} N; "
            f"no state consistent with the friction law was found (residual {residual:.3g} N)")
    if status == ONSET_FAILED:
        j = int(info[DETAIL])
        raise SolverError(
            f"{where}: crossing {j + 1} (node {yarn.crossing_node[j]}) at the friction onset "
            f"(R_0 = {yarn.friction_onset:.3g} N): no open/closed state consistent with the "
            f"contact and friction laws was found, also by continuation in R_0 from "
            f"{CONTINUATION_START:.3g} N and by the semismooth Newton on the contact forces "
            f"(residual {residual:.3g} N)")
    if not np.isfinite(residual):
        raise SolverError(f"{where}: the residual became {residual} (non-finite state)")
    reason = {STALLED: "line search stalled above the rounding floor",
              MAX_ITERATIONS: f"no convergence in {int(info[ITERATIONS])} Newton iterations"}[status]
    raise SolverError(f"{where}: {reason}; residual {residual:.3g} N, tolerance {tolerance:.3g} N")

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
    the onset it finds the sticking crossings in fewer iterations (10 against 30 on the
    first friction step of runs/paper_fig5.toml, `benchmarks/static.py`).
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


SET_NEWTON = _newton_set_polished


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
    iterations, converged = _semismooth(pos, yarn, P, fixed, anchors, R, tolerance,
                                        min(max_iterations, SEMISMOOTH_ITERATIONS))
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
            more, converged = _semismooth(pos, yarn, P, fixed, anchors, R, tolerance,
                                          min(max_iterations, SEMISMOOTH_ITERATIONS))
            iterations += more
            if converged:
                break
    if converged:
        info[RESIDUAL] = _natural_residual(pos, yarn, P, anchors, fixed)
        info[ITERATIONS], info[STATUS] = iterations, CONVERGED
    return converged
