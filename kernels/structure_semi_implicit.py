"""Linearly implicit relaxation of any structure: each time step one conjugate-gradient solve
preconditioned by the chains' banded solves (docs/model.md section 5, (5.4); section 10).

    (M (1 + dt c) + dt^2 K) dv = dt (f - dt K v - c M v),   v += dv,   x += dt v,

f the force at x (F_T at the current R), K the tangent made positive semi-definite, F_T
frozen (`structure_tangent`: a compressed segment's negative geometric part and bending's
moment term dropped; each tie's dR/dg >= 0 and its Huber Hessian, k_t I sticking, the exact
positive semi-definite block sliding, or where the planes move the secant (F_T / |s|) I); the
wrap springs, the ties between chains and the moving planes couple the chains. A is stored
as each chain's band (its terms and its ties' diagonal parts) plus, in the product only, the
ties' off-diagonal parts, the wrap springs' blocks between their pairs of nodes and the
planes' rows (`plane_row`, from the per-group sums U_f and G_f = sum_t w_t,f (H_t ds_t)_f,
`boundary_sums`); a tied family's dof is one unknown whose copies sit on its nodes: its row
the sum of theirs, each node's band holding 1/m of the family's mass, the CG inner products
counting each copy at its share, its preconditioner its diagonal (`tie_diagonals`): CG runs on
T^T A T, the static solver's unknowns (the design of the fabric's first semi-implicit
kernels, generalised to any structure).

The right side is dt f + M v - A v (A v by the same product). Held dofs get identity rows
and columns and zero right sides. PCG is preconditioned by P = the chains' bands (each
factored by `band_lu`, a tied dof's row the identity there): block-diagonal over chains and
SPD. It stops at sqrt(r^T P^-1 r / b^T P^-1 b) <= cg_tolerance (CG_TOLERANCE, the fabric's
choice), or after as many iterations as the group's dofs. Where the group's matrix is its
band alone (`StructureArrays.group_exact`: one chain, its ties to ground, no wrap, planes or
tied dofs; every one-yarn scene) P = A: the first iterate x = P^-1 b is the solution, so with
`settings.direct` the band is factored in place and solved at once, the right side
dt (f - dt K v - c M v) taken from the band of K (as the one-yarn model's first semi-implicit
kernel took it), counted as one CG iteration; without it CG finds the solution in one
iteration.

Time step rule (the fabric's first kernels', docs/model.md and docs/results.md): dt
starts at the masses' dt (1 s with fictitious masses); a step that lowers f^T M^-1 f is
accepted and dt doubles (at most DT_MAX); one that does not is shortened along its new
velocity, x = x_0 + alpha dt v for alpha = 1/2, 1/4, ... (settings.backtracks halvings, a
force evaluation each): the first alpha that lowers the merit is accepted with v scaled by
alpha and dt kept; else the step is undone (positions back, velocities zeroed) and dt halved.
A factorisation with a pivot that is not positive halves dt and rebuilds (at most
MAX_REFACTORISATIONS times: NOT_POSITIVE_DEFINITE).

Kinematics: the dofs are dim node + coordinate (dim 2 planar, 3 spatial) and the bands'
half-width `band_lu.bandwidth(dim)`; K is the kinematics' tangent
(`structure_checks.TANGENTS`: the planar `structure_tangent`, the spatial
`spatial_terms.tangent_terms`, whose bands hold the blocks within two nodes of one chain and
whose product, `coupling_vector` once per node, applies every other block; docs/model.md
11.11). The moving planes, wraps and tied dofs are the planar fabric's only.

Layouts, the same stages in the same order (bit-identical): "grouped", one thread per group
running the time loop and CG inside; "node_parallel", a launch per stage with threads per tie,
chain, node or dof and one per group for each decision (`stage_kernel`), the loops over CG
iterations, refactorisations and line-search trials in Python on the per-group flags read back.
"""

import functools
from types import SimpleNamespace

import warp as wp

from dynfab.kernels import band_lu, status, structure_checks, structure_forces
from dynfab.kernels import structure_settings, structure_variants
from dynfab.kernels.precision import KINEMATICS, vector

CG_TOLERANCE = 1e-2
"""CG's default relative tolerance [-] (the fabric's choice, docs/model.md section 10)."""
DT_GROWTH = 2.0
"""dt factor after an accepted full step [-]."""
DT_SHRINK = 0.5
"""dt factor after an undone step or a pivot that is not positive [-]."""
DT_MAX = 1e12
"""The largest time step [s]."""
MAX_BACKTRACKS = 4
"""Halvings of a step's length along its new velocity before it is undone (the default)."""
MAX_REFACTORISATIONS = 60
"""dt halvings allowed to obtain positive pivots in one step."""
ACCEPT, TRIAL, UNDO = 1, 2, 3
"""A group's line-search decision (`state.decision`)."""
CG_RZ, CG_STOP, CG_ALPHA, CG_BETA, CG_DONE, CG_ITERATIONS = range(6)
"""Columns of `state.cg`."""

