"""Transient dynamics of any structure in physical time: symplectic Euler with viscous c
(default 0), the anchors return-mapped at every step (docs/model.md sections 4, 5).

Each time step from the force f^n at x^n and time t:

    v = keep v + (gain / m) f^n,   x += dt v         (`structure_explicit.viscous_move`)

then the loads at t + dt: each row of the path follows the piecewise-linear ramp through
(0, 0) and (k T / n, value_k), k = 1..n (T = settings.duration, held after T). A driven node
(`load_family` >= 0, the row of its first component) on a free dof takes an end force, row
`load_family` times its `load_direction`; on a held one, each component c its direction names
(direction[c] != 0) a prescribed displacement x_c = x0_c + direction[c] u_c(t + dt), u_c the
row `load_family` + c, with the ramp's velocity direction[c] (u_c(t + dt) - u_c(t)) / dt (a
chain end pulled along x: one row; a specimen's held node: its own three rows, the frame's
turn sampled finely, `dynfab.model.loading.Drive`); then f^{n+1} at the new positions and
every tie's anchor return-mapped, its dissipation F_T |delta xi| added to the
tie's total (`StructureState.dissipated`). The masses are the physical ones and dt at most the
Gershgorin bound x safety (`structure_checks`' start with fictitious = 0); the host shortens dt
to land on the output times. A non-finite kinetic energy stops the group (NON_FINITE).

Stages (both layouts, as `structure_explicit`): `T_MOVE` (per node), `T_TIES` (per tie),
`T_GATHER` (per node), `T_BLOCKS` (per block), `T_RETURN` (per tie), `T_CHECK` (per group).
"""

import functools
from types import SimpleNamespace

import warp as wp

from dynfab.kernels import status, structure_checks, structure_explicit, structure_forces
from dynfab.kernels import structure_settings, structure_variants
from dynfab.kernels.precision import KINEMATICS, vector

T_MOVE, T_TIES, T_GATHER, T_BLOCKS, T_RETURN, T_CHECK = range(200, 206)
"""Stages of a transient time step (`stage_kernel`; the start's are `structure_explicit`'s)."""
NODE, TIE, BLOCK, GROUP = (structure_explicit.NODE, structure_explicit.TIE,
                          structure_explicit.BLOCK, structure_explicit.GROUP)
KINDS = {T_MOVE: NODE, T_TIES: TIE, T_GATHER: NODE, T_RETURN: TIE, T_BLOCKS: BLOCK,
         T_CHECK: GROUP}
STEP_STAGES = (T_MOVE, T_TIES, T_GATHER, T_BLOCKS, T_RETURN, T_CHECK)


