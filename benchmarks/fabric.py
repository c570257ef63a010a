"""Benchmark of the woven fabric's solvers (MODEL.md sections 5, 6, 10): cost against patch size.

Run:  python benchmarks/fabric.py [--quick] [--budget SECONDS] [--friction] [--pieces]
      (prints the table, writes benchmarks/fabric.json; --quick: 4 x 4 and 8 x 8 only)

The case: clamped balanced patches of the paper's yarn (`fabric_data.paper_patch_scene`:
pitch 0.1/16 m, k_c = 1e5 N/m), n x n yarns for n = 4 to 64, 8 segments per half-wave
(N = M = 8 n: 2 n (8 n + 1) nodes, about 131,000 dofs at n = 64), frictionless unless
--friction (the paper's friction, in every part but the explicit one, whose numba loop has
none), one load step from the as-woven state under force
control, (warp, weft) = LOAD per yarn, residual tolerance TOLERANCE for every solver.
Per size, in increasing order, in a subprocess of its own (`run_size`) that first runs
every part untimed on a 4 x 4 patch (compiles; loads the numba and Warp caches), then:

1. `explicit_costs`: the explicit time step (Warp, MODEL.md 5) in ns per node and step:
   the grouped layout (the CPU default, scatter order), the same loop in the gather
   order, the node-parallel layout (a GPU's: a launch per stage) and a plain numba loop of
   the same forces (`numba_steps`, the masses the kernels choose), viscous damping, a fixed
   number of steps (aim: Warp at most 1.5x numba); the launch cost per step; |Warp - numba|
   after the same steps.
2. `newton_costs`: the Newton solve alone (the static solver's sparse backend,
   `SparseNewton.equilibrium`: time per Newton iteration); later `static_costs`:
   `StaticSolver.step` whole (Newton and the
   certificate), the certificate (`dynfab.solvers.certificate.certify_patch`: inertia, lowest
   eigenvalue and its bracket, the norm estimate of the error bound) and two of its parts,
   the inertia count and the nearest eigenvalue (MODEL.md 6), each timed on its own.
3. `pcg_costs`: the semi-implicit solver's linear algebra inside Newton (the solver itself
   is part 6); its linear solve ((M/h^2 + H) dx = f, Newton as h -> inf) is measured inside the static
   solver: `PCGNewton`, Newton with its direction by CG preconditioned with each yarn's
   own banded block of H, on the same step; time, CG iterations, fallbacks to SuperLU.
4. `dynamic_costs`: `dynfab.solvers.dynamic.DynamicSolver.step` (kinetic damping, grouped layout)
   on the same step: time per load step, its time steps, the relaxation's time per time step
   (the relaxation alone, `StructureRelaxation.relax`), and the largest position difference
   from the static solution.
5. `newton_pieces` (--pieces): gradient, Hessian assembly, SuperLU (default; symmetric
   mode in the nested-dissection order, the Newton solve's), the factorisation in each
   fill-reducing ordering (the geometric nested dissection of `dynfab.model.fabric.ordering`,
   SuperLU's MMD_AT_PLUS_A and COLAMD: time, fill nnz(L + U), one solve; fitted exponents
   of the factor time and the fill), the inertia (SuperLU's symmetric-mode pivots, else
   the Schur complement) against dense eigenvalues (n <= 8), and the nearest eigenvalue
   through the ordered shift-invert against ARPACK factoring the matrix itself.
6. `semi_costs` (part "semi"): `DynamicSolver.step` with the semi-implicit method on the
   same step: time, time steps, CG iterations per time step, |x - x_static|, its relaxation
   against the Newton solve; the relaxation in the grouped and the node-parallel layout (a
   launch per stage, one run each): us per CG iteration, and the launches' cost.

Timing: time.perf_counter, the fastest of REPEATS runs where one run takes less than
FAST seconds, else one run (warm: the 4 x 4 pass compiled everything). Memory: the
peak resident set (resource.getrusage ru_maxrss) of the size's subprocess, with its
value after the imports and the 4 x 4 pass, so the difference is what the size adds
(Python, numpy, SciPy's SuperLU and Warp's arrays alike, unlike tracemalloc); each part
also records the peak so far, so a size stopped by the budget still gives a lower bound.
Budget: a size whose subprocess runs longer than --budget seconds is stopped; the parts
it finished are kept, the rest and every larger size are recorded as not run.
Exponents: least squares of log(time) on log(nodes) over the sizes measured (aims: at
most 1.1 for a time step, 1.5 for a Newton iteration, nested dissection's bound on a
two-dimensional graph), and over the largest three alone (small patches carry fixed
overheads that flatten the fit).
"""

from __future__ import annotations

import argparse
import json
import math
import os
import platform
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numba
import numpy as np
import scipy
import scipy.linalg
import scipy.sparse
import scipy.sparse.linalg

from dynfab.solvers import certificate
from dynfab.model.fabric import inertia, ordering
from dynfab.solvers.dynamic import DynamicSolver
from dynfab.model.fabric.model import FabricModel
from dynfab.solvers.newton_sparse import SparseNewton, _sparse_solve
from dynfab.kernels.structure_relaxation import StructureRelaxation
from dynfab.kernels.structure_settings import RELATIVE_TOLERANCE
from dynfab.reports.fabric_data import paper_patch_scene
from dynfab.scene import Dynamic
from dynfab.solvers.static import StaticSolver