(TIE_BLOCKS, BUILD, FACTORED, VELOCITY, BOUNDARY, RHS, CG_START, PRECONDITION, FIRST_SUM, COPY,
 CG_BOUNDARY, PRODUCT, CURVATURE, STEP_LENGTH, UPDATE, NEXT_SUM, DIRECTION, MOVE, TIES, GATHER,
 BLOCKS, SEARCH, TRIAL_MOVE, FINISH, RE_TIES, RE_GATHER, RE_BLOCKS, FINISH_GROUP, CHECK) = \
    range(100, 129)
"""Stages of a semi-implicit time step (`stage_kernel`; the start's are `structure_explicit`'s)."""
NODE, TIE, BLOCK, CHAIN, GROUP, DOF = range(6)
KINDS = {TIE_BLOCKS: TIE, BUILD: CHAIN, FACTORED: GROUP, VELOCITY: DOF, BOUNDARY: GROUP,
         RHS: NODE, CG_START: DOF, PRECONDITION: CHAIN, FIRST_SUM: GROUP, COPY: DOF,
         CG_BOUNDARY: GROUP, PRODUCT: NODE, CURVATURE: CHAIN, STEP_LENGTH: GROUP, UPDATE: DOF,
         NEXT_SUM: GROUP, DIRECTION: DOF, MOVE: NODE, TIES: TIE, GATHER: NODE, BLOCKS: BLOCK,
         SEARCH: GROUP, TRIAL_MOVE: NODE, FINISH: NODE, RE_TIES: TIE, RE_GATHER: NODE,
         RE_BLOCKS: BLOCK, FINISH_GROUP: GROUP, CHECK: GROUP}