@functools.cache
def functions(scalar, friction: bool, boundary: bool,
              kinematics: str = "planar") -> SimpleNamespace:
    """The transient stage `wp.func`s of one variant."""
    dim = KINEMATICS[kinematics]
    vec = vector(scalar, dim)
    Data, State, Settings = structure_variants.structs(scalar, dim)
    forces = structure_forces.functions(scalar, friction, boundary, kinematics)
    checks = structure_checks.functions(scalar, friction, boundary, kinematics=kinematics)
    explicit = structure_explicit.functions(scalar, friction, boundary, kinematics)

    @wp.func(inline=True)
    def load_at(time: scalar, path: wp.array2d(dtype=scalar), family: int,
                duration: scalar) -> scalar:
        """Family `family`'s load value [N or m] at `time` [s] (module docstring)."""
        n = path.shape[1]
        position = wp.min(time / duration, scalar(1.0)) * scalar(n)
        k = wp.min(int(position), n - 1)
        before = scalar(0.0)
        if k > 0:
            before = path[family, k - 1]
        return before + (position - scalar(k)) * (path[family, k] - before)

    @wp.func(inline=True)
    def drive(i: int, data: Data, state: State, path: wp.array2d(dtype=scalar), time: scalar,
              dt: scalar, duration: scalar):
        """Node i's load at time + dt: an end force on a free dof, a prescribed displacement
        and its ramp velocity on each held component its direction names (module
        docstring)."""
        family = data.load_family[i]
        if family >= 0:
            direction = data.load_direction[i]
            if data.free[i][0] != scalar(0.0):
                state.load[i] = load_at(time + dt, path, family, duration) * direction
            else:
                position = state.position[i]
                velocity = state.velocity[i]
                for c in range(wp.static(dim)):
                    if direction[c] != scalar(0.0):
                        after = load_at(time + dt, path, family + c, duration)
                        before = load_at(time, path, family + c, duration)
                        position[c] = data.rest_position[i][c] + after * direction[c]
                        velocity[c] = (after - before) * direction[c] / dt
                state.position[i] = position
                state.velocity[i] = velocity

    @wp.func(inline=True)
    def move_node(i: int, data: Data, state: State, settings: Settings,
                  path: wp.array2d(dtype=scalar), k: int):
        """The viscous step at step k of the launch, then the loads at its end."""
        dt = settings.fixed_dt
        explicit.viscous_move(i, state, explicit.viscous_factors(dt, settings.damping_coefficient,
                                                                 scalar(0.0)))
        drive(i, data, state, path, settings.time + scalar(k) * dt, dt, settings.duration)

    @wp.func(inline=True)
    def return_tie(t: int, data: Data, state: State):
        state.dissipated[t] = state.dissipated[t] + forces.return_map(t, state.position, data,
                                                                      state)

    @wp.func(inline=True)
    def check(g: int, data: Data, state: State, settings: Settings):
        """Count the step; the kinetic energy; NON_FINITE where it is not finite."""
        state.steps[g] = state.steps[g] + 1
        state.force_evaluations[g] = state.force_evaluations[g] + 1
        state.dt[g] = settings.fixed_dt
        energy = checks.group_sum(g, data, state)[0]
        state.kinetic_energy[g] = energy
        state.residual[g] = checks.group_max(g, data, state)
        if not wp.isfinite(energy):
            state.status[g] = int(status.NON_FINITE)

    @wp.func(inline=True)
    def unit_stage(stage: int, u: int, data: Data, state: State, settings: Settings,
                   path: wp.array2d(dtype=scalar), k: int):
        if stage == T_MOVE:
            if explicit.running(state, data.node_group[u]):
                move_node(u, data, state, settings, path, k)
        elif stage == T_TIES:
            if explicit.running(state, data.tie_group[u]):
                forces.tie_pass(u, state.position, data, state)
        elif stage == T_GATHER:
            if explicit.running(state, data.node_group[u]):
                checks.gather_node(u, data, state, settings)
        elif stage == T_RETURN:
            if explicit.running(state, data.tie_group[u]):
                return_tie(u, data, state)
        elif stage == T_BLOCKS:
            if explicit.running(state, data.block_group[u]):
                checks.block_stage(u, data, state)
        elif stage == T_CHECK:
            if explicit.running(state, u):
                check(u, data, state, settings)

    return SimpleNamespace(load_at=load_at, move_node=move_node, return_tie=return_tie,
                           check=check, unit_stage=unit_stage)


@structure_variants.variant("transient", "node_parallel")
def stage_kernel(scalar, friction: bool, boundary: bool, kinematics: str = "planar"):
    """The node-parallel layout's transient kernel (a launch per stage; `k` the step within
    the launch's run of steps from settings.time)."""
    Data, State, Settings = structure_variants.structs(scalar, KINEMATICS[kinematics])
    ops = functions(scalar, friction, boundary, kinematics)
    start_ops = structure_explicit.functions(scalar, friction, boundary, kinematics)

    @wp.kernel(module="unique", module_options=structure_settings.MODULE_OPTIONS)
    def stage_pass(data: Data, state: State, settings: Settings, path: wp.array2d(dtype=scalar),
                   stage: int, k: int):
        if stage >= T_MOVE:
            ops.unit_stage(stage, wp.tid(), data, state, settings, path, k)
        else:  # the start's stages (`structure_explicit.START_STAGES`)
            start_ops.unit_stage(stage, wp.tid(), data, state, settings)

    return stage_pass


@structure_variants.variant("transient", "grouped")
def grouped_kernel(scalar, friction: bool, boundary: bool, order: str,
                   kinematics: str = "planar"):
    """The grouped layout's transient kernel: thread g starts group first + g (`begin` != 0:
    the masses, dt and forces) or advances it by settings.chunk steps of settings.fixed_dt
    from settings.time."""
    Data, State, Settings = structure_variants.structs(scalar, KINEMATICS[kinematics])
    ops = functions(scalar, friction, boundary, kinematics)
    group = structure_checks.group_functions(scalar, friction, boundary, order,
                                             kinematics=kinematics)

    @wp.kernel(module="unique", module_options=structure_settings.MODULE_OPTIONS)
    def advance(data: Data, state: State, settings: Settings, path: wp.array2d(dtype=scalar),
                first: int, begin: int):
        g = first + wp.tid()
        if begin != 0:
            group.start(g, data, state, settings)
            return
        lo = data.group_node[g]
        hi = data.group_node[g + 1]
        for k in range(settings.chunk):
            if state.status[g] != int(status.RUNNING):
                break
            for i in range(lo, hi):
                ops.move_node(i, data, state, settings, path, k)
            group.evaluate(g, data, state, settings)
            for t in range(data.group_tie[g], data.group_tie[g + 1]):
                ops.return_tie(t, data, state)
            ops.check(g, data, state, settings)

    return advance