OUTPUT = Path(__file__).resolve().parent / "fabric.json"
SIZES = (4, 8, 16, 32, 64)
"""n of the n x n patches."""
QUICK_SIZES = (4, 8)
SEGMENTS_PER_HALF_WAVE = 8
LOAD = (0.3, 0.1)
"""(warp, weft) end force per yarn [N] of the load step."""
TOLERANCE = 1e-10
"""Residual tolerance [N] of the static, PCG and dynamic solvers (tests/test_fabric_dynamic.py)."""
PAPER_FRICTION = {"alpha": 0.2, "beta": 1e3, "contact_length": 2e-3, "fiber_radius": 1e-3}
"""The paper's Gralen parameters (docs/model.md section 7), R_0 the default 1e-5 N: the
[friction] table of --friction."""
BUDGET = 120.0
"""Default wall-time budget of one size [s]."""
DAMPING = 0.05
"""Viscous c [1/s] at dt = 1 s (fictitious masses) of the explicit-step runs."""
STEP_WORK = 2e7
"""Node-steps of one timed explicit run (about 1 s at 50 ns per node and step)."""
PER_STEP_WORK = 4e6
"""Node-steps of one timed run of the per-step layout (slower on small patches)."""
WARM_WORK = 2e4
"""Node-steps of the untimed 4 x 4 explicit runs that compile."""
REPEATS = 3
FAST = 2.0
"""A part whose first run takes less than this [s] is repeated REPEATS times."""
CG_RTOL = 1e-12
"""CG's relative residual |H d + g| / |g|: a Newton direction needs far less, but the
line search and the stopping test then see the same steps as SuperLU's."""
CG_MAX = 2000
AIMS = {"explicit_over_numba": 1.5, "exponent_time_step": 1.1, "exponent_newton_iteration": 1.5}
"""The limit of each aim (at most)."""
PARTS = ("explicit", "newton", "pcg", "static", "dynamic", "semi")
"""In the order they run, cheapest first: on large patches the certificate (in the static
and dynamic steps) is the slowest piece."""


def nodes(n: int) -> int:
    """Nodes of the n x n patch: 2 n yarns of 8 n + 1 nodes (MODEL.md 10)."""
    return 2 * n * (SEGMENTS_PER_HALF_WAVE * n + 1)


def patch_model(n: int, friction=None) -> FabricModel:
    """The n x n patch with the load step and tolerance of this benchmark; `friction` a
    [friction] table or None."""
    tables = {} if friction is None else {"friction": friction}
    return FabricModel.from_scene(paper_patch_scene(
        n, n, SEGMENTS_PER_HALF_WAVE,
        load={"control": "force", "values": [LOAD[0]], "weft_values": [LOAD[1]]},
        static={"tolerance": TOLERANCE}, dynamic={"tolerance": TOLERANCE}, **tables))


def timed(function):
    """(fastest wall time [s], last result): REPEATS runs if the first is under FAST s."""
    began = time.perf_counter()
    result = function()
    best = time.perf_counter() - began
    if best < FAST:
        for _ in range(REPEATS - 1):
            began = time.perf_counter()
            result = function()
            best = min(best, time.perf_counter() - began)
    return best, result


# --- 1. The explicit time step: Warp against a plain numba loop of the same forces ---

@numba.njit(cache=True)
def numba_contact(g, law):
    """R(g) [N] of R/k_c + sum_m C_m (1 - exp(-a_m R)) = g, Newton from the lower bound."""
    if g <= 0.0:
        return 0.0
    R = max(0.0, law[0] * (g - law[1] - law[3]))
    for _ in range(64):
        decay_wa, decay_we = math.exp(-law[2] * R), math.exp(-law[4] * R)
        value = R / law[0] + law[1] * (1.0 - decay_wa) + law[3] * (1.0 - decay_we)
        tangent = 1.0 / (1.0 / law[0] + law[1] * law[2] * decay_wa + law[3] * law[4] * decay_we)
        step = (g - value) * tangent
        if not step > 4e-16 * R:
            break
        R += step
    return R


@numba.njit(cache=True)
def numba_forces(pos, nxt, rest_length, stretch, bend, rest_angle, free, cw, cwe, side, offset,
                 law, external, force):
    """force = -dV/dr on the free dofs, scattered term by term (MODEL.md 2, 10)."""
    n = pos.shape[0]
    force[:, :] = external
    for i in range(n):
        j = nxt[i]
        if j < 0:
            continue
        ex, ez = pos[j, 0] - pos[i, 0], pos[j, 1] - pos[i, 1]
        length = math.sqrt(ex * ex + ez * ez)
        t = stretch[i] * (length - rest_length[i]) / length
        force[i, 0] += t * ex
        force[i, 1] += t * ez
        force[j, 0] -= t * ex
        force[j, 1] -= t * ez
        k = nxt[j]
        if k < 0 or bend[j] == 0.0:
            continue
        bx, bz = pos[k, 0] - pos[j, 0], pos[k, 1] - pos[j, 1]
        moment = bend[j] * (math.atan2(ex * bz - ez * bx, ex * bx + ez * bz) - rest_angle[j])
        a2, b2 = ex * ex + ez * ez, bx * bx + bz * bz
        gax, gaz = moment * ez / a2, -moment * ex / a2
        gbx, gbz = -moment * bz / b2, moment * bx / b2
        force[i, 0] += gax
        force[i, 1] += gaz
        force[j, 0] += gbx - gax
        force[j, 1] += gbz - gaz
        force[k, 0] -= gbx
        force[k, 1] -= gbz
    for c in range(cw.shape[0]):
        g = offset[c] - side[c] * (pos[cw[c], 1] - pos[cwe[c], 1])
        R = numba_contact(g, law)
        force[cw[c], 1] += side[c] * R
        force[cwe[c], 1] -= side[c] * R
    for i in range(n):
        force[i, 0] *= free[i, 0]
        force[i, 1] *= free[i, 1]