@functools.cache
def functions(scalar, friction: bool, boundary: bool,
              kinematics: str = "planar") -> SimpleNamespace:
    """The stage `wp.func`s of one variant (module docstring)."""
    dim = KINEMATICS[kinematics]
    vec = vector(scalar, dim)
    Data, State, Settings = structure_variants.structs(scalar, dim)
    forces = structure_forces.functions(scalar, friction, boundary, kinematics)
    tangent = structure_checks.TANGENTS[kinematics](scalar, friction, boundary)
    checks = structure_checks.functions(scalar, friction, boundary, True, kinematics)
    band_ops = band_lu.functions(scalar, dim)
    BANDWIDTH = band_lu.bandwidth(dim)  # noqa: N806

    @wp.func(inline=True)
    def running(state: State, g: int) -> bool:
        return state.status[g] == int(status.RUNNING)

    @wp.func(inline=True)
    def searching(state: State, g: int) -> bool:
        """The group runs and its line search has not decided (no decision yet, or TRIAL)."""
        return running(state, g) and state.decision[g] != scalar(ACCEPT) \
            and state.decision[g] != scalar(UNDO)

    @wp.func(inline=True)
    def undone(state: State, g: int) -> bool:
        """The group runs and its step is undone."""
        return running(state, g) and state.decision[g] == scalar(UNDO)

    @wp.func(inline=True)
    def free_dof(data: Data, row: int) -> scalar:
        return data.free[row / dim][row % dim]

    @wp.func(inline=True)
    def members(data: Data, i: int) -> int:
        """m for a node of a tied family of m (one dof, its copies on m nodes), else 1."""
        count = int(1)
        if wp.static(boundary):
            family = data.node_tie[i]
            if family >= 0:
                count = data.plane_offsets[family + 1] - data.plane_offsets[family]
        return count

    # ------------------------------------------------------------- the system

    @wp.func(inline=True)
    def tie_blocks(t: int, data: Data, state: State, settings: Settings):
        tangent.tie_blocks(t, state.position, data, state,
                           forces.plane_shift(state.position, data), settings.secant)

    @wp.func(inline=True)
    def is_direct(g: int, data: Data, settings: Settings) -> bool:
        """The group's matrix is its one chain's band, solved directly (module docstring)."""
        return settings.direct != 0 and data.group_exact[g] != 0

    @wp.func(inline=True)
    def direct_done(g: int, state: State) -> bool:
        """This step's x was solved directly at the build (`build_chain`)."""
        return state.cg[g, CG_DONE] == scalar(2.0)

    @wp.func(inline=True)
    def build_chain(c: int, data: Data, state: State, settings: Settings):
        """Chain c's rows of A = M (1 + dt c) + dt^2 K in the band (held dofs: identity; a tied
        node's mass its share), their copy factored into P (a tied dof's row the identity);
        chain_failed[c] = the first pivot that is not positive, or -1. Where the group is
        `is_direct`: the right side from the band of K first (as the one-yarn solver), then the
        band factored in place and x = A^-1 b solved."""
        g = data.chain_group[c]
        dt = state.dt[g]
        damping = wp.max(settings.damping_coefficient, scalar(0.0))
        a = data.chain_start[c]
        b = data.chain_start[c + 1]
        lo = dim * a
        hi = dim * b
        band = state.band
        tangent.assemble_chain(c, state.position, data, state, band, 1)
        direct = is_direct(g, data, settings)
        if direct:  # A is this band: x = dt (f - dt K v - c M v), K v from the band of K
            for row in range(lo, hi):
                i = row / dim
                comp = row % dim
                stiffness_velocity = scalar(0.0)
                for j in range(wp.max(lo, row - BANDWIDTH), wp.min(hi, row + BANDWIDTH + 1)):
                    stiffness_velocity += band[row, j - row + BANDWIDTH] \
                        * state.velocity[j / dim][j % dim]
                state.x[row] = free_dof(data, row) * dt * (
                    state.force[i][comp] - dt * stiffness_velocity
                    - damping * state.mass[i] * state.velocity[i][comp])
        dt2 = dt * dt
        for row in range(lo, hi):
            for k in range(2 * BANDWIDTH + 1):
                band[row, k] = dt2 * band[row, k]
            band[row, BANDWIDTH] += (scalar(1.0) + dt * damping) * state.mass[row / dim] \
                / scalar(members(data, row / dim))
        for row in range(lo, hi):
            if free_dof(data, row) == scalar(0.0):
                band_ops.constrain(band, lo, hi, row)
        if direct:  # factored in place and solved: x = A^-1 b
            failed = band_ops.factor(band, lo, hi)
            if failed < 0:
                band_ops.solve(band, lo, hi, state.x)
            state.chain_failed[c] = failed
        else:
            for row in range(lo, hi):
                for k in range(2 * BANDWIDTH + 1):
                    state.factor[row, k] = band[row, k]
            if wp.static(boundary):
                for i in range(a, b):
                    if data.node_tie[i] >= 0:
                        band_ops.constrain(state.factor, lo, hi, dim * i)
            state.chain_failed[c] = band_ops.factor(state.factor, lo, hi)

    @wp.func(inline=True)
    def factored(g: int, data: Data, state: State, settings: Settings):
        """Every chain of g factored: on (a direct group's x solved: CG done in one iteration);
        else dt halved for a rebuild (NOT_POSITIVE_DEFINITE after MAX_REFACTORISATIONS)."""
        failed = bool(False)
        for c in range(data.group_chain[g], data.group_chain[g + 1]):
            if state.chain_failed[c] >= 0:
                failed = True
        if failed:
            state.refactorisations[g] = state.refactorisations[g] + 1
            state.dt[g] = state.dt[g] * scalar(DT_SHRINK)
            if state.refactorisations[g] >= MAX_REFACTORISATIONS:
                state.status[g] = int(status.NOT_POSITIVE_DEFINITE)
        else:
            state.factored[g] = 1
            if is_direct(g, data, settings):
                state.cg[g, CG_DONE] = scalar(2.0)
                state.cg[g, CG_ITERATIONS] = scalar(1.0)

    @wp.func(inline=True)
    def boundary_sums(g: int, x: wp.array(dtype=scalar), data: Data, state: State):
        """boundary[g] = (U_0, U_1, G_0, G_1, ...) of x where the planes move (module docstring):
        U_f the sum of x over family f's plane nodes, G_f = sum_t w_t,f (H_t ds_t)_f with
        ds_t = (x_a, x_b) - w_t o U, in tie order."""
        if wp.static(boundary):
            if data.plane_offsets[2] > 0 and data.node_group[data.plane_nodes[0]] == g:
                U = vec(scalar(0.0), scalar(0.0))
                for family in range(2):
                    total = scalar(0.0)
                    for m in range(data.plane_offsets[family], data.plane_offsets[family + 1]):
                        total += x[2 * data.plane_nodes[m]]
                    U[family] = total
                G = vec(scalar(0.0), scalar(0.0))
                for t in range(data.group_tie[g], data.group_tie[g + 1]):
                    w = data.tie_weight[t]
                    blk = state.coupling[t]
                    x_b = scalar(0.0)
                    if data.tie_b[t] >= 0:
                        x_b = x[2 * data.tie_b[t]]
                    ds = vec(x[2 * data.tie_a[t]], x_b) - wp.cw_mul(w, U)
                    G = G + wp.cw_mul(w, vec(blk[1] * ds[0] + blk[2] * ds[1],
                                             blk[2] * ds[0] + blk[3] * ds[1]))
                state.boundary[g, 0] = U[0]
                state.boundary[g, 1] = U[1]
                state.boundary[g, 2] = G[0]
                state.boundary[g, 3] = G[1]

    @wp.func(inline=True)
    def tie_diagonals(g: int, data: Data, state: State):
        """boundary[g, 4 + f] = P's entry of tied family f's dof: its nodes' band diagonals plus
        dt^2 sum_t (m w_t,f)^2 h_t,ff."""
        if wp.static(boundary):
            dt = state.dt[g]
            for family in range(2):
                begin = data.plane_offsets[family]
                end = data.plane_offsets[family + 1]
                if end > begin:
                    first = data.plane_nodes[begin]
                    if data.node_tie[first] >= 0 and data.node_group[first] == g:
                        total = scalar(0.0)
                        for m in range(begin, end):
                            total += state.band[2 * data.plane_nodes[m], BANDWIDTH]
                        planes = scalar(0.0)
                        for t in range(data.group_tie[g], data.group_tie[g + 1]):
                            w = scalar(end - begin) * data.tie_weight[t][family]
                            planes += w * w * state.coupling[t][1 + 2 * family]
                        state.boundary[g, 4 + family] = total + dt * dt * planes

    @wp.func(inline=True)
    def plane_row(i: int, comp: int, data: Data, state: State) -> scalar:
        """The moving planes' part of the ties' J^T H J times x at dof (node i, comp) [N], from
        `boundary_sums` of x: -H (w o U) on a tie's slip dofs, -G_f on family f's plane nodes."""
        value = scalar(0.0)
        if wp.static(boundary):
            if comp == 0:
                g = data.node_group[i]
                U = vec(state.boundary[g, 0], state.boundary[g, 1])
                for k in range(data.node_tie_start[i], data.node_tie_start[i + 1]):
                    t = data.node_ties[k]
                    moved = wp.cw_mul(data.tie_weight[t], U)
                    blk = state.coupling[t]
                    if data.tie_a[t] == i:
                        value = value - (blk[1] * moved[0] + blk[2] * moved[1])
                    else:
                        value = value - (blk[2] * moved[0] + blk[3] * moved[1])
                family = data.node_plane[i]
                if family >= 0:
                    value = value - state.boundary[g, 2 + family]
        return value

    @wp.func(inline=True)
    def own_row(i: int, comp: int, x: wp.array(dtype=scalar), data: Data, state: State,
                dt2: scalar, coupling: scalar) -> scalar:
        """(A x) at dof (node i, comp) from node i's own row (`boundary_sums` of x done);
        dt2 = dt^2 [s^2] of its group, `coupling` the tangent's blocks outside the band times x
        there (`coupling_vector`)."""
        row = dim * i + comp
        chain = data.node_chain[i]
        value = band_ops.row_product(state.band, row, dim * data.chain_start[chain],
                                     dim * data.chain_start[chain + 1], x)
        coupled = coupling
        if wp.static(boundary):
            coupled = coupled + plane_row(i, comp, data, state) \
                + tangent.wrap_cross(state.position, data, i, x, comp)
        return value + dt2 * free_dof(data, row) * coupled

    @wp.func(inline=True)
    def product_value(i: int, comp: int, x: wp.array(dtype=scalar), data: Data, state: State,
                      dt2: scalar, coupling: vec) -> scalar:
        """(A x) at dof (node i, comp), `coupling` node i's `coupling_vector` of x; a tied
        node's in-plane dof: its family's rows summed in plane-node order (T^T A T x, the same
        on every copy)."""
        value = scalar(0.0)
        tied = int(-1)
        if wp.static(boundary):
            if comp == 0:
                tied = data.node_tie[i]
        if tied >= 0:
            for m in range(data.plane_offsets[tied], data.plane_offsets[tied + 1]):
                j = data.plane_nodes[m]
                value += own_row(j, 0, x, data, state, dt2,
                                 tangent.coupling_vector(j, x, data, state)[0])
        else:
            value = own_row(i, comp, x, data, state, dt2, coupling[comp])
        return value

    @wp.func(inline=True)
    def rhs_node(i: int, data: Data, state: State):
        """rhs = dt f + M v - A v at node i's dofs (0 on held ones), A v from x = v."""
        dt = state.dt[data.node_group[i]]
        coupling = tangent.coupling_vector(i, state.x, data, state)
        for comp in range(dim):
            row = dim * i + comp
            state.rhs[row] = free_dof(data, row) * (
                dt * state.force[i][comp] + state.mass[i] * state.velocity[i][comp]
                - product_value(i, comp, state.x, data, state, dt * dt, coupling))

    # ------------------------------------------------------------- PCG

    @wp.func(inline=True)
    def precondition_chain(c: int, data: Data, state: State):
        """z = P^-1 r on chain c's dofs (a tied dof: r over its `tie_diagonals` entry);
        chain_partial[c] = r . z there."""
        a = data.chain_start[c]
        b = data.chain_start[c + 1]
        band_ops.solve_into(state.factor, dim * a, dim * b, state.r, state.z)
        if wp.static(boundary):
            g = data.chain_group[c]
            for i in range(a, b):
                family = data.node_tie[i]
                if family >= 0:
                    state.z[2 * i] = state.r[2 * i] / state.boundary[g, 4 + family]
        state.chain_partial[c] = chain_dot(c, state.r, state.z, data)

    @wp.func(inline=True)
    def chain_dot(c: int, u: wp.array(dtype=scalar), w: wp.array(dtype=scalar),
                  data: Data) -> scalar:
        """sum of u w over chain c's dofs, in order, a tied copy counted at its share."""
        total = scalar(0.0)
        for i in range(data.chain_start[c], data.chain_start[c + 1]):
            total += data.share[i] * (u[dim * i] * w[dim * i])
            for c in range(1, dim):
                total += u[dim * i + c] * w[dim * i + c]
        return total

    @wp.func(inline=True)
    def chain_sum(g: int, data: Data, state: State) -> scalar:
        total = scalar(0.0)
        for c in range(data.group_chain[g], data.group_chain[g + 1]):
            total += state.chain_partial[c]
        return total

    @wp.func(inline=True)
    def cg_start(d: int, state: State):
        state.x[d] = scalar(0.0)
        state.r[d] = state.rhs[d]

    @wp.func(inline=True)
    def first_sum(g: int, data: Data, state: State, settings: Settings):
        """r^T z and the stop value."""
        total = chain_sum(g, data, state)
        state.cg[g, CG_RZ] = total
        state.cg[g, CG_STOP] = settings.cg_tolerance * settings.cg_tolerance * total
        state.cg[g, CG_DONE] = scalar(0.0)
        state.cg[g, CG_ITERATIONS] = scalar(0.0)
        if not total > state.cg[g, CG_STOP]:
            state.cg[g, CG_DONE] = scalar(1.0)

    @wp.func(inline=True)
    def copy_direction(d: int, data: Data, state: State):
        """p = z."""
        state.p[d] = state.z[d]

    @wp.func(inline=True)
    def cg_done(g: int, state: State) -> bool:
        return state.cg[g, CG_DONE] != scalar(0.0)

    @wp.func(inline=True)
    def product_node(i: int, data: Data, state: State, dt2: scalar):
        """q = A p at node i's dofs (dt2 = dt^2 of its group)."""
        coupling = tangent.coupling_vector(i, state.p, data, state)
        for comp in range(dim):
            state.q[dim * i + comp] = product_value(i, comp, state.p, data, state, dt2, coupling)

    @wp.func(inline=True)
    def curvature_chain(c: int, data: Data, state: State):
        state.chain_partial[c] = chain_dot(c, state.p, state.q, data)

    @wp.func(inline=True)
    def step_length(g: int, data: Data, state: State):
        """alpha = r^T z / p^T A p; done where p^T A p is not positive."""
        total = chain_sum(g, data, state)
        if total > scalar(0.0):
            state.cg[g, CG_ALPHA] = state.cg[g, CG_RZ] / total
        else:
            state.cg[g, CG_DONE] = scalar(1.0)

    @wp.func(inline=True)
    def update_range(g: int, lo: int, hi: int, state: State):
        """x += alpha p, r -= alpha q over dofs lo..hi-1 of group g (until done)."""
        if not cg_done(g, state):
            alpha = state.cg[g, CG_ALPHA]
            for d in range(lo, hi):
                state.x[d] = state.x[d] + alpha * state.p[d]
                state.r[d] = state.r[d] - alpha * state.q[d]

    @wp.func(inline=True)
    def next_sum(g: int, data: Data, state: State):
        """beta = new r^T z / old; one more iteration counted; done at the stop or after as
        many iterations as the group's dofs."""
        total = chain_sum(g, data, state)
        if not cg_done(g, state):
            iterations = state.cg[g, CG_ITERATIONS] + scalar(1.0)
            state.cg[g, CG_ITERATIONS] = iterations
            state.cg[g, CG_BETA] = total / state.cg[g, CG_RZ]
            state.cg[g, CG_RZ] = total
            dofs = scalar(dim * (data.group_node[g + 1] - data.group_node[g]))
            if not total > state.cg[g, CG_STOP] or iterations >= dofs:
                state.cg[g, CG_DONE] = scalar(1.0)

    @wp.func(inline=True)
    def direction_range(g: int, lo: int, hi: int, state: State):
        """p = z + beta p over dofs lo..hi-1 of group g (until done)."""
        if not cg_done(g, state):
            beta = state.cg[g, CG_BETA]
            for d in range(lo, hi):
                state.p[d] = state.z[d] + beta * state.p[d]

    # ------------------------------------------------------------- the step

    @wp.func(inline=True)
    def move_node(i: int, data: Data, state: State):
        """previous = x, v += dv, x += dt v at node i."""
        dt = state.dt[data.node_group[i]]
        state.previous_position[i] = state.position[i]
        dv = vec()
        for c in range(dim):
            dv[c] = state.x[dim * i + c]
        v = state.velocity[i] + dv
        state.velocity[i] = v
        state.position[i] = state.position[i] + dt * v

    @wp.func(inline=True)
    def search(g: int, data: Data, state: State, settings: Settings):
        """The line search's decision on the positions just evaluated: ACCEPT where the merit
        fell, else TRIAL at half the length while halvings remain, else UNDO."""
        merit = checks.group_sum(g, data, state)[2]
        if merit < state.merit[g]:
            state.decision[g] = scalar(ACCEPT)
        elif state.search[g] < settings.backtracks:
            state.search[g] = state.search[g] + 1
            state.backtracks[g] = state.backtracks[g] + 1
            state.step_length[g] = scalar(0.5) * state.step_length[g]
            state.decision[g] = scalar(TRIAL)
        else:
            state.decision[g] = scalar(UNDO)

    @wp.func(inline=True)
    def trial_node(i: int, data: Data, state: State):
        """x = previous + alpha dt v where the group tries a shorter step."""
        g = data.node_group[i]
        if state.decision[g] == scalar(TRIAL):
            state.position[i] = state.previous_position[i] \
                + (state.step_length[g] * state.dt[g]) * state.velocity[i]

    @wp.func(inline=True)
    def finish_node(i: int, data: Data, state: State):
        """Accepted at alpha < 1: v *= alpha; undone: back at rest."""
        g = data.node_group[i]
        if state.decision[g] == scalar(UNDO):
            state.position[i] = state.previous_position[i]
            state.velocity[i] = vec()
        elif state.step_length[g] < scalar(1.0):
            state.velocity[i] = state.step_length[g] * state.velocity[i]

    @wp.func(inline=True)
    def finish_group(g: int, data: Data, state: State):
        """dt and the counters after the line search; the accepted merit."""
        if state.decision[g] == scalar(UNDO):
            state.rejected[g] = state.rejected[g] + 1
            state.dt[g] = state.dt[g] * scalar(DT_SHRINK)
        else:
            state.merit[g] = checks.group_sum(g, data, state)[2]
            if state.step_length[g] < scalar(1.0):
                state.shortened[g] = state.shortened[g] + 1
            else:
                state.dt[g] = wp.min(state.dt[g] * scalar(DT_GROWTH), scalar(DT_MAX))
        state.cg_iterations[g] = state.cg_iterations[g] + int(state.cg[g, CG_ITERATIONS])

    @wp.func(inline=True)
    def reset_flags(g: int, state: State):
        """A new time step: not factored, CG not done, no halving, full length, no decision."""
        state.factored[g] = 0
        state.cg[g, CG_DONE] = scalar(0.0)
        state.refactorisations[g] = 0
        state.search[g] = 0
        state.step_length[g] = scalar(1.0)
        state.decision[g] = scalar(0.0)

    @wp.func(inline=True)
    def check_step(g: int, data: Data, state: State, settings: Settings):
        """`structure_checks.check` and the progress test; the next step's flags reset."""
        checks.check_progress(g, state, checks.check(g, data, state, settings),
                              structure_checks.STALL_MIN_STEPS)
        reset_flags(g, state)

    @wp.func(inline=True)
    def unit_stage(stage: int, u: int, data: Data, state: State, settings: Settings):
        """Stage `stage` on unit u, if its group runs (and, where it applies, still searches,
        still factors or is undone)."""
        if stage == TIE_BLOCKS:
            if running(state, data.tie_group[u]):
                tie_blocks(u, data, state, settings)
        elif stage == BUILD:
            g = data.chain_group[u]
            if running(state, g) and state.factored[g] == 0:
                build_chain(u, data, state, settings)
        elif stage == FACTORED:
            if running(state, u) and state.factored[u] == 0:
                factored(u, data, state, settings)
        elif stage == VELOCITY:
            g = data.node_group[u / dim]
            if running(state, g) and not direct_done(g, state):
                state.x[u] = state.velocity[u / dim][u % dim]
        elif stage == BOUNDARY:
            if running(state, u) and not direct_done(u, state):
                boundary_sums(u, state.x, data, state)
                tie_diagonals(u, data, state)
        elif stage == RHS:
            g = data.node_group[u]
            if running(state, g) and not direct_done(g, state):
                rhs_node(u, data, state)
        elif stage == CG_START:
            g = data.node_group[u / dim]
            if running(state, g) and not direct_done(g, state):
                cg_start(u, state)
        elif stage == PRECONDITION:
            g = data.chain_group[u]
            if running(state, g) and not cg_done(g, state):
                precondition_chain(u, data, state)
        elif stage == FIRST_SUM:
            if running(state, u) and not direct_done(u, state):
                first_sum(u, data, state, settings)
        elif stage == COPY:
            g = data.node_group[u / dim]
            if running(state, g) and not direct_done(g, state):
                copy_direction(u, data, state)
        elif stage == CG_BOUNDARY:
            if running(state, u) and not cg_done(u, state):
                boundary_sums(u, state.p, data, state)
        elif stage == PRODUCT:
            g = data.node_group[u]
            if running(state, g) and not cg_done(g, state):
                product_node(u, data, state, state.dt[g] * state.dt[g])
        elif stage == CURVATURE:
            g = data.chain_group[u]
            if running(state, g) and not cg_done(g, state):
                curvature_chain(u, data, state)
        elif stage == STEP_LENGTH:
            if running(state, u) and not cg_done(u, state):
                step_length(u, data, state)
        elif stage == UPDATE:
            g = data.node_group[u / dim]
            if running(state, g):
                update_range(g, u, u + 1, state)
        elif stage == NEXT_SUM:
            if running(state, u):
                next_sum(u, data, state)
        elif stage == DIRECTION:
            g = data.node_group[u / dim]
            if running(state, g):
                direction_range(g, u, u + 1, state)
        elif stage == MOVE:
            if running(state, data.node_group[u]):
                move_node(u, data, state)
        elif stage == TIES:
            if searching(state, data.tie_group[u]):
                forces.tie_pass(u, state.position, data, state)
        elif stage == GATHER:
            if searching(state, data.node_group[u]):
                checks.gather_node(u, data, state, settings)
        elif stage == BLOCKS:
            if searching(state, data.block_group[u]):
                checks.block_stage(u, data, state)
        elif stage == SEARCH:
            if searching(state, u):
                search(u, data, state, settings)
        elif stage == TRIAL_MOVE:
            if running(state, data.node_group[u]):
                trial_node(u, data, state)
        elif stage == FINISH:
            if running(state, data.node_group[u]):
                finish_node(u, data, state)
        elif stage == RE_TIES:
            if undone(state, data.tie_group[u]):
                forces.tie_pass(u, state.position, data, state)
        elif stage == RE_GATHER:
            if undone(state, data.node_group[u]):
                checks.gather_node(u, data, state, settings)
        elif stage == RE_BLOCKS:
            if undone(state, data.block_group[u]):
                checks.block_stage(u, data, state)
        elif stage == FINISH_GROUP:
            if running(state, u):
                finish_group(u, data, state)
        elif stage == CHECK:
            if running(state, u):
                check_step(u, data, state, settings)

    return SimpleNamespace(running=running, tie_blocks=tie_blocks, build_chain=build_chain,
                           factored=factored, boundary_sums=boundary_sums,
                           tie_diagonals=tie_diagonals, rhs_node=rhs_node,
                           precondition_chain=precondition_chain, cg_start=cg_start,
                           first_sum=first_sum, copy_direction=copy_direction, cg_done=cg_done,
                           product_node=product_node, curvature_chain=curvature_chain,
                           step_length=step_length, update_range=update_range, next_sum=next_sum,
                           direction_range=direction_range, move_node=move_node, search=search,
                           trial_node=trial_node, finish_node=finish_node,
                           finish_group=finish_group, check_step=check_step,
                           reset_flags=reset_flags,
                           unit_stage=unit_stage, product_value=product_value,
                           direct_done=direct_done)


