"""Explicit relaxation of any structure: symplectic Euler with viscous (given or adaptive c),
kinetic (Barnes) or FIRE 2.0 damping (docs/model.md section 5, "The dynamic solver (decisions)").

    v^{n+1/2} = keep v^{n-1/2} + (gain / m) f(x^n),   x^{n+1} = x^n + dt v^{n+1/2},

keep = (1 - c dt/2) / (1 + c dt/2), gain = dt / (1 + c dt/2) (the damping force centred in
time; c = 0 undamped). The dampings (whose decisions docs/model.md records, "The dynamic
solver (decisions)"):
- viscous: c given, or adaptive (a negative settings coefficient): c = 2 sqrt(q), q by
  Underwood's diagonal estimate u^T K u / u^T M u where positive and below the secant
  -u . (f - f0) / u^T M u, else the secant; capped at 2 / dt;
- kinetic: when the kinetic energy a full step would reach falls below the last one, the peak
  has passed: x -= dt/2 v, v = 0 (that energy, sum_i 1/2 m_i |v_i + (dt / m_i) f_i|^2, is
  summed by the force pass before it, `structure_checks.force_values`); after KINETIC_STEPS
  steps a group still running continues with viscous damping at c dt = FALLBACK_DAMPING, c
  doubling (at most c dt = 2) after each STALL_STEPS steps without a new low of the residual;
- FIRE 2.0: with P = f . v, dt grows by DT_GROWTH (at most DT_MAX x the stable dt) and alpha
  shrinks after DELAY_STEPS positive steps; P <= 0 shrinks dt (not below DT_MIN x) after the
  first DELAY_STEPS steps, resets alpha, backs x by dt/2 v and zeroes v (MAX_NEGATIVE_STEPS in
  a row: STALLED); then v += dt M^-1 f, v = (1 - alpha) v + alpha |v| f / |f|, x += dt v.

Every step is a sequence of stages, each a `wp.func` of one unit (node, tie, block or group):
`PRE` (per node: the damping's terms), `BLOCKS` (the adaptive c and FIRE), `DECIDE` (per
group: the kinetic peak, the adaptive c, FIRE's dt and alpha), `MOVE` (per node), for FIRE
`BLOCKS`, `MIX` (per group) and `MIX_MOVE` (per node), then the forces at the new positions
(`TIES` per tie and `GATHER` per node, or the group's scatter), `BLOCKS` and `CHECK` (per
group: `structure_checks`). Two layouts of the same stages:

- "grouped" (the CPU's): one thread per group runs the time loop inside the kernel, each stage
  a loop over the group's units, up to `settings.chunk` steps per launch; the forces in
  "scatter" order by default (each term once), or in "gather" order, the node-parallel
  layout's arithmetic in its order (the same bits);
- "node_parallel" (the GPU's): a launch per stage with a thread per unit (`stage_kernel`),
  the time loop in Python; every thread returns at once when its group has stopped, so a
  launch of a finished group changes nothing.

A group's sums (kinetic energy, power, Underwood's quotients, the energy check's work) are
each node's term summed per block in node order, then over the blocks: the same in both
layouts. Tied families count once (`StructureArrays.share`).
"""

import functools
from types import SimpleNamespace

import warp as wp

from dynfab.kernels import status, structure_checks, structure_forces, structure_settings
from dynfab.kernels import structure_variants
from dynfab.kernels.precision import KINEMATICS, vector
from dynfab.kernels.structure_settings import FIRE, KINETIC, VISCOUS
ORDERS = ("scatter", "gather")
KINETIC_STEPS = 200_000
"""Time steps of kinetic damping before the viscous fallback (docs/model.md, kinetic damping)."""
STALL_STEPS = 100_000
"""Steps without a new low of the residual after which the fallback's c doubles."""
FALLBACK_DAMPING = 0.05
"""c dt [-] of the first viscous fallback."""
FALLBACK_GROWTH = 2.0
"""Factor on the fallback's c at each further stall [-]."""
DELAY_STEPS = 20
"""FIRE's N_delay."""
MAX_NEGATIVE_STEPS = 2000
"""FIRE's N_neg_max: non-positive-power steps in a row after which FIRE has stalled."""
DT_GROWTH = 1.1
"""FIRE's f_inc [-]."""
DT_SHRINK = 0.5
"""FIRE's f_dec [-]."""
ALPHA_START = 0.25
"""FIRE's alpha_start [-]."""
ALPHA_SHRINK = 0.99
"""FIRE's f_alpha [-]."""
DT_START = 0.5
"""FIRE's largest starting dt / stable dt [-] (docs/results.md, "FIRE's largest time step")."""
DT_MAX = 0.6
"""FIRE's dt_max / stable dt [-]."""
DT_MIN = 0.02
"""FIRE's dt_min / stable dt [-]."""