@numba.njit(cache=True)
def numba_steps(pos, vel, mass, nxt, rest_length, stretch, bend, rest_angle, free, cw, cwe, side,
                offset, law, external, dt, coefficient, steps):
    """`steps` centred viscous symplectic Euler steps; the residual at the last positions."""
    force = np.zeros_like(pos)
    half = 0.5 * coefficient * dt
    residual = 0.0
    for step in range(steps + 1):
        numba_forces(pos, nxt, rest_length, stretch, bend, rest_angle, free, cw, cwe, side, offset,
                     law, external, force)
        residual = np.abs(force).max()
        if step == steps:
            break
        for i in range(pos.shape[0]):
            for c in range(2):
                v = ((1.0 - half) * vel[i, c] + (dt / mass[i]) * force[i, c]) / (1.0 + half)
                vel[i, c] = v
                pos[i, c] += dt * v
    return residual


def warp_run(structure, layout, steps, order="scatter"):
    """Positions after `steps` viscous steps of one Warp layout (fictitious masses, dt = 1 s),
    as a callable."""
    relaxation = StructureRelaxation(structure, damping="viscous", damping_coefficient=DAMPING,
                                     layout=layout, order=order)
    relaxation.check_interval, relaxation.chunk = 1 << 30, steps
    loads = relaxation.chain_loads(LOAD)
    return lambda: relaxation.relax(structure.rest_position, loads, None, tolerance=0.0,
                                    max_steps=steps)[0]


def numba_run(structure, steps):
    """Positions after `steps` steps of the numba loop (the masses the kernels choose at the
    as-woven state), as a callable."""
    relaxation = StructureRelaxation(structure, damping="viscous", damping_coefficient=DAMPING)
    relaxation.start(structure.rest_position, relaxation.chain_loads(LOAD), None)
    mass = relaxation.group_values("mass")
    a = relaxation.arrays
    external = relaxation.node_loads(relaxation.chain_loads(LOAD))
    law = np.ascontiguousarray(a.contact_law[0])  # every tie's: a uniform patch

    def run():
        pos, vel = a.rest_position.copy(), np.zeros_like(a.rest_position)
        numba_steps(pos, vel, mass, a.next, a.rest_length, a.stretch_stiffness,
                    a.bend_stiffness, a.rest_angle, a.free, a.tie_a, a.tie_b, a.tie_side,
                    a.tie_offset, law, external, 1.0, DAMPING, steps)
        return pos
    return run


def explicit_costs(n: int, work: float = STEP_WORK, per_step_work: float = PER_STEP_WORK) -> dict:
    """ns per node and step of the Warp layouts and the numba loop on the n x n patch."""
    structure = patch_model(n).structure
    count, crossings = structure.rest_position.shape[0], structure.tie_a.size
    steps = max(20, int(work / count))
    per_step_steps = max(10, int(per_step_work / count))
    time_grouped, warp_positions = timed(warp_run(structure, "grouped", steps))
    time_numba, numba_positions = timed(numba_run(structure, steps))
    time_gather, _ = timed(warp_run(structure, "grouped", per_step_steps, "gather"))
    time_parallel, _ = timed(warp_run(structure, "node_parallel", per_step_steps, "gather"))
    return {"nodes": count, "crossings": crossings, "steps": steps,
            "per_step_steps": per_step_steps,
            "persistent_ns_per_node_step": 1e9 * time_grouped / (count * steps),
            "numba_ns_per_node_step": 1e9 * time_numba / (count * steps),
            "gather_ns_per_node_step": 1e9 * time_gather / (count * per_step_steps),
            "per_step_ns_per_node_step": 1e9 * time_parallel / (count * per_step_steps),
            "launch_cost_us_per_step": 1e6 * (time_parallel - time_gather) / per_step_steps,
            "persistent_s_per_step": time_grouped / steps,
            "numba_s_per_step": time_numba / steps,
            "persistent_over_numba": time_grouped / time_numba,
            "warp_minus_numba_positions_m": float(np.abs(warp_positions - numba_positions).max()),
            "displacement_m": float(np.abs(warp_positions - structure.rest_position).max())}


# --- 2. The static step: Newton iterations, then the whole step with its certificate ---

def newton_costs(n: int, friction=None):
    """(row, positions): the Newton solve of the load step alone (the static solver's sparse
    backend, `SparseNewton.equilibrium`: the friction chain, no certificate), its time per
    iteration."""
    solver = StaticSolver(patch_model(n, friction))
    start = solver.initial_state()
    P = solver.model.yarn_loads(*LOAD)

    def newton():
        pos, anchors = start.positions.copy(), start.anchors.copy()
        return solver.backend.equilibrium(pos, P, anchors)[0], pos
    newton_s, (info, positions) = timed(newton)
    iterations = int(info.iterations)
    return {"dofs_free": solver.backend.pattern.free_count, "newton_s": newton_s,
            "newton_iterations": iterations, "s_per_newton_iteration": newton_s / max(iterations, 1),
            "residual_N": float(info.residual)}, positions