@structure_variants.variant("semi_implicit", "node_parallel")
def stage_kernel(scalar, friction: bool, boundary: bool, kinematics: str = "planar"):
    """The node-parallel layout's kernel: one launch per stage, a thread per unit; the start's
    stages are `structure_explicit`'s (`START_STAGES`), with the merit."""
    Data, State, Settings = structure_variants.structs(scalar, KINEMATICS[kinematics])
    ops = functions(scalar, friction, boundary, kinematics)
    checks = structure_checks.functions(scalar, friction, boundary, True, kinematics)
    forces = structure_forces.functions(scalar, friction, boundary, kinematics)
    from dynfab.kernels import structure_explicit as explicit
    stiffest = explicit.functions(scalar, friction, boundary, kinematics)

    @wp.kernel(module="unique", module_options=structure_settings.MODULE_OPTIONS)
    def stage_pass(data: Data, state: State, settings: Settings, stage: int):
        u = wp.tid()
        if stage >= 100:
            ops.unit_stage(stage, u, data, state, settings)
        elif stage == explicit.START_TIES:
            forces.tie_pass(u, state.position, data, state)
        elif stage == explicit.START_GATHER:
            checks.gather_node(u, data, state, settings)
        elif stage == explicit.START_BLOCKS:
            checks.block_stage(u, data, state)
        elif stage == explicit.STIFFEST_TIES or stage == explicit.STIFFEST_CHAINS:
            stiffest.unit_stage(stage, u, data, state, settings)  # the planar band's (only)
        elif stage == explicit.ROWS:
            checks.rows_node(u, data, state, settings)
        elif stage == explicit.START:
            checks.start_group(u, data, state, settings)
            ops.reset_flags(u, state)

    return stage_pass


