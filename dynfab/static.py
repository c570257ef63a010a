"""The static reference solver: Newton on the exact banded Hessian (MODEL.md section 6).

Each load step minimises V plus the Huber friction terms over the free dofs,
from the previous state. Friction is solved coupled: at every iteration F_T
is re-evaluated from the current contact forces (Gralen's law), and the
Newton matrix carries the derivative of F_T through R on sliding crossings
(`friction.add_limit_coupling`), so the converged state satisfies Gralen's
law exactly and convergence stays quadratic. Steps are globalised by a
backtracking line search on the energy with F_T frozen; when the energy
change is lost in rounding, a step is accepted if it lowers the residual
(MODEL.md 6). An indefinite matrix (compression, exact bending) is shifted
by a multiple of the identity until its LU pivots are positive.
"""

from __future__ import annotations

import numba
import numpy as np

from dynfab import assembly
from dynfab.banded import BANDWIDTH, constrain, lu_factor, lu_solve
from dynfab.certificate import (MAX_ESCAPES, NEGATIVES, StepStability, certify_yarn, check_accuracy,
                                escape_yarn)
from dynfab.errors import SolverError
from dynfab.observables import finish_step

CONVERGED, ROUNDING_FLOOR, STALLED, MAX_ITERATIONS, CYCLING = range(5)
"""Outcomes of `newton`, in info[STATUS]."""
RESIDUAL, ITERATIONS, STATUS, DETAIL = range(4)
"""Fields of `newton`'s info array; DETAIL is the cycling crossing or the last shift."""

EPS = np.finfo(np.float64).eps
MAX_FLIPS = 12
"""Open/closed switches of one crossing after which the iteration is declared cycling."""


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
def _total_energy(pos, yarn, P, anchors, friction_limit, terms):
    assembly.energies(pos, yarn, P, anchors, friction_limit, terms)
    return terms.sum()


@numba.njit(cache=True)
def _line_search(pos, direction, slope, residual, yarn, P, anchors, friction_limit, fixed,
                 trial, grad, terms, halvings):
    """Backtrack on the energy (F_T frozen) from step 1, at most `halvings` times; returns the
    accepted step or 0.

    Armijo: E(t) <= E(0) + 1e-4 t slope. Where |E(t) - E(0)| is within the rounding
    of the energy sum, the energy cannot judge: accept if the residual falls.
    """
    e0 = _total_energy(pos, yarn, P, anchors, friction_limit, terms)
    rounding = 64.0 * EPS * (np.abs(terms).sum() + abs(P) * abs(pos[-1, 0]))
    d = direction.reshape(pos.shape)
    t = 1.0
    for _ in range(halvings):
        trial[:, :] = pos + t * d
        e1 = _total_energy(trial, yarn, P, anchors, friction_limit, terms)
        if e1 - e0 <= 1e-4 * t * slope:
            return t
        if abs(e1 - e0) <= rounding:
            assembly.gradient(trial, yarn, P, anchors, friction_limit, grad)
            if max_free(grad, fixed) < residual:
                return t
        t *= 0.5
    return 0.0


@numba.njit(cache=True)
def newton(pos, yarn, P, fixed, anchors, tolerance, max_iterations, info):
    """Solve one load step in place from `pos`; outcome in info (RESIDUAL, ITERATIONS, STATUS, DETAIL).

    `P` is the end load [N] (0 under displacement control, x_N then fixed in
    `fixed` and set by the caller). `anchors` stay fixed (incremental form).
    """
    n = pos.size
    c = yarn.crossing_node.size
    grad, trial = np.zeros_like(pos), np.empty_like(pos)
    band, work = np.zeros((n, 2 * BANDWIDTH + 1)), np.zeros((n, 2 * BANDWIDTH + 1))
    direction, terms = np.zeros(n), np.zeros(6)
    contact_force, friction_limit, tangent = np.zeros(c), np.zeros(c), np.zeros(c)
    was_closed, flips = np.zeros(c, np.bool_), np.zeros(c, np.int64)
    previous = np.inf
    cut = False  # the last step was shortened: use the secant friction stiffness
    info[STATUS], info[DETAIL] = MAX_ITERATIONS, 0.0
    for iteration in range(max_iterations + 1):
        assembly.contact_state(pos, yarn, contact_force, friction_limit, tangent)
        assembly.gradient(pos, yarn, P, anchors, friction_limit, grad)
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
            if yarn.has_friction and flips[j] > MAX_FLIPS:
                info[STATUS], info[DETAIL] = CYCLING, j
                return
        assembly.hessian(pos, yarn, anchors, friction_limit, tangent, True, band, cut)
        floor = 4.0 * EPS * np.abs(band[:, BANDWIDTH]).max() * np.abs(pos).max()
        if residual <= floor and residual > 0.5 * previous:
            info[STATUS] = ROUNDING_FLOOR
            return
        previous = residual
        info[DETAIL] = _shifted_direction(band, work, grad, fixed, direction)
        slope = np.dot(grad.ravel(), direction)
        if not slope < 0.0:  # the coupling made it uphill for the frozen energy: drop it
            assembly.hessian(pos, yarn, anchors, friction_limit, tangent, False, band, cut)
            info[DETAIL] = _shifted_direction(band, work, grad, fixed, direction)
            slope = np.dot(grad.ravel(), direction)
        # At the rounding floor a Newton step can only be lost in rounding: a few halvings
        # tell, sixty would only cost time.
        t = _line_search(pos, direction, slope, residual, yarn, P, anchors, friction_limit,
                         fixed, trial, grad, terms, 8 if residual <= floor else 60)
        if t == 0.0:
            info[STATUS] = ROUNDING_FLOOR if residual <= floor else STALLED
            return
        pos[:, :] = trial
        cut = t < 1.0