START_TIES, START_GATHER, START_BLOCKS, STIFFEST_TIES, STIFFEST_CHAINS, ROWS, START, \
    START_DAMPING, PRE, BLOCKS, DECIDE, MOVE, MIX, MIX_MOVE, TIES, GATHER, CHECK = range(17)
"""Stages (`stage_kernel`)."""
NODE, TIE, BLOCK, CHAIN, GROUP = range(5)
"""What a stage's threads run over."""
KINDS = {START_TIES: TIE, START_GATHER: NODE, START_BLOCKS: BLOCK, STIFFEST_TIES: TIE,
         STIFFEST_CHAINS: CHAIN,
         ROWS: NODE, START: GROUP, START_DAMPING: GROUP, PRE: NODE, BLOCKS: BLOCK,
         DECIDE: GROUP, MOVE: NODE, MIX: GROUP, MIX_MOVE: NODE, TIES: TIE, GATHER: NODE,
         CHECK: GROUP}
START_STAGES = (START_TIES, START_GATHER, START_BLOCKS, STIFFEST_TIES, STIFFEST_CHAINS, ROWS,
                START, START_DAMPING)


def step_stages(damping: str, adaptive: bool) -> tuple:
    """The stages of one time step for `damping` (viscous with `adaptive` c or not)."""
    pre = (PRE, BLOCKS, DECIDE) if damping == "fire" or adaptive else ()
    if damping == "kinetic":  # the last force pass summed the trial step's energy
        pre = (DECIDE,)
    mix = (BLOCKS, MIX, MIX_MOVE) if damping == "fire" else ()
    return (*pre, MOVE, *mix, TIES, GATHER, BLOCKS, CHECK)