@structure_variants.variant("semi_implicit", "grouped")
def grouped_kernel(scalar, friction: bool, boundary: bool, order: str,
                   kinematics: str = "planar"):
    """The grouped layout's kernel: thread g runs group first + g, the start (`begin` != 0) or
    up to settings.chunk time steps. `order` "gather" evaluates the forces as the node-parallel
    layout does (the same bits); "scatter" in scatter order."""
    dim = KINEMATICS[kinematics]
    Data, State, Settings = structure_variants.structs(scalar, dim)
    ops = functions(scalar, friction, boundary, kinematics)

    group = structure_checks.group_functions(scalar, friction, boundary, order, True,
                                             kinematics=kinematics)
    evaluate = group.evaluate

    @wp.func(inline=True)
    def start(g: int, data: Data, state: State, settings: Settings):
        group.start(g, data, state, settings)
        ops.reset_flags(g, state)

    @wp.func(inline=True)
    def solve(g: int, data: Data, state: State, settings: Settings):
        """x = A^-1 rhs by PCG from x = 0 (module docstring)."""
        lo = dim * data.group_node[g]
        hi = dim * data.group_node[g + 1]
        c0 = data.group_chain[g]
        c1 = data.group_chain[g + 1]
        for d in range(lo, hi):
            ops.cg_start(d, state)
        for c in range(c0, c1):
            ops.precondition_chain(c, data, state)
        ops.first_sum(g, data, state, settings)
        for d in range(lo, hi):
            ops.copy_direction(d, data, state)
        dt2 = state.dt[g] * state.dt[g]
        while not ops.cg_done(g, state):
            ops.boundary_sums(g, state.p, data, state)
            for i in range(lo / dim, hi / dim):
                ops.product_node(i, data, state, dt2)
            for c in range(c0, c1):
                ops.curvature_chain(c, data, state)
            ops.step_length(g, data, state)
            ops.update_range(g, lo, hi, state)
            if not ops.cg_done(g, state):
                for c in range(c0, c1):
                    ops.precondition_chain(c, data, state)
            ops.next_sum(g, data, state)
            ops.direction_range(g, lo, hi, state)

    @wp.func(inline=True)
    def step(g: int, data: Data, state: State, settings: Settings):
        lo = data.group_node[g]
        hi = data.group_node[g + 1]
        for t in range(data.group_tie[g], data.group_tie[g + 1]):
            ops.tie_blocks(t, data, state, settings)
        while ops.running(state, g) and state.factored[g] == 0:
            for c in range(data.group_chain[g], data.group_chain[g + 1]):
                ops.build_chain(c, data, state, settings)
            ops.factored(g, data, state, settings)
        if ops.running(state, g):
            if not ops.direct_done(g, state):
                for d in range(dim * lo, dim * hi):
                    state.x[d] = state.velocity[d / dim][d % dim]
                ops.boundary_sums(g, state.x, data, state)
                ops.tie_diagonals(g, data, state)
                for i in range(lo, hi):
                    ops.rhs_node(i, data, state)
                solve(g, data, state, settings)
            for i in range(lo, hi):
                ops.move_node(i, data, state)
            evaluate(g, data, state, settings)
            ops.search(g, data, state, settings)
            while state.decision[g] == scalar(TRIAL):
                for i in range(lo, hi):
                    ops.trial_node(i, data, state)
                evaluate(g, data, state, settings)
                ops.search(g, data, state, settings)
            for i in range(lo, hi):
                ops.finish_node(i, data, state)
            if state.decision[g] == scalar(UNDO):
                evaluate(g, data, state, settings)
            ops.finish_group(g, data, state)
            ops.check_step(g, data, state, settings)

    return structure_checks.grouped_relax(scalar, start, step, dim)