def static_costs(n: int, friction=None):
    """(row, state, record): StaticSolver.step on the load step (Newton and the
    certificate), the certificate (`dynfab.solvers.certificate.certify_patch`: the inertia, the
    lowest eigenvalue with its proved bracket, est ||H^-1||_inf) on its own at its
    solution, and parts of it timed alone: the inertia count and the nearest eigenvalue
    (MODEL.md 6)."""
    solver = StaticSolver(patch_model(n, friction))
    start = solver.initial_state()
    step_s, (state, record) = timed(lambda: solver.step(start, LOAD))
    limit = solver.backend.friction_limits(state.positions)
    certificate_s, checked = timed(lambda: certificate.certify_patch(
        solver.model, state.positions, state.anchors, limit))
    inertia_s, result = timed(lambda: inertia.inertia(solver.model, state.positions, state.anchors, limit))
    nearest_s, nearest = timed(lambda: inertia.nearest_eigenvalue(
        solver.backend.hessian(state.positions, state.anchors, limit)))
    row = {"step_s": step_s, "step_iterations": int(record["iterations"]),
           "buckled": bool(record["buckled"]), "certificate_s": certificate_s,
           "inertia_s": inertia_s, "nearest_eigenvalue_s": nearest_s,
           "schur_size": result.schur_size, "negative_eigenvalues": int(result.negatives),
           "nearest_eigenvalue_N_per_m": nearest,
           "lowest_eigenvalue_N_per_m": float(checked.result[certificate.LOWEST]),
           "lowest_eigenvalue_error_N_per_m": float(checked.result[certificate.LOWEST_ERROR]),
           "inverse_norm_m_per_N": float(checked.result[certificate.INVERSE_NORM]),
           "error_estimate_m": float(record["error_estimate"]),
           "residual_N": float(record["residual"])}
    return row, state, record


# --- 4. The dynamic step on the same load step ---

def relax_time(solver: DynamicSolver, start) -> tuple[float, object]:
    """(wall time [s], outcome) of the step's relaxation alone (`StructureRelaxation.relax`
    from the step's start, the solver's tolerance rule), one run."""
    begun = solver.model.start_of_step(start, LOAD)
    relative = RELATIVE_TOLERANCE if solver.options.tolerance is None else 0.0
    began = time.perf_counter()
    _, outcome = solver.relaxation.relax(begun.positions, begun.chain_loads, begun.anchors,
                                         tolerance=solver.tolerance, max_steps=
                                         solver.options.max_steps, relative_tolerance=relative)
    return time.perf_counter() - began, outcome


def dynamic_costs(n: int, static_positions=None, friction=None):
    """(row, state, record): DynamicSolver.step on the load step; |x - x_static|."""
    model = patch_model(n, friction)
    solver = DynamicSolver(model)
    start = model.initial_state()
    step_s, (state, record) = timed(lambda: solver.step(start, LOAD))
    steps = int(record["time_steps"])
    relax_s, _ = timed(lambda: relax_time(solver, start)[0])
    row = {"step_s": step_s, "time_steps": steps, "relax_s": relax_s,
           "relax_s_per_time_step": relax_s / max(steps, 1),
           "residual_N": float(record["residual"])}
    if static_positions is not None:
        row["static_difference_m"] = float(np.abs(state.positions - static_positions).max())
    return row, state, record


# --- 3. The semi-implicit stand-in: Newton with per-yarn preconditioned CG ---

class PCGNewton(SparseNewton):
    """The static solver's sparse backend with its Newton direction by per-yarn preconditioned
    CG."""

    def __init__(self, model):
        super().__init__(model)
        f = self.structure
        dof_yarn = np.repeat(np.arange(model.yarns), 2 * np.diff(f.chain_start))
        unknown = self.pattern.index >= 0
        self.unknown_yarn = np.zeros(self.pattern.free_count, int)
        self.unknown_yarn[self.pattern.index[unknown]] = dof_yarn[unknown]
        assert np.all(np.diff(self.unknown_yarn) >= 0)  # yarn after yarn (no ties)
        self.cg_iterations, self.fallbacks = [], 0

    def _preconditioner(self, H):
        """B^-1 as a LinearOperator, or None if B is not positive definite.

        The unknowns of a clamped patch run yarn after yarn, so B (H without the entries
        joining two yarns) is one band matrix whose bands never cross a yarn's boundary:
        one banded Cholesky of it is every yarn's own, done in one LAPACK call."""
        H = H.tocoo()
        keep = self.unknown_yarn[H.row] == self.unknown_yarn[H.col]
        row, col, value = H.row[keep], H.col[keep], H.data[keep]
        width = int(np.abs(row - col).max())
        band = np.zeros((width + 1, H.shape[0]))
        upper = col >= row  # upper form: band[width + i - j, j] = B[i, j]
        np.add.at(band, (width + row[upper] - col[upper], col[upper]), value[upper])
        try:
            factor = scipy.linalg.cholesky_banded(band)
        except np.linalg.LinAlgError:
            return None
        n = H.shape[0]
        return scipy.sparse.linalg.LinearOperator(
            (n, n), matvec=lambda r: scipy.linalg.cho_solve_banded((factor, False), r))

    def _direction(self, H, g):
        B = self._preconditioner(H)
        if B is not None:
            count = [0]
            d, info = scipy.sparse.linalg.cg(H, -g, rtol=CG_RTOL, atol=0.0, maxiter=CG_MAX, M=B,
                                             callback=lambda _: count.__setitem__(0, count[0] + 1))
            if info == 0 and g @ d < 0.0:
                self.cg_iterations.append(count[0])
                return d
        self.fallbacks += 1
        return super()._direction(H, g)


