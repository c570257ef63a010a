"""Exact sensitivities of a load path's equilibria to scene parameters (docs/model.md, "Fitting").

At the converged state x^n of load step n (anchors xi^{n-1} held, docs/model.md section 4)
the coupled residual r(x, xi, p) = dV/dx (friction's F_T taken from the
current contact forces) vanishes on the free dofs. Differentiating along the
path,

    J dx^n/dp = -(dr/dp + dr/dxi dxi^{n-1}/dp),

J the exact coupled Jacobian at x^n (`assembly.hessian(coupled=True)`, not
the shifted or secant-modified matrix Newton may have factored last); one
banded solve per parameter and step. The right side is the derivative of r at
FIXED state along (dp = 1, dxi = dxi^{n-1}/dp): a central difference of the
residual function with step h = EPS^(1/3) x the parameter's scale. r is linear
in the anchors and in EA, EI, alpha, beta ell r_f, k_t (exact but for
rounding); through the contact law (Kawabata K, C, the weft spring) its
truncation error is O(h^2) ~ 1e-11 relative, at the rounding level
(tests/test_fit_sensitivity.py shows both).

The history is carried by the return map: a crossing that slides in step n
has xi^n = x_{n_j} - sign(s) F_T / k_t, so

    dxi^n/dp = dx_{n_j}/dp - sign(s) d(F_T/k_t)/dp,
    dF_T/dp = dF_T/dz dz_{n_j}/dp + dF_T/dp|_x,

dF_T/dz read from the coupled Jacobian (the coupling entry minus the
symmetric one, so it follows the friction law in dynfab/model/terms/friction.py),
the explicit part again a central difference at fixed state; a sticking
crossing keeps dxi^n/dp = dxi^{n-1}/dp. The result is the derivative of the
discrete curve wherever the stick/slip and open/closed sets are the same at
p and nearby; where a set switches within a step the curve has a kink and
this is one of its one-sided derivatives.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numba
import numpy as np
from scipy.linalg import solve_banded

from dynfab.model import assembly
from dynfab.linalg.banded import BANDWIDTH, constrain, lu_factor, lu_solve
from dynfab.model.domain import check_not_folded
from dynfab.errors import UserError
from dynfab.model.yarn import initial_state
from dynfab.model.builders import build_model
from dynfab.solvers.static import StaticSolver
from dynfab.model.terms import friction

EPS = np.finfo(np.float64).eps
RELATIVE_STEP = EPS ** (1.0 / 3.0)
"""Central-difference step of the residual in a parameter, relative to its scale: balances the
O(h^2) truncation against the O(EPS/h) rounding (both ~ 4e-11 relative)."""

OBSERVABLES = ("end_displacement", "end_force", "crimp")
"""Per-step observables whose sensitivities are computed (the measured columns a curve may have)."""


@dataclass
class PathSolution:
    """A solved load path of one yarn: what the sensitivities need, and the observables."""

    scene: object
    model: object
    load: np.ndarray
    """The load path (steps,) [N or m]."""
    positions: list = field(default_factory=list)
    """Converged positions x^n per step (N+1, 2) [m]."""
    anchors_before: list = field(default_factory=list)
    """Anchors xi^{n-1} held during step n (C,) [m]."""
    sliding: list = field(default_factory=list)
    """Sliding flags per step (C,) bool, after the return map."""
    closed: list = field(default_factory=list)
    """Closed contacts per step (C,) bool (g > 0)."""
    observables: dict = field(default_factory=dict)
    """name -> (steps,) array, for every name of OBSERVABLES."""


def set_key(scene, dotted_key: str, value: float):
    """A copy of `scene` with one numeric key set WITHOUT validation (a finite-difference
    neighbour, e.g. alpha - h below 0, is never run, only evaluated)."""
    table_name, _, name = dotted_key.partition(".")
    table = getattr(scene, table_name)
    if table is None or not hasattr(table, name):
        raise UserError(f"{dotted_key}: the scene has no such key")
    return replace(scene, **{table_name: replace(table, **{name: float(value)})})


def solve_path(scene, solver_options: dict | None = None) -> PathSolution:
    """Solve the scene's load path with the static solver from the as-woven state (one yarn);
    a step that folds the yarn back raises SolverError (`dynfab.model.domain`)."""
    model = build_model(scene)
    if model.yarn_count != 1:
        raise UserError(f"a fit takes one simulated yarn; the scene has {model.yarn_count} "
                         "(set geometry.yarns = 1 and remove any [sweep])")
    solver = StaticSolver(model, **(solver_options or {}))
    state = initial_state(model)
    solution = PathSolution(scene=scene, model=model, load=np.asarray(model.load_values, float))
    values = {name: [] for name in OBSERVABLES}
    yarn = model.yarns[0]
    for load_value in solution.load:
        before = model.per_crossing(state.anchors)[0]
        state, record = solver.step(state, float(load_value))
        check_not_folded([record["positions"]], ["the yarn"])  # a folded yarn is no fit: the trial is refused
        pos = record["positions"][0]
        solution.positions.append(pos)
        solution.anchors_before.append(before)
        solution.sliding.append(np.asarray(record["sliding"][0], bool).copy())
        solution.closed.append(_closed(pos, yarn))
        for name in OBSERVABLES:
            values[name].append(float(record[name][0]))
    solution.observables = {name: np.asarray(v) for name, v in values.items()}
    return solution


def _closed(pos, yarn) -> np.ndarray:
    """g_j > 0 per crossing (the contact tangent is positive exactly there)."""
    c = yarn.crossing_node.size
    R, limit, tangent = np.zeros(c), np.zeros(c), np.zeros(c)
    assembly.contact_state(pos, yarn, R, limit, tangent)
    return tangent > 0.0


def parameter_scale(scene, dotted_key: str, value: float) -> float:
    """The scale a central-difference step is relative to: |value|, or at 0 a typical size.

    At 0: an amplitude takes the segment length L/N [m] (the residual is nonlinear in it);
    every other key that may be 0 enters the residual linearly (alpha, beta, ell, r_f, g, the
    weft tension through eq. 4), where any step is exact, and takes 1.
    """
    if value != 0.0:
        return abs(value)
    if dotted_key.endswith("amplitude"):
        return scene.geometry.length / scene.geometry.segments
    return 1.0


def path_sensitivities(solution: PathSolution, keys, values=None,
                       observables=OBSERVABLES) -> dict:
    """d(observable)/dp (steps, len(keys)) of each of `observables`, along the solved path.

    `values` are the parameters' current values (default: the scene's). The
    scene of `solution` must hold them already (it is the one solved).
    """
    scene, model = solution.scene, solution.model
    yarn = model.yarns[0]
    if values is None:
        values = [_get_key(scene, key) for key in keys]
    steps_h = [RELATIVE_STEP * parameter_scale(scene, k, v) for k, v in zip(keys, values)]
    plus = [_yarn_at(scene, k, v + h) for k, v, h in zip(keys, values, steps_h)]
    minus = [_yarn_at(scene, k, v - h) for k, v, h in zip(keys, values, steps_h)]
    fixed = model.fixed_dofs()
    force_control = model.control == "force"
    n_par, c = len(keys), yarn.crossing_node.size
    d_anchor = np.zeros((n_par, c))
    out = {name: np.zeros((solution.load.size, n_par)) for name in OBSERVABLES}
    want_crimp = "crimp" in observables
    for step, (pos, anchors) in enumerate(zip(solution.positions, solution.anchors_before)):
        P = float(solution.load[step]) if force_control else 0.0
        coupled, symmetric, limit = _jacobians(pos, yarn, anchors)
        factors = coupled.copy()
        rhs = np.zeros((n_par, pos.size))
        explicit_row_end = np.zeros(n_par)
        explicit_limit = np.zeros((n_par, c))
        for k in range(n_par):
            _explicit(pos, anchors, d_anchor[k], P, plus[k], minus[k], steps_h[k], rhs[k],
                      explicit_limit[k])
            explicit_row_end[k] = rhs[k, -2]
        rhs *= -1.0
        dx = _solve(factors, rhs, fixed)
        _observe(out, step, pos, dx, symmetric, explicit_row_end, force_control, want_crimp)
        d_anchor = _carry_anchors(pos, yarn, anchors, limit, coupled, symmetric, dx,
                                  explicit_limit, d_anchor)
    return {name: out[name] for name in observables}


def _yarn_at(scene, dotted_key: str, value: float):
    """The yarn of the scene with one key set (unvalidated: a difference neighbour)."""
    return build_model(set_key(scene, dotted_key, value)).yarns[0]


def _get_key(scene, dotted_key: str) -> float:
    table_name, _, name = dotted_key.partition(".")
    return float(getattr(getattr(scene, table_name), name))


def _jacobians(pos, yarn, anchors):
    """(coupled J, symmetric Hessian, F_T) at the converged state, unconstrained, banded."""
    c = yarn.crossing_node.size
    R, limit, tangent = np.zeros(c), np.zeros(c), np.zeros(c)
    assembly.contact_state(pos, yarn, R, limit, tangent)
    n = pos.size
    coupled = np.zeros((n, 2 * BANDWIDTH + 1))
    symmetric = np.zeros((n, 2 * BANDWIDTH + 1))
    assembly.hessian(pos, yarn, anchors, limit, tangent, True, coupled, False)
    assembly.hessian(pos, yarn, anchors, limit, tangent, False, symmetric, False)
    return coupled, symmetric, limit


@numba.njit(cache=True)
def _residual(pos, yarn, P, anchors, grad, slip_limit):
    """r(x, xi, p) into grad: the coupled residual dV/dx [N] with F_T from the current contact
    forces; F_T / k_t per crossing [m] into slip_limit."""
    c = yarn.crossing_node.size
    R, tangent = np.zeros(c), np.zeros(c)
    assembly.contact_state(pos, yarn, R, slip_limit, tangent)
    assembly.gradient(pos, yarn, P, anchors, slip_limit, grad)
    if yarn.active[friction.INDEX]:
        slip_limit /= yarn.stick_stiffness


@numba.njit(cache=True)
def _explicit(pos, anchors, d_anchor, P, yarn_plus, yarn_minus, h, dr, dlimit):
    """Central difference at FIXED x along (dp = 1, dxi = d_anchor): dr [N] and d(F_T/k_t)|_x."""
    c = anchors.size
    g_plus, g_minus = np.zeros_like(pos), np.zeros_like(pos)
    t_plus, t_minus = np.zeros(c), np.zeros(c)
    _residual(pos, yarn_plus, P, anchors + h * d_anchor, g_plus, t_plus)
    _residual(pos, yarn_minus, P, anchors - h * d_anchor, g_minus, t_minus)
    dr[:] = (g_plus.ravel() - g_minus.ravel()) / (2.0 * h)
    dlimit[:] = (t_plus - t_minus) / (2.0 * h)


def _solve(band, rhs, fixed):
    """dx (n_par, n) with J dx = rhs on the free dofs, 0 on the fixed ones (one LU, O(N))."""
    rhs = rhs.copy()
    work = band.copy()
    first = rhs[0] if rhs.shape[0] else np.zeros(band.shape[0])
    constrain(work, first, fixed)
    for k in range(1, rhs.shape[0]):
        rhs[k][fixed] = 0.0
    if lu_factor(work) < 0:
        for k in range(rhs.shape[0]):
            lu_solve(work, rhs[k])
        return rhs
    # A pivot that is not positive (an indefinite J under compression): pivoted banded LU.
    work = band.copy()
    constrain(work, np.zeros(band.shape[0]), fixed)
    n = band.shape[0]
    ab = np.zeros((2 * BANDWIDTH + 1, n))
    for offset in range(-BANDWIDTH, BANDWIDTH + 1):
        rows = np.arange(max(0, -offset), min(n, n - offset))
        ab[BANDWIDTH - offset, rows + offset] = work[rows, offset + BANDWIDTH]
    return solve_banded((BANDWIDTH, BANDWIDTH), ab, rhs.T).T


def _observe(out, step, pos, dx, symmetric, explicit_row_end, force_control, want_crimp):
    """Observable sensitivities of one step from dx (n_par, n)."""
    n = pos.size
    end_x = n - 2
    if force_control:
        out["end_displacement"][step] = dx[:, end_x]
    else:
        # Reaction dV/dx_N (no load term, no friction at the end node): its row of the Hessian.
        cols = np.arange(max(0, end_x - BANDWIDTH), min(n, end_x + BANDWIDTH + 1))
        row = symmetric[end_x, cols - end_x + BANDWIDTH]
        out["end_force"][step] = dx[:, cols] @ row + explicit_row_end
    if want_crimp:
        out["crimp"][step] = _crimp_derivative(pos, dx)


def _crimp_derivative(pos, dx):
    """d crimp = d(arc)/proj - arc d(proj)/proj^2 of crimp = (arc - proj)/proj (model.crimp)."""
    edges = np.diff(pos, axis=0)
    lengths = np.hypot(edges[:, 0], edges[:, 1])
    arc, proj = lengths.sum(), pos[-1, 0] - pos[0, 0]
    d = dx.reshape(dx.shape[0], -1, 2)
    d_edges = np.diff(d, axis=1)
    d_arc = (d_edges * (edges / lengths[:, None])[None]).sum(axis=(1, 2))
    d_proj = d[:, -1, 0] - d[:, 0, 0]
    return d_arc / proj - arc * d_proj / proj ** 2


@numba.njit(cache=True)
def _carry_anchors(pos, yarn, anchors, limit, coupled, symmetric, dx, explicit_limit, d_anchor):
    """dxi^n/dp: the return map's derivative on sliding crossings, unchanged on sticking ones."""
    new = d_anchor.copy()
    if not yarn.active[friction.INDEX]:
        return new
    k_t = yarn.stick_stiffness
    for j in range(yarn.crossing_node.size):
        node = yarn.crossing_node[j]
        slip = pos[node, 0] - anchors[j]
        if not friction.is_sliding(slip, limit[j], k_t):
            continue
        sign = np.sign(slip)
        x, z = 2 * node, 2 * node + 1
        # coupling entry of J = sign(s) dF_T/dz (friction.add_limit_coupling)
        dlimit_dz = sign * (coupled[x, z - x + BANDWIDTH] - symmetric[x, z - x + BANDWIDTH])
        for k in range(new.shape[0]):
            dlimit = dlimit_dz * dx[k, z] / k_t + explicit_limit[k, j]
            new[k, j] = dx[k, x] - sign * dlimit
    return new