@functools.cache
def functions(scalar, friction: bool, boundary: bool,
              kinematics: str = "planar") -> SimpleNamespace:
    """The stage `wp.func`s of one variant (module docstring)."""
    dim = KINEMATICS[kinematics]
    vec = vector(scalar, dim)
    vec4 = wp.types.vector(4, scalar)
    Data, State, Settings = structure_variants.structs(scalar, dim)
    forces = structure_forces.functions(scalar, friction, boundary, kinematics)
    checks = structure_checks.functions(scalar, friction, boundary, kinematics=kinematics)
    elements = structure_forces.KINDS[kinematics]
    stiffens = elements.STIFFENS_IN_A_STEP
    stall_min_steps = elements.STALL_MIN_STEPS[dim] if stiffens else 0

    @wp.func(inline=True)
    def running(state: State, g: int) -> bool:
        return state.status[g] == int(status.RUNNING)

    @wp.func(inline=True)
    def start_damping(g: int, state: State, settings: Settings):
        """The damping's state at the step's start (FIRE: dt at most DT_START x stable)."""
        if settings.damping == FIRE:
            state.dt[g] = wp.min(state.dt[g], scalar(DT_START) * state.stable_dt[g])
            state.fire_alpha[g] = scalar(ALPHA_START)
            state.fire_positive[g] = 0
            state.fire_negative[g] = 0

    @wp.func(inline=True)
    def pre_values(i: int, data: Data, state: State, settings: Settings) -> vec4:
        """The damping's terms of node i (module docstring): the adaptive c's, FIRE's."""
        g = data.node_group[i]
        share = data.share[i]
        values = vec4(scalar(0.0), scalar(0.0), scalar(0.0), scalar(0.0))
        if settings.damping == VISCOUS:
            u = state.position[i] - state.start_position[i]
            change = state.force[i] - state.previous_force[i]
            underwood = scalar(0.0)
            for c in range(wp.static(dim)):
                moved = state.dt[g] * state.velocity[i][c]
                if moved != scalar(0.0):
                    underwood += u[c] * u[c] * (-change[c] / moved)
            secant = -wp.dot(u, state.force[i] - state.start_force[i])
            values = vec4(share * underwood, share * secant,
                          share * (wp.dot(u, u) * state.mass[i]), scalar(0.0))
        if settings.damping == FIRE:
            values[0] = share * wp.dot(state.force[i], state.velocity[i])
        return values

    @wp.func(inline=True)
    def pre_blocks(g: int, data: Data, state: State, settings: Settings):
        """Every node's `pre_values` summed straight into its block's sums (what the
        node-parallel layout's PRE and BLOCKS stages store and sum)."""
        for b in range(data.group_block[g], data.group_block[g + 1]):
            total = vec4(scalar(0.0), scalar(0.0), scalar(0.0), scalar(0.0))
            for i in range(data.block_start[b], data.block_start[b + 1]):
                total = total + pre_values(i, data, state, settings)
            state.block_values[b] = total

    @wp.func(inline=True)
    def decide(g: int, data: Data, state: State, settings: Settings):
        """The damping's decision for the step from the group's sums (module docstring)."""
        sums = checks.group_sum(g, data, state)
        if settings.damping == KINETIC:  # the trial step's energy, from the last force pass
            state.decision[g] = scalar(0.0)
            if state.steps[g] > 0 and sums[2] < state.kinetic_energy[g]:
                state.decision[g] = scalar(1.0)
        if settings.damping == VISCOUS:
            stiffness = sums[1]
            if sums[0] > scalar(0.0) and sums[0] < sums[1]:
                stiffness = sums[0]
            c = scalar(0.0)
            if stiffness > scalar(0.0) and sums[2] > scalar(0.0):
                c = wp.min(scalar(2.0) * wp.sqrt(stiffness / sums[2]), scalar(2.0) / state.dt[g])
            state.damping_coefficient[g] = c
        if settings.damping == FIRE:
            dt = state.dt[g]
            stable = state.stable_dt[g]
            state.decision[g] = scalar(0.0)
            if sums[0] > scalar(0.0):
                state.fire_positive[g] = state.fire_positive[g] + 1
                state.fire_negative[g] = 0
                if state.fire_positive[g] > DELAY_STEPS:
                    dt = wp.min(dt * scalar(DT_GROWTH), scalar(DT_MAX) * stable)
                    state.fire_alpha[g] = state.fire_alpha[g] * scalar(ALPHA_SHRINK)
            else:
                state.fire_positive[g] = 0
                state.fire_negative[g] = state.fire_negative[g] + 1
                if state.fire_negative[g] > MAX_NEGATIVE_STEPS:
                    state.status[g] = int(status.STALLED)
                if state.steps[g] >= DELAY_STEPS:
                    if dt * scalar(DT_SHRINK) >= scalar(DT_MIN) * stable:
                        dt = dt * scalar(DT_SHRINK)
                    state.fire_alpha[g] = scalar(ALPHA_START)
                state.decision[g] = scalar(1.0)
            state.dt[g] = dt

    @wp.func(inline=True)
    def viscous_factors(dt: scalar, c: scalar, store: scalar) -> vec4:
        """(dt [s], keep [-], gain [s], store) of the centred viscous step at c [1/s]; `store`
        1 keeps the step's force (the adaptive c's next estimate)."""
        half = scalar(0.5) * c * dt
        return vec4(dt, (scalar(1.0) - half) / (scalar(1.0) + half), dt / (scalar(1.0) + half),
                    store)

    @wp.func(inline=True)
    def step_factors(g: int, state: State, settings: Settings) -> vec4:
        """The group's `viscous_factors` for this step: the given or adaptive c (viscous), the
        fallback's c or none (kinetic: keep 1, gain dt), none (FIRE)."""
        dt = state.dt[g]
        factors = vec4(dt, scalar(1.0), dt, scalar(0.0))
        if settings.damping == KINETIC:
            c = state.damping_coefficient[g]
            if c > scalar(0.0):
                factors = viscous_factors(dt, c, scalar(0.0))
        if settings.damping == VISCOUS:
            c = settings.damping_coefficient
            store = scalar(0.0)
            if c < scalar(0.0):
                c = state.damping_coefficient[g]
                store = scalar(1.0)
            factors = viscous_factors(dt, c, store)
        return factors

    @wp.func(inline=True)
    def viscous_move(i: int, state: State, factors: vec4):
        """v = keep v + (gain / m) f, x += dt v (module docstring)."""
        v = factors[1] * state.velocity[i] + (factors[2] / state.mass[i]) * state.force[i]
        state.velocity[i] = v
        state.position[i] = state.position[i] + factors[0] * v
        if factors[3] != scalar(0.0):
            state.previous_force[i] = state.force[i]

    @wp.func(inline=True)
    def move_node(i: int, data: Data, state: State, settings: Settings, factors: vec4):
        """Node i's update with its group's `step_factors` (module docstring); FIRE:
        node_values = (|v|^2, |f|^2) for `mix`."""
        g = data.node_group[i]
        dt = factors[0]
        if settings.damping == KINETIC:
            if state.damping_coefficient[g] == scalar(0.0) and state.decision[g] != scalar(0.0):
                state.position[i] = state.position[i] - (scalar(0.5) * dt) * state.velocity[i]
                state.velocity[i] = vec()
            else:
                viscous_move(i, state, factors)
        if settings.damping == VISCOUS:
            viscous_move(i, state, factors)
        if settings.damping == FIRE:
            if state.decision[g] != scalar(0.0):
                state.position[i] = state.position[i] - (scalar(0.5) * dt) * state.velocity[i]
                state.velocity[i] = vec()
            v = state.velocity[i] + (dt / state.mass[i]) * state.force[i]
            state.velocity[i] = v
            share = data.share[i]
            state.node_values[i] = vec4(share * wp.dot(v, v),
                                        share * wp.dot(state.force[i], state.force[i]),
                                        scalar(0.0), scalar(0.0))

    @wp.func(inline=True)
    def mix(g: int, data: Data, state: State):
        """FIRE's mixing alpha |v| / |f| from the group's sums."""
        sums = checks.group_sum(g, data, state)
        mixing = scalar(0.0)
        if sums[1] > scalar(0.0):
            mixing = state.fire_alpha[g] * wp.sqrt(sums[0] / sums[1])
        state.mixing[g] = mixing

    @wp.func(inline=True)
    def mix_move(i: int, data: Data, state: State):
        """FIRE: v = (1 - alpha) v + mixing f, x += dt v."""
        g = data.node_group[i]
        v = (scalar(1.0) - state.fire_alpha[g]) * state.velocity[i] \
            + state.mixing[g] * state.force[i]
        state.velocity[i] = v
        state.position[i] = state.position[i] + state.dt[g] * v

    @wp.func(inline=True)
    def escalate(g: int, data: Data, state: State):
        """Kinetic damping's viscous fallback (module docstring), from rest."""
        c = state.damping_coefficient[g]
        dt = state.dt[g]
        change = bool(False)
        if c == scalar(0.0):
            if state.steps[g] >= KINETIC_STEPS:
                c = scalar(FALLBACK_DAMPING) / dt
                change = True
        elif state.steps_since_best[g] >= STALL_STEPS:
            c = wp.min(c * scalar(FALLBACK_GROWTH), scalar(2.0) / dt)
            change = True
        if change:
            state.damping_coefficient[g] = c
            for i in range(data.group_node[g], data.group_node[g + 1]):
                state.velocity[i] = vec()
            state.kinetic_energy[g] = scalar(0.0)
            state.best_residual[g] = state.residual[g]
            state.steps_since_best[g] = 0

    @wp.func(inline=True)
    def check_step(g: int, data: Data, state: State, settings: Settings):
        """`structure_checks.check`, the energy test, kinetic damping's fallback; where a step
        can stiffen the elements past its masses (`STIFFENS_IN_A_STEP`: crossings that slide,
        docs/model.md 11.13), the progress test too (`structure_checks.check_progress`, after
        the elements' `STALL_MIN_STEPS`)."""
        code = checks.check_energy(g, data, state, checks.check(g, data, state, settings))
        if wp.static(stiffens):
            code = checks.check_progress(g, state, code, stall_min_steps)
        if settings.damping == KINETIC:
            if code == int(status.RUNNING):
                escalate(g, data, state)

    @wp.func(inline=True)
    def unit_stage(stage: int, u: int, data: Data, state: State, settings: Settings):
        """Stage `stage` on unit u (a node, tie, block, chain or group), if its group runs."""
        if stage == START_TIES:
            forces.tie_pass(u, state.position, data, state)
        elif stage == START_GATHER:
            checks.gather_node(u, data, state, settings)
        elif stage == START_BLOCKS:
            checks.block_stage(u, data, state)
        elif stage == STIFFEST_TIES:
            checks.stiffest_tie(u, data, state)
        elif stage == STIFFEST_CHAINS:
            checks.stiffest_chain(u, data, state)
        elif stage == ROWS:
            checks.rows_node(u, data, state, settings)
        elif stage == START:
            checks.start_group(u, data, state, settings)
        elif stage == START_DAMPING:
            start_damping(u, state, settings)
        elif stage == PRE:
            if running(state, data.node_group[u]):
                state.node_values[u] = pre_values(u, data, state, settings)
        elif stage == BLOCKS:
            if running(state, data.block_group[u]):
                checks.block_stage(u, data, state)
        elif stage == DECIDE:
            if running(state, u):
                decide(u, data, state, settings)
        elif stage == MOVE:
            g = data.node_group[u]
            if running(state, g):
                move_node(u, data, state, settings, step_factors(g, state, settings))
        elif stage == MIX:
            if running(state, u):
                mix(u, data, state)
        elif stage == MIX_MOVE:
            if running(state, data.node_group[u]):
                mix_move(u, data, state)
        elif stage == TIES:
            if running(state, data.tie_group[u]):
                forces.tie_pass(u, state.position, data, state)
        elif stage == GATHER:
            if running(state, data.node_group[u]):
                checks.gather_node(u, data, state, settings)
        elif stage == CHECK:
            if running(state, u):
                check_step(u, data, state, settings)

    return SimpleNamespace(running=running, start_damping=start_damping, pre_blocks=pre_blocks,
                           decide=decide, move_node=move_node, mix=mix, mix_move=mix_move,
                           check_step=check_step, unit_stage=unit_stage, viscous_move=viscous_move,
                           viscous_factors=viscous_factors, step_factors=step_factors)