def pcg_costs(n: int, static_positions=None, friction=None) -> dict:
    """StaticSolver.step with the `PCGNewton` backend on the load step: time, CG iterations,
    fallbacks, |x - x_static|."""
    solver = StaticSolver(patch_model(n, friction))
    backend = solver.backend = PCGNewton(solver.model)
    start = solver.initial_state()

    def step():
        backend.cg_iterations, backend.fallbacks = [], 0  # this run's alone
        return solver.step(start, LOAD)
    step_s, (state, record) = timed(step)
    counts = np.array(backend.cg_iterations)
    row = {"step_s": step_s, "newton_iterations": int(record["iterations"]),
           "cg_iterations_mean": float(counts.mean()) if counts.size else None,
           "cg_iterations_max": int(counts.max()) if counts.size else None,
           "fallbacks": backend.fallbacks}
    if static_positions is not None:
        row["static_difference_m"] = float(np.abs(state.positions - static_positions).max())
    return row


# --- 6. The semi-implicit solver on the same load step, and its two PCG layouts ---

LAYOUT_CG_TOLERANCE = 1e-10
"""CG tolerance of the layout comparison's solves: many iterations, so the time per iteration
is measured, not the setup."""
LAYOUT_TIME = 0.5
"""Seconds of repeated solves per layout in the layout comparison."""


def semi_costs(n: int, static_positions=None, friction=None, newton_s=None) -> dict:
    """`DynamicSolver.step` with the semi-implicit method on the load step: time, time steps,
    CG iterations per time step, |x - x_static|; its relaxation alone in the grouped layout
    (one launch per chunk of time steps) and the node-parallel one (a launch per stage, the
    loops over CG iterations in Python): us per CG iteration of each, and their difference,
    the launches' cost."""
    model = patch_model(n, friction)
    solver = DynamicSolver(model, Dynamic(method="semi_implicit", tolerance=TOLERANCE))
    start = model.initial_state()
    step_s, (state, record) = timed(lambda: solver.step(start, LOAD))
    steps, cg = int(record["time_steps"]), int(record["cg_iterations"])
    relax_s, (_, outcome) = timed(lambda: relax_time(solver, start))
    row = {"step_s": step_s, "time_steps": steps, "relax_s": relax_s,
           "cg_iterations": cg, "cg_per_time_step": cg / max(steps, 1),
           "relax_s_per_time_step": relax_s / max(steps, 1),
           "residual_N": float(record["residual"])}
    if newton_s is not None:
        row["relax_over_newton"] = row["relax_s"] / newton_s
    if static_positions is not None:
        row["static_difference_m"] = float(np.abs(state.positions - static_positions).max())
    parallel = DynamicSolver(model, solver.options, layout="node_parallel")
    parallel_s, parallel_outcome = relax_time(parallel, start)  # one run: the whole time loop
    iterations = int(outcome.cg_iterations.sum())
    row.update({"per_step_relax_s": parallel_s, "layout_cg_iterations": iterations,
                "persistent_us_per_cg_iteration": 1e6 * relax_s / max(iterations, 1),
                "launches_us_per_cg_iteration": 1e6 * parallel_s / max(iterations, 1),
                "launch_cost_us_per_cg_iteration": 1e6 * (parallel_s - relax_s)
                / max(iterations, 1),
                "layouts_same_cg_iterations": bool(np.array_equal(
                    outcome.cg_iterations, parallel_outcome.cg_iterations))})
    return row


# --- 5. The pieces of one Newton iteration ---

def newton_pieces(n: int, positions) -> dict:
    """Gradient, Hessian, the orderings' factorisations (`ordering_pieces`), SuperLU
    (default and symmetric mode), the inertia (`inertia.inertia`, its route recorded; dense
    eigenvalues where n <= 8) and the nearest eigenvalue (`nearest_eigenvalue_pieces`) at
    `positions`, the frictionless Newton solution of the load step."""
    solver = SparseNewton(patch_model(n))
    pos, anchors = positions, solver.model.initial_state().anchors
    limit = np.zeros(n * n)
    P = solver.model.yarn_loads(*LOAD)
    H = solver.hessian(pos, anchors, limit)
    g = solver.pattern.reduce(solver.gradient(pos, P, anchors, limit))
    row = {"hessian_nonzeros": int(H.nnz),
           "gradient_s": timed(lambda: solver.gradient(pos, P, anchors, limit))[0],
           "hessian_s": timed(lambda: solver.hessian(pos, anchors, limit))[0],
           "splu_default_s": timed(lambda: scipy.sparse.linalg.splu(H).solve(-g))[0],
           "splu_symmetric_s": timed(lambda: _sparse_solve(H, -g, order=ordering.fabric_order(
               solver.structure, solver.pattern)))[0]}
    row.update(ordering_pieces(solver, H, g))
    row["inertia_s"], result = timed(lambda: inertia.inertia(solver.model, pos, anchors, limit))
    row["inertia_negatives"], row["inertia_method"] = int(result.negatives), result.method
    row.update(nearest_eigenvalue_pieces(H))
    if n <= 8:
        dense = H.toarray()
        row["inertia_dense_eigvalsh_s"], values = timed(lambda: np.linalg.eigvalsh(dense))
        row["dense_negatives"] = int(np.count_nonzero(values < 0))
    return row