class StaticSolver:
    """Solves a model's load steps one after another with `newton` (MODEL.md section 6).

    Every converged step is certified (`dynfab.certificate`): a saddle is left along a
    direction of negative curvature and solved again (at most MAX_ESCAPES times), and the
    step's position error bound must be within `accuracy` of its displacements.
    `certify=False` skips the escape (the step still reports its stability).
    """

    name = "static"

    def __init__(self, model, *, tolerance: float | None = None, max_iterations: int | None = None,
                 accuracy: float | None = None, certify: bool = True):
        self.model = model
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
        positions = prescribe_load(self.model, state, load_value)
        P = load_value if self.model.control == "force" else 0.0
        info = np.zeros(4)
        yarns = self.model.yarn_count
        residual, iterations = np.zeros(yarns), np.zeros(yarns, np.int64)
        at_floor, stability = np.zeros(yarns, np.bool_), StepStability(yarns)
        for k, yarn in enumerate(self.model.yarns):
            result, iterations[k], stability.buckled[k] = self._solve_certified(
                positions[k], k, yarn, P, state.anchors[k], info)
            residual[k] = info[RESIDUAL]
            at_floor[k] = info[STATUS] == ROUNDING_FLOOR
            stability.record(k, result, residual[k])
            check_accuracy(k, stability.error_estimate[k],
                           stability.scale(positions[k], yarn.rest_position), residual[k],
                           self.tolerance, self.accuracy, at_floor[k], "float64",
                           "static.accuracy", stability.shift[k])
        new_state, record = finish_step(self.model, state, positions, load_value, residual,
                                        iterations)
        record["rounding_floor"] = at_floor
        record.update(stability.fields())
        return new_state, record


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


def prescribe_load(model, state, load_value: float) -> np.ndarray:
    """The starting positions of a load step: the previous state, and under displacement
    control x_N = x0_N + u with the increment spread linearly along the yarn (a better guess)."""
    positions = state.positions.copy()
    if model.control == "displacement":
        rest = model.stacked("rest_position")
        length = rest[:, -1:, 0]
        increment = load_value - (positions[:, -1, 0] - rest[:, -1, 0])
        positions[:, :, 0] += increment[:, None] * rest[:, :, 0] / length
        positions[:, -1, 0] = rest[:, -1, 0] + load_value
    return positions


def _raise_on_failure(info, yarn_index: int, yarn, tolerance: float) -> None:
    """SolverError with one clear line unless the step converged (or met the rounding floor)."""
    status, residual = int(info[STATUS]), info[RESIDUAL]
    where = f"yarn {yarn_index}"
    if status in (CONVERGED, ROUNDING_FLOOR):
        return
    if status == CYCLING:
        j = int(info[DETAIL])
        raise SolverError(
            f"{where}: crossing {j + 1} (node {yarn.crossing_node[j]}) keeps opening and closing at "
            f"g = 0, where Gralen's friction limit jumps by beta*ell*r_f = {yarn.friction_constant:.3g} N; "
            f"no state consistent with the friction law was found (residual {residual:.3g} N)")
    if not np.isfinite(residual):
        raise SolverError(f"{where}: the residual became {residual} (non-finite state)")
    reason = {STALLED: "line search stalled above the rounding floor",
              MAX_ITERATIONS: f"no convergence in {int(info[ITERATIONS])} Newton iterations"}[status]
    raise SolverError(f"{where}: {reason}; residual {residual:.3g} N, tolerance {tolerance:.3g} N")
