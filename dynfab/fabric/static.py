"""The fabric's static solver: Newton on the exact sparse Hessian (docs/model.md sections 6, 10).

Each load step minimises V plus the Huber friction terms over the free dofs from the
previous state, to a residual (largest free force component) of `spec.tolerance`, or to
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
`solve`). Then the anchors are return-mapped (radially,
`dynfab.fabric.friction`). The one-yarn solver's open/closed active set, continuation
in R_0 and semismooth fallback are not here (yet): a step neither reaches stops with a
SolverError.

Globalisation (docs/model.md section 6): a backtracking line search on the energy (F_T frozen);
where the energy change is within its rounding, a step that lowers the residual is
accepted. After a shortened step, and to retry a failed one, sliding crossings get the
secant stiffness F_T/|s| I (a quadratic majorant of the Huber term, as in the one-yarn
solver), so a step cannot overshoot a crossing about to stick again. A step reaching
Kawabata's wall (k_c = inf) has energy +inf and is halved. If the Newton direction is not a descent direction (an indefinite Hessian), the matrix
is shifted by mu I, mu growing tenfold from 1e-10 max|diag|, until it is.

Each converged step is checked for stability (`dynfab.fabric.inertia`): the number of
negative eigenvalues of the Hessian with F_T frozen, from the signs of the pivots of
SuperLU's symmetric-mode factorisation (Sylvester's law), or where that is not safe by
Haynsworth's inertia additivity over the per-yarn banded LDL^T blocks (on the small
periodic cell, a dense Bunch-Kaufman LDL^T), and the eigenvalue nearest zero (the smallest
when there is no negative one). From a saddle the step leaves along the lowest
eigenvectors (shift-invert Lanczos below the spectrum, the shift placed by the inertia)
and is solved again (`_certified`), as the one-yarn solver does along its LDL^T's
negative-pivot directions (docs/model.md section 6).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse
import scipy.sparse.linalg

from dynfab.errors import SolverError
from dynfab.fabric import assembly, contact, friction, inertia, ordering
from dynfab.fabric.layout import Fabric, build_fabric
from dynfab.fabric.spec import FabricSpec
from dynfab.terms import friction as gralen

EPS = np.finfo(np.float64).eps
FROZEN_UPDATES = 3
"""Newton solves with F_T frozen per load step before the coupled Newton takes over: the
fixed point on F_T contracts slowly near the friction onset, so a few frozen solves then
the coupled Newton take fewer iterations than more frozen solves (docs/model.md, fabric
decisions); 1 left the coupled Newton too far from the solution on the small-load path of
tests/test_fabric_energy.py."""
MAX_FROZEN = 50
"""Further frozen solves when the coupled Newton fails."""
MAX_ESCAPES = 12
"""Saddles left per load step (docs/model.md section 6) before the state is accepted as it is."""
ESCAPE_CANDIDATES = 16
"""Directions of negative curvature tried per escape (the lowest eigenvectors)."""
HALVINGS = 60
"""Line-search halvings (8 at the rounding floor, where a step is lost in rounding)."""


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
class FabricState:
    """What changes during a run (docs/model.md section 10)."""

    positions: np.ndarray
    """(in-plane coordinate, z) of every node (nodes, 2) [m]."""
    anchors: np.ndarray
    """Friction anchors xi per crossing (C, 2) [m], relative to the as-woven slip."""
    dissipated: float = 0.0
    """Cumulative friction dissipation [J]."""
    work: float = 0.0
    """Work of the end loads, trapezoid rule over the load steps [J]."""
    end_force: np.ndarray | None = None
    """End force along each yarn (Y,) [N]: the load (force control) or the reaction."""

    def copy(self) -> "FabricState":
        return FabricState(self.positions.copy(), self.anchors.copy(), self.dissipated,
                           self.work, None if self.end_force is None else self.end_force.copy())


def as_woven_state(fabric: Fabric) -> FabricState:
    """As woven, anchors at zero slip, nothing dissipated, no end force."""
    pos = fabric.rest_position.copy()
    anchors = np.zeros((fabric.warp_node.size, 2))
    anchors[:, 0] = pos[fabric.warp_node, 0] - fabric.plane_x
    anchors[:, 1] = pos[fabric.weft_node, 0] - fabric.plane_y
    return FabricState(pos, anchors, end_force=np.zeros(fabric.yarn_start.size - 1))


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


class FabricStaticSolver:
    """Solves a fabric's load steps one after another (docs/model.md sections 6, 10)."""

    def __init__(self, spec: FabricSpec):
        self.spec = spec
        self.fabric: Fabric = build_fabric(spec)
        self.pattern = assembly.Pattern(self.fabric)
        self.free = ~self.fabric.fixed
        self.yarns = self.fabric.yarn_start.size - 1
        self._terms = np.zeros(len(assembly.TERMS))

    # ------------------------------------------------------------------ state

    def initial_state(self) -> FabricState:
        """As woven, anchors at zero slip, nothing dissipated (`as_woven_state`)."""
        return as_woven_state(self.fabric)

    def yarn_loads(self, warp_value: float, weft_value: float) -> np.ndarray:
        """The load of each yarn (Y,) [N or m]: the family's value times its factor."""
        f = self.fabric
        return np.where(f.is_warp, warp_value, weft_value) * f.load_factor

    # ------------------------------------------------------------------ pieces

    def contact_forces(self, pos) -> np.ndarray:
        f = self.fabric
        out = np.zeros(f.warp_node.size)
        contact.forces(pos, f.warp_node, f.weft_node, f.side, f.gap_offset, f.contact_law, out)
        return out

    def friction_limits(self, pos) -> np.ndarray:
        """F_T from Gralen's law at the contact forces of `pos` (0 without friction)."""
        f = self.fabric
        out = np.zeros(f.warp_node.size)
        if f.has_friction:
            gralen.limits(self.contact_forces(pos), f.friction_alpha, f.friction_constant,
                          f.friction_onset, out)
        return out

    def energy(self, pos, P, anchors, limit) -> float:
        return assembly.total_energy(pos, self.fabric, P, anchors, limit, self._terms)

    def gradient(self, pos, P, anchors, limit) -> np.ndarray:
        grad = np.zeros_like(pos)
        assembly.gradient(pos, self.fabric, P, anchors, limit, grad)
        return grad

    def hessian(self, pos, anchors, limit, secant=False) -> scipy.sparse.csc_matrix:
        """The Hessian on the free dofs, F_T frozen (`secant`: see `friction.huber_hessian`)."""
        values = np.zeros(self.pattern.size)
        assembly.hessian_values(pos, self.fabric, anchors, limit, values, secant)
        return self.pattern.matrix(values)

    def residual(self, grad) -> float:
        """The largest force component on the unknowns [N] (a tied family's cell length
        carries the sum of its yarns' end forces)."""
        r = np.abs(self.pattern.reduce(grad))
        return float(r.max()) if r.size else 0.0

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

    def _line_search(self, pos, d, slope, residual, P, anchors, limit, halvings):
        """Armijo on the energy from step 1; within its rounding, accept a lower residual."""
        e0 = self.energy(pos, P, anchors, limit)
        rounding = 64.0 * EPS * (np.abs(self._terms).sum()
                                 + assembly.rounding_scale(pos, self.fabric, P, limit))
        t = 1.0
        for _ in range(halvings):
            trial = pos + t * d
            e1 = self.energy(trial, P, anchors, limit)
            if e1 - e0 <= 1e-4 * t * slope:
                return trial, t
            if abs(e1 - e0) <= rounding:
                if self.residual(self.gradient(trial, P, anchors, limit)) < residual:
                    return trial, t
            t *= 0.5
        return None

    def newton(self, pos, P, anchors, limit) -> NewtonInfo:
        """Minimise V + sum H (F_T frozen) from `pos`, in place (docs/model.md section 6)."""
        spec, info = self.spec, NewtonInfo()
        previous = np.inf
        cut = False  # the last step was shortened: the secant friction stiffness
        for iteration in range(spec.max_iterations + 1):
            grad = self.gradient(pos, P, anchors, limit)
            residual = self.residual(grad)
            info.residual, info.iterations = residual, iteration
            if residual <= spec.tolerance:
                info.converged = True
                return info
            if iteration == spec.max_iterations or not np.isfinite(residual):
                return info
            H = self.hessian(pos, anchors, limit, cut)
            floor = 4.0 * EPS * np.abs(H.diagonal()).max() * np.abs(pos).max()
            info.floor = floor
            if residual <= floor and residual > 0.5 * previous:
                info.converged = info.at_floor = True
                return info
            previous = residual
            trial = self._newton_step(pos, grad, H, residual, floor, P, anchors, limit)
            if trial is None and not cut and self.fabric.has_friction:
                cut = True  # a Huber kink in the way: retry on the secant model
                trial = self._newton_step(pos, grad, self.hessian(pos, anchors, limit, True),
                                          residual, floor, P, anchors, limit)
            if trial is None:
                info.converged = info.at_floor = residual <= floor
                return info
            trial, t = trial
            cut = t < 1.0
            pos[:, :] = trial
        return info

    def _newton_step(self, pos, grad, H, residual, floor, P, anchors, limit):
        """(new positions, step length) of a line-searched Newton step on H, or None."""
        g = self.pattern.reduce(grad)
        d_free = self._direction(H, g)
        d = self.pattern.expand(d_free)
        return self._line_search(pos, d.reshape(pos.shape), g @ d_free, residual, P, anchors,
                                 limit, 8 if residual <= floor else HALVINGS)

    def solve(self, pos, P, anchors) -> tuple[NewtonInfo, np.ndarray, int]:
        """Newton solves with F_T frozen, F_T updated between them to the law at the
        solution, until consistent; after FROZEN_UPDATES of them the coupled Newton
        (`coupled_newton`) from where they stand. If that fails, the frozen solves go on
        from the state before it (the fixed point converges, slowly, where the coupled
        Newton's merit stalls at a kink), up to MAX_FROZEN, and the coupled Newton is tried
        again (module docstring). Returns (info, F_T, solves)."""
        limit = self.friction_limits(pos)
        iterations, outer = 0, 0
        for frozen in (FROZEN_UPDATES, MAX_FROZEN):
            for _ in range(frozen):
                outer += 1
                info = self.newton(pos, P, anchors, limit)
                iterations += info.iterations
                if not info.converged:
                    break
                if not self.fabric.has_friction:
                    return info, limit, outer
                limit = self.friction_limits(pos)
                info.residual = self.residual(self.gradient(pos, P, anchors, limit))
                # consistent: the residual with F_T from the law within the tolerance, or
                # within the rounding floor the last solve stopped at
                if info.residual <= max(self.spec.tolerance, info.floor if info.at_floor else 0.0):
                    info.iterations = iterations
                    return info, limit, outer
            if not self.fabric.has_friction:
                break
            start = pos.copy()
            outer += 1
            coupled = self.coupled_newton(pos, P, anchors)
            iterations += coupled.iterations
            if coupled.converged:
                coupled.iterations = iterations
                return coupled, self.friction_limits(pos), outer
            pos[:, :] = start
            limit = self.friction_limits(pos)
        info.iterations = iterations
        info.converged = False
        return info, limit, outer

    def coupling(self, pos, anchors, limit) -> scipy.sparse.csc_matrix:
        """d(dH/ds)/dz through F_T(R(g)) on the free dofs: the non-symmetric part of the
        coupled friction Jacobian (`dynfab.terms.friction.add_limit_coupling` in 2D).

        On a sliding crossing dH/ds = F_T s/|s|, so its rows (x_a, y_b) gain
        (s/|s|) dF_T/dR dR/dg dg/dz with dg/dz_a = -sigma, dg/dz_b = +sigma; sticking
        crossings (dH/ds = k_t s) have none.
        """
        f = self.fabric
        c = f.warp_node.size
        tangent, huber = np.zeros(c), np.zeros((c, 3))
        assembly.crossing_blocks(pos, f, anchors, limit, tangent, huber)
        R = self.contact_forces(pos)
        px, py = assembly.planes(pos, f)
        rows, cols, values = [], [], []
        for i in range(c):
            sx, sy = friction.slip(pos, anchors, f.warp_node, f.weft_node, px, py, i)
            norm = np.hypot(sx, sy)
            if not (tangent[i] > 0.0 and limit[i] > 0.0 and f.stick_stiffness * norm >= limit[i]):
                continue
            slope = gralen.limit_slope(R[i], f.friction_alpha, f.friction_constant,
                                       f.friction_onset) * tangent[i]
            za, zb = 2 * f.warp_node[i] + 1, 2 * f.weft_node[i] + 1
            # rows: J^T (s / |s|), J the slip's Jacobian (its nodes and the plane nodes)
            J = assembly.slip_jacobian(f, i)
            for row, unit in zip(assembly.slip_dofs(f, i), J.T @ np.array([sx, sy]) / norm):
                for col, dg in ((za, -f.side[i]), (zb, f.side[i])):
                    rows.append(row)
                    cols.append(col)
                    values.append(unit * slope * dg)
        index = self.pattern.index
        rows, cols = index[np.array(rows, int)], index[np.array(cols, int)]
        keep = (rows >= 0) & (cols >= 0)
        n = self.pattern.free_count
        return scipy.sparse.csc_matrix((np.array(values)[keep], (rows[keep], cols[keep])),
                                       shape=(n, n))

    def coupled_newton(self, pos, P, anchors) -> NewtonInfo:
        """Newton on the coupled problem (F_T = F_T(R) at every iterate), in place.

        The Jacobian is the Hessian plus `coupling` (not symmetric: SuperLU pivots), and
        steps are backtracked on the 2-norm of the free residual with F_T re-evaluated at
        each trial (docs/model.md section 4's merit for the coupled problem): accepted when it falls
        by 1e-4 t of itself.
        """
        spec, info = self.spec, NewtonInfo()
        previous = np.inf
        for iteration in range(spec.max_iterations + 1):
            limit = self.friction_limits(pos)
            grad = self.gradient(pos, P, anchors, limit)
            residual = self.residual(grad)
            info.residual, info.iterations = residual, iteration
            if residual <= spec.tolerance:
                info.converged = True
                return info
            if iteration == spec.max_iterations or not np.isfinite(residual):
                return info
            H = self.hessian(pos, anchors, limit)
            floor = 4.0 * EPS * np.abs(H.diagonal()).max() * np.abs(pos).max()
            if residual <= floor and residual > 0.5 * previous:
                info.converged = info.at_floor = True
                return info
            previous = residual
            g = self.pattern.reduce(grad)
            d_free = _sparse_solve((H + self.coupling(pos, anchors, limit)).tocsc(), -g,
                                   symmetric=False)
            if d_free is None:
                return info
            d = self.pattern.expand(d_free).reshape(pos.shape)
            norm0, t = np.linalg.norm(g), 1.0
            for _ in range(8 if residual <= floor else HALVINGS):
                trial = pos + t * d
                trial_grad = self.gradient(trial, P, anchors, self.friction_limits(trial))
                if np.linalg.norm(self.pattern.reduce(trial_grad)) <= (1.0 - 1e-4 * t) * norm0:
                    break
                t *= 0.5
            else:
                info.converged = info.at_floor = residual <= floor
                return info
            pos[:, :] = trial
        return info

    # ------------------------------------------------------------------ steps

    def step(self, state: FabricState, warp_value: float, weft_value: float):
        """Solve one load step from `state`; returns (new state, record) or raises SolverError."""
        f, spec = self.fabric, self.spec
        pos, anchors, P = self.start_of_step(state, warp_value, weft_value)
        info, limit, outer = self.solve(pos, P, anchors)
        if not info.converged:
            raise SolverError(
                f"fabric: no convergence ({info.iterations} Newton iterations, {outer} friction "
                f"solves); residual {info.residual:.3g} N, tolerance {spec.tolerance:.3g} N")
        info, limit, outer, escapes, inertia_result, nearest = self._certified(
            pos, P, anchors, info, limit, outer)
        R = self.contact_forces(pos)
        end_force = self._end_force(pos, P, anchors, limit)
        sliding = np.zeros(f.warp_node.size, np.bool_)
        friction_force = np.zeros((f.warp_node.size, 2))
        lost = 0.0
        if f.has_friction:
            px, py = assembly.planes(pos, f)
            lost = friction.return_map(pos, anchors, f.warp_node, f.weft_node, px, py, limit,
                                       f.stick_stiffness, sliding, friction_force)
        u_old = state.positions[f.load_node, 0] - f.rest_position[f.load_node, 0]
        u_new = pos[f.load_node, 0] - f.rest_position[f.load_node, 0]
        work = state.work + float(0.5 * (state.end_force + end_force) @ (u_new - u_old))
        new = FabricState(pos, anchors, state.dissipated + lost, work, end_force)
        record = dict(residual=info.residual, iterations=info.iterations, friction_solves=outer,
                      rounding_floor=info.at_floor, contact_force=R.reshape(spec.warps, spec.wefts),
                      friction_limit=limit.reshape(spec.warps, spec.wefts),
                      sliding=sliding.reshape(spec.warps, spec.wefts), friction_force=friction_force,
                      negative_eigenvalues=inertia_result.negatives,
                      stable=inertia_result.negatives == 0, nearest_eigenvalue=nearest,
                      escapes=escapes,
                      end_force=end_force,
                      end_displacement=u_new, strain=self.strains(pos), crimp=self.crimps(pos))
        return new, record

    def _certified(self, pos, P, anchors, info, limit, outer):
        """The step's stability check, and the escape from a saddle (docs/model.md section 6), in
        place.

        With negative eigenvalues (F_T frozen), the lowest eigenvectors (at most
        ESCAPE_CANDIDATES) are tried as directions: steps of +-t v, t from the patch
        length halving 53 times, and the trial of lowest V + H (beyond its rounding) is
        taken; the step is then solved again and checked again, at most MAX_ESCAPES
        times. If no direction lowers the energy the state is accepted and reported as
        a saddle. Returns (info, F_T, solves, escapes, inertia, nearest eigenvalue)."""
        escapes = 0
        while True:
            result = inertia.inertia(self, pos, anchors, limit)
            nearest = inertia.nearest_eigenvalue(self.hessian(pos, anchors, limit))
            if result.negatives == 0 or escapes == MAX_ESCAPES:
                return info, limit, outer, escapes, result, nearest
            escaped = self._escape(pos, P, anchors, limit, result.negatives, nearest)
            if escaped is None:
                return info, limit, outer, escapes, result, nearest
            pos[:, :] = escaped
            escapes += 1
            iterations = info.iterations
            info, limit, more = self.solve(pos, P, anchors)
            info.iterations += iterations
            outer += more
            if not info.converged:
                return info, limit, outer, escapes, result, nearest

    def _escape(self, pos, P, anchors, limit, negatives, nearest):
        """The trial of lowest V + H along the lowest eigenvectors, or None (no drop)."""
        count = min(negatives, ESCAPE_CANDIDATES, self.pattern.free_count - 1)
        _, vectors = inertia.lowest_eigenvectors(self, pos, anchors, limit, count, nearest)
        e0 = self.energy(pos, P, anchors, limit)
        rounding = 64.0 * EPS * (np.abs(self._terms).sum()
                                 + assembly.rounding_scale(pos, self.fabric, P, limit))
        length = max(self.spec.warp.length, self.spec.weft.length)
        best, best_pos = e0 - rounding, None
        for k in range(count):
            d = self.pattern.expand(vectors[:, k]).reshape(pos.shape)
            t = length
            for _ in range(53):
                for sign in (1.0, -1.0):
                    trial = pos + (sign * t) * d
                    e = self.energy(trial, P, anchors, limit)
                    if e < best - rounding:
                        best, best_pos = e, trial
                t *= 0.5
        return best_pos

    def run(self, state: FabricState | None = None):
        """Every load step of the spec in sequence; returns (final state, records)."""
        state = self.initial_state() if state is None else state
        records = []
        for warp_value, weft_value in zip(*self.spec.loads()):
            state, record = self.step(state, warp_value, weft_value)
            records.append(record)
        return state, records

    def start_of_step(self, state: FabricState, warp_value: float, weft_value: float):
        """(positions, anchors, end loads P [N]) a load step starts from, copies of the state's:
        under force control P is each yarn's load; under displacement control P = 0 and the
        ends are moved to their prescribed displacements (`_prescribe`). Shared by the static
        and the dynamic fabric solvers."""
        loads = self.yarn_loads(warp_value, weft_value)
        pos, anchors = state.positions.copy(), state.anchors.copy()
        if self.spec.control == "force":
            return pos, anchors, loads
        self._prescribe(pos, loads)
        return pos, anchors, np.zeros(self.yarns)

    def _prescribe(self, pos, loads) -> None:
        """Displacement control: u_N = load on each yarn, the increment spread linearly along
        the yarn (a better start than the end node alone)."""
        f = self.fabric
        for y in range(self.yarns):
            a, b = f.yarn_start[y], f.yarn_start[y + 1]
            rest = f.rest_position[a:b, 0]
            increment = loads[y] - (pos[b - 1, 0] - rest[-1])
            pos[a:b, 0] += increment * (rest - rest[0]) / (rest[-1] - rest[0])
            pos[b - 1, 0] = rest[-1] + loads[y]

    def _end_force(self, pos, P, anchors, limit) -> np.ndarray:
        """End force along each yarn [N]: P under force control; under displacement control
        the reaction dV/du_N of the elastic terms."""
        if self.spec.control == "force":
            return np.asarray(P, float).copy()
        grad = self.gradient(pos, np.zeros(self.yarns), anchors, limit)
        return grad[self.fabric.load_node, 0].copy()

    def crimps(self, pos) -> np.ndarray:
        """Mean crimps (warp, weft) [-]: (arc length - projected length) / projected length of
        each yarn (`dynfab.model.crimp`, the projected length its end-to-end extent along
        itself), averaged over the family (docs/model.md section 10)."""
        f = self.fabric
        crimp = np.empty(self.yarns)
        for y in range(self.yarns):
            chain = pos[f.yarn_start[y]:f.yarn_start[y + 1]]
            arc = np.hypot(*np.diff(chain, axis=0).T).sum()
            projected = chain[-1, 0] - chain[0, 0]
            crimp[y] = (arc - projected) / projected
        return np.array([crimp[f.is_warp].mean(), crimp[~f.is_warp].mean()])

    def strains(self, pos) -> np.ndarray:
        """Nominal strains (warp, weft): the mean end displacement of the family's loaded
        yarns over their length (docs/model.md section 10). Under displacement control a yarn of
        factor 0 is held, not loaded, and left out (a pull-out's other warps), unless the whole
        family is; under force control a factor-0 yarn's end is free and counts."""
        f, spec = self.fabric, self.spec
        u = pos[f.load_node, 0] - f.rest_position[f.load_node, 0]
        loaded = (f.load_factor != 0) | (spec.control == "force")
        out = []
        for family, length in ((f.is_warp, spec.warp.length), (~f.is_warp, spec.weft.length)):
            chosen = family & loaded if (family & loaded).any() else family
            out.append(u[chosen].mean() / length)
        return np.array(out)