ORDERINGS = ("nested_dissection", "MMD_AT_PLUS_A", "COLAMD")
"""The fill-reducing orderings compared: `dynfab.model.fabric.ordering`'s, and SuperLU's own two."""


def ordering_pieces(solver, H, g) -> dict:
    """Per ordering: SuperLU's factorisation in symmetric mode with diagonal pivots (the
    Newton solve's and the inertia's), its time, its fill nnz(L + U) and one solve's time,
    of H without its explicit zeros (frictionless, the friction blocks are zero values: what
    SuperLU's own orderings saw in the Newton solve, `H + 0 I` dropping them); minimum degree
    also on H's whole pattern (the friction blocks' values are nonzero in a run with
    friction); and the time to compute the nested-dissection order (once per pattern,
    uncached here)."""
    xy = ordering.coordinates(solver.structure, solver.pattern.index, H.shape[0])
    row = {"order_nested_dissection_s": timed(lambda: ordering.nested_dissection(H, xy))[0]}
    order = ordering.fabric_order(solver.structure, solver.pattern)
    values = H.copy()
    values.eliminate_zeros()
    factors = {"nested_dissection": lambda: ordering.OrderedLU(values, order)}
    for name in ORDERINGS[1:]:
        factors[name] = lambda name=name: scipy.sparse.linalg.splu(
            values, permc_spec=name, diag_pivot_thresh=0.0, options=dict(SymmetricMode=True))
    factors["MMD_AT_PLUS_A_whole_pattern"] = lambda: scipy.sparse.linalg.splu(
        H, permc_spec="MMD_AT_PLUS_A", diag_pivot_thresh=0.0, options=dict(SymmetricMode=True))
    for name, factor in factors.items():
        row[f"factor_{name}_s"], lu = timed(factor)
        superlu = getattr(lu, "lu", lu)
        row[f"fill_{name}"] = int(superlu.L.nnz + superlu.U.nnz)
        row[f"solve_{name}_s"] = timed(lambda: lu.solve(-g))[0]
    return row


def nearest_eigenvalue_pieces(H) -> dict:
    """The nearest eigenvalue (`inertia.nearest_eigenvalue`: ARPACK with the ordered
    shift-invert factorisation) and, as it was before, ARPACK factoring H itself (SuperLU's
    COLAMD with partial pivoting); the ordered one's count of solves."""
    row = {}
    row["nearest_eigenvalue_s"], row["nearest_eigenvalue_N_per_m"] = timed(
        lambda: inertia.nearest_eigenvalue(H))
    row["nearest_eigenvalue_arpack_lu_s"], value = timed(lambda: float(scipy.sparse.linalg.eigsh(
        H, k=1, sigma=0.0, which="LM", tol=inertia.EIGEN_TOL, v0=inertia.start_vector(H.shape[0]),
        return_eigenvectors=False)[0]))
    row["nearest_eigenvalue_arpack_lu_N_per_m"] = value
    inverse = inertia.shift_inverse(H, 0.0, ordering.known_order(H))
    count = [0]

    def counted(r):
        count[0] += 1
        return inverse.matvec(r)
    scipy.sparse.linalg.eigsh(H, k=1, sigma=0.0, which="LM", tol=inertia.EIGEN_TOL,
                              OPinv=scipy.sparse.linalg.LinearOperator(H.shape, matvec=counted,
                                                                       dtype=float),
                              v0=inertia.start_vector(H.shape[0]), return_eigenvectors=False)
    row["nearest_eigenvalue_solves"] = count[0]
    return row


# --- One size, in its own process ---

def measure_size(n: int, parts=PARTS, friction=None, pieces=False, emit=None, warm=False):
    """Every part on the n x n patch, in order; each part's row is passed to `emit(part, row)`
    as it finishes. `warm`: the untimed compile pass (short explicit runs)."""
    emit = emit or (lambda part, row: None)
    if "explicit" in parts:
        work = (WARM_WORK, WARM_WORK) if warm else (STEP_WORK, PER_STEP_WORK)
        emit("explicit", explicit_costs(n, *work))
    positions = None
    if {"newton", "static", "pcg", "dynamic", "semi"} & set(parts) or pieces:
        row, positions = newton_costs(n, friction)
        emit("newton", row)
    if "pcg" in parts:
        emit("pcg", pcg_costs(n, positions, friction))
    if "static" in parts:
        emit("static", static_costs(n, friction)[0])
    if "dynamic" in parts:
        emit("dynamic", dynamic_costs(n, positions, friction)[0])
    if "semi" in parts:
        emit("semi", semi_costs(n, positions, friction, row["newton_s"]))
    if pieces:
        emit("pieces", newton_pieces(n, positions))


def megabytes() -> float:
    """Peak resident set of this process so far [MB] (ru_maxrss is in kB on Linux)."""
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def child(n: int, parts, friction, pieces) -> None:
    """The subprocess of one size: the 4 x 4 compile pass, then each part as a JSON line."""
    import warp as wp
    wp.config.quiet = True
    wp.init()
    measure_size(4, parts, friction, pieces, warm=True)
    print(json.dumps({"part": "baseline", "peak_rss_MB": megabytes()}), flush=True)

    def emit(part, row):
        print(json.dumps({"part": part, **row, "peak_rss_MB": megabytes()}), flush=True)
    measure_size(n, parts, friction, pieces, emit)
    print(json.dumps({"part": "memory", "peak_rss_MB": megabytes()}), flush=True)