@structure_variants.variant("explicit", "node_parallel")
def stage_kernel(scalar, friction: bool, boundary: bool, kinematics: str = "planar"):
    """The node-parallel layout's kernel: one launch per stage, a thread per unit."""
    Data, State, Settings = structure_variants.structs(scalar, KINEMATICS[kinematics])
    ops = functions(scalar, friction, boundary, kinematics)

    @wp.kernel(module="unique", module_options=structure_settings.MODULE_OPTIONS)
    def stage_pass(data: Data, state: State, settings: Settings, stage: int):
        ops.unit_stage(stage, wp.tid(), data, state, settings)

    return stage_pass


@structure_variants.variant("explicit", "grouped")
def grouped_kernel(scalar, friction: bool, boundary: bool, order: str,
                   kinematics: str = "planar"):
    """The grouped layout's kernel: thread g runs group first + g, the start (`start` != 0)
    or up to settings.chunk time steps; `kinematics` "spatial": vec3 nodes and the spatial
    terms (`structure_forces`), in either order."""
    dim = KINEMATICS[kinematics]
    Data, State, Settings = structure_variants.structs(scalar, dim)
    ops = functions(scalar, friction, boundary, kinematics)
    forces = structure_forces.functions(scalar, friction, boundary, kinematics)
    group = structure_checks.group_functions(scalar, friction, boundary, order,
                                             kinematics=kinematics)
    blocks, evaluate = group.blocks, group.evaluate
    scatter = order == "scatter"

    @wp.func(inline=True)
    def start(g: int, data: Data, state: State, settings: Settings):
        group.start(g, data, state, settings)
        ops.start_damping(g, state, settings)

    @wp.func(inline=True)
    def step(g: int, data: Data, state: State, settings: Settings):
        lo = data.group_node[g]
        hi = data.group_node[g + 1]
        pre = settings.damping == FIRE
        if settings.damping == VISCOUS:
            pre = settings.damping_coefficient < scalar(0.0)
        if pre:
            ops.pre_blocks(g, data, state, settings)
            ops.decide(g, data, state, settings)
        elif settings.damping == KINETIC:  # its energy is summed already
            if state.damping_coefficient[g] == scalar(0.0):
                ops.decide(g, data, state, settings)
        if ops.running(state, g):
            factors = ops.step_factors(g, state, settings)
            if settings.damping == FIRE:
                for i in range(lo, hi):
                    ops.move_node(i, data, state, settings, factors)
                blocks(g, data, state)
                ops.mix(g, data, state)
                for i in range(lo, hi):
                    ops.mix_move(i, data, state)
                evaluate(g, data, state, settings)
            else:  # the move and the scatter's start in one pass
                for i in range(lo, hi):
                    ops.move_node(i, data, state, settings, factors)
                    if wp.static(scatter):
                        state.force[i] = forces.external(i, state.position, data, state)
                group.evaluate_set(g, data, state, settings)
            ops.check_step(g, data, state, settings)

    return structure_checks.grouped_relax(scalar, start, step, dim)