def run_size(n: int, budget_s: float, parts, friction: bool, pieces: bool) -> dict:
    """The parts of size n from a subprocess stopped after budget_s; unfinished parts say so."""
    command = [sys.executable, __file__, "--size", str(n), "--parts", ",".join(parts)]
    command += ["--friction"] * friction + ["--pieces"] * pieces
    began = time.perf_counter()
    with tempfile.TemporaryFile("w+") as out:
        process = subprocess.Popen(command, stdout=out, stderr=subprocess.PIPE, text=True)
        try:
            _, error = process.communicate(timeout=budget_s)
            stopped = False
        except subprocess.TimeoutExpired:
            process.kill()
            _, error = process.communicate()
            stopped = True
        out.seek(0)
        lines = [json.loads(line) for line in out if line.startswith("{")]
    row = {"n": n, "nodes": nodes(n), "wall_s": time.perf_counter() - began}
    for line in lines:
        row[line.pop("part")] = line
    wanted = list(parts) + ["pieces"] * pieces + ["memory"]
    for part in wanted:
        if part not in row:
            row[part] = ({"not run": f"exceeded budget ({budget_s:g} s)"} if stopped else
                         {"not run": f"failed (exit status {process.returncode}): "
                                     f"{error.strip().splitlines()[-1] if error.strip() else ''}"})
    if "not run" in row["memory"]:  # the peak when the last finished part ended, a lower bound
        peaks = [line["peak_rss_MB"] for line in lines if "peak_rss_MB" in line]
        row["memory"]["peak_rss_MB_at_least"] = max(peaks) if peaks else None
    row["stopped"] = stopped
    return row


def peak(row) -> str | float | None:
    """The size's peak RSS [MB], or '>= x' where the size was stopped before its end."""
    memory = row.get("memory", {})
    if "peak_rss_MB" in memory:
        return memory["peak_rss_MB"]
    if memory.get("peak_rss_MB_at_least") is not None:
        return f">= {memory['peak_rss_MB_at_least']:.0f}"
    return None


# --- The summary: exponents, aims, the table ---

def exponent(rows, part: str, key: str):
    """Least-squares slope of log(row[part][key]) on log(nodes) over the rows that have it,
    and over the largest three of them (None with fewer than two, or three)."""
    points = [(r["nodes"], r[part][key]) for r in rows if key in r.get(part, {})]
    if len(points) < 2:
        return None, None
    x, y = np.log(np.array(points, float)).T
    slope = float(np.polyfit(x, y, 1)[0])
    tail = float(np.polyfit(x[-3:], y[-3:], 1)[0]) if len(points) >= 3 else None
    return slope, tail


FITS = {"exponent_time_step": ("explicit", "persistent_s_per_step"),
        "exponent_time_step_numba": ("explicit", "numba_s_per_step"),
        "exponent_time_step_dynamic_solver": ("dynamic", "relax_s_per_time_step"),
        "exponent_dynamic_load_step": ("dynamic", "step_s"),
        "exponent_newton_iteration": ("newton", "s_per_newton_iteration"),
        "exponent_factor_nested_dissection": ("pieces", "factor_nested_dissection_s"),
        "exponent_factor_MMD_AT_PLUS_A": ("pieces", "factor_MMD_AT_PLUS_A_s"),
        "exponent_factor_COLAMD": ("pieces", "factor_COLAMD_s"),
        "exponent_fill_nested_dissection": ("pieces", "fill_nested_dissection"),
        "exponent_fill_MMD_AT_PLUS_A": ("pieces", "fill_MMD_AT_PLUS_A"),
        "exponent_fill_MMD_AT_PLUS_A_whole_pattern": ("pieces", "fill_MMD_AT_PLUS_A_whole_pattern"),
        "exponent_static_step": ("static", "step_s"),
        "exponent_certificate": ("static", "certificate_s"),
        "exponent_inertia": ("static", "inertia_s"),
        "exponent_nearest_eigenvalue": ("static", "nearest_eigenvalue_s"),
        "exponent_pcg_step": ("pcg", "step_s"),
        "exponent_semi_implicit_load_step": ("semi", "step_s")}
"""Fitted exponent: (part, key of the time)."""


def summary(rows) -> dict:
    """The fitted exponents (all sizes, largest three) and each aim's value and verdict."""
    fits = {name: dict(zip(("all_sizes", "largest_three"), exponent(rows, *where)))
            for name, where in FITS.items()}
    ratios = [r["explicit"]["persistent_over_numba"] for r in rows
              if "persistent_over_numba" in r.get("explicit", {})]
    values = {"explicit_over_numba": max(ratios) if ratios else None,
              "exponent_time_step": fits["exponent_time_step"]["all_sizes"],
              "exponent_newton_iteration": fits["exponent_newton_iteration"]["all_sizes"]}
    aims = {name: {"value": value, "at_most": AIMS[name],
                   "met": None if value is None else value <= AIMS[name]}
            for name, value in values.items()}
    return {"exponents": fits, "aims": aims}


COLUMNS = (("n", lambda r: f"{r['n']}x{r['n']}", 5),
           ("nodes", lambda r: r["nodes"], 6),
           ("dofs", lambda r: r["newton"].get("dofs_free"), 6),
           ("Newton s/it", lambda r: r["newton"].get("s_per_newton_iteration"), 11),
           ("its", lambda r: r["newton"].get("newton_iterations"), 3),
           ("cert s", lambda r: r["static"].get("certificate_s"), 7),
           ("static s", lambda r: r["static"].get("step_s"), 8),
           ("dyn steps", lambda r: r["dynamic"].get("time_steps"), 9),
           ("dyn s/step", lambda r: r["dynamic"].get("relax_s_per_time_step"), 10),
           ("dyn s", lambda r: r["dynamic"].get("step_s"), 7),
           ("pcg s", lambda r: r["pcg"].get("step_s"), 7),
           ("cg its", lambda r: r["pcg"].get("cg_iterations_mean"), 6),
           ("semi s", lambda r: r["semi"].get("step_s"), 7),
           ("semi steps", lambda r: r["semi"].get("time_steps"), 10),
           ("cg/step", lambda r: r["semi"].get("cg_per_time_step"), 7),
           ("warp ns", lambda r: r["explicit"].get("persistent_ns_per_node_step"), 7),
           ("numba ns", lambda r: r["explicit"].get("numba_ns_per_node_step"), 8),
           ("ratio", lambda r: r["explicit"].get("persistent_over_numba"), 5),
           ("dyn-st m", lambda r: r["dynamic"].get("static_difference_m"), 10),
           ("peak MB", peak, 7),
           ("base MB", lambda r: r["baseline"].get("peak_rss_MB"), 7))
"""The table's columns: (heading, value of a row, width)."""


def cell(value, width: int) -> str:
    """One cell: '-' for a value not measured, 3 significant digits for a float."""
    if value is None:
        return "-".rjust(width)
    if isinstance(value, float):
        return f"{value:.3g}".rjust(width)
    return str(value).rjust(width)


def table(rows) -> str:
    """The markdown table of the rows (a part not run: '-')."""
    lines = ["| " + " | ".join(name.rjust(width) for name, _, width in COLUMNS) + " |",
             "|" + "|".join("---:" for _ in COLUMNS) + "|"]
    for r in rows:
        parts = {p: r.get(p, {}) for p in ("newton", "static", "dynamic", "pcg", "explicit",
                                            "memory", "baseline", "semi")}
        lines.append("| " + " | ".join(cell(value({**r, **parts}), width)
                                       for _, value, width in COLUMNS) + " |")
    return "\n".join(lines)


def report(result) -> str:
    """The table, the exponents, the aims and what was not run."""
    lines = [table(result["rows"]), ""]
    for name, fit in result["summary"]["exponents"].items():
        lines.append(f"{name}: all sizes {cell(fit['all_sizes'], 0)}, "
                     f"largest three {cell(fit['largest_three'], 0)}")
    for name, aim in result["summary"]["aims"].items():
        verdict = {None: "not measured", True: "met", False: "NOT met"}[aim["met"]]
        lines.append(f"aim {name} <= {aim['at_most']}: {cell(aim['value'], 0)} {verdict}")
    for r in result["rows"]:
        for part, value in r.items():
            if isinstance(value, dict) and "not run" in value:
                lines.append(f"{r['n']}x{r['n']} {part}: not run: {value['not run']}")
    return "\n".join(lines)


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="4 x 4 and 8 x 8 only")
    parser.add_argument("--budget", type=float, default=BUDGET, help="wall-time budget per size [s]")
    parser.add_argument("--friction", action="store_true", help="the paper's friction")
    parser.add_argument("--pieces", action="store_true", help="the pieces of a Newton iteration too")
    parser.add_argument("--parts", default=",".join(PARTS), help="comma-separated subset of " + ",".join(PARTS))
    parser.add_argument("--size", type=int, help=argparse.SUPPRESS)  # the subprocess of one size
    parser.add_argument("--output", type=Path, default=OUTPUT)
    args = parser.parse_args(argv)
    parts = tuple(p for p in PARTS if p in args.parts.split(","))
    friction = PAPER_FRICTION if args.friction else None
    if args.size is not None:
        child(args.size, parts, friction, args.pieces)
        return
    rows, stopped = [], False
    for n in QUICK_SIZES if args.quick else SIZES:
        if stopped:
            rows.append({"n": n, "nodes": nodes(n), **{p: {"not run": "a smaller size exceeded the budget"}
                                                       for p in parts}})
            continue
        rows.append(run_size(n, args.budget, parts, args.friction, args.pieces))
        stopped = rows[-1]["stopped"]
        print(table(rows[-1:]).splitlines()[-1], flush=True)
    import warp as wp
    result = {"machine": {"platform": platform.platform(), "cpus": os.cpu_count(),
                          "python": platform.python_version(), "numpy": np.__version__,
                          "scipy": scipy.__version__, "numba": numba.__version__,
                          "warp": wp.config.version},
              "case": {"sizes": [r["n"] for r in rows], "segments_per_half_wave": SEGMENTS_PER_HALF_WAVE,
                       "load_N": LOAD, "tolerance_N": TOLERANCE, "friction": args.friction,
                       "budget_s": args.budget, "repeats": REPEATS, "fast_s": FAST,
                       "damping_c_dt": DAMPING, "cg_rtol": CG_RTOL,
                       "memory": "peak RSS (ru_maxrss) of the size's subprocess; baseline: after "
                                 "the imports and the 4 x 4 compile pass",
                       "semi_implicit": "semi: the Warp semi-implicit solver; pcg: the static "
                                        "solver with per-yarn preconditioned CG"},
              "rows": rows, "summary": summary(rows)}
    print(report(result))
    args.output.write_text(json.dumps(result, indent=2) + "\n")
    print(f"wrote {args.output}")


if __name__ == "__main__":
    main()
