"""What every relaxation of a group does around its integrator: the masses and time step at the
start, the group sums, and the convergence, divergence and rounding-floor tests after each time
step (docs/model.md section 5, "The dynamic solver (decisions)").

Start (`start_*`, from the positions at rest): the forces; the stiffest tangent K the step can
meet (every contact at k_s, every tie sticking, stretch and bending exact at the starting
positions; `structure_tangent`) and each node's Gershgorin row sum, the larger of its two dofs'
sum_j |K_ij|; then fictitious masses m_i = dt^2 / (4 safety^2) x that (dt = 1 s or the dt asked
for; stable dt = dt / safety) or the physical masses with dt = safety x 2 min_i sqrt(m_i / rows_i)
(or the dt asked for). A tied family's nodes take the family's summed mass. The rounding floor
ROUNDING_FLOOR_FACTOR eps max_i |K_ii| max_i |x_i| and the default tolerance min(D, max(1e-6 F,
floor)) (F the force scale: the end loads, contact forces and segment tensions), the one-yarn
solver's constants (docs/model.md, "The dynamic solver (decisions)").

Each time step, `check`: converged (residual <= tolerance), non-finite, diverged (residual beyond
DIVERGENCE_FACTOR x its start), at the rounding floor, out of steps; explicit integrators add
`check_energy` (kinetic energy beyond ENERGY_FACTOR x the largest f0 . (x - x0), every
ENERGY_CHECK_INTERVAL steps), the semi-implicit one `check_progress` (no new low of the residual
during the last half of at least STALL_MIN_STEPS steps).

Group sums: every node writes its terms into `node_values` (vec4; a force pass's last component
the node's residual); `block_stage` sums a block in node order (and keeps the largest residual);
`group_sum` adds the group's blocks in order (both layouts: the same bits; the grouped layout's
scatter order sums straight into the blocks, `values_blocks`).
"""

import functools
from types import SimpleNamespace

import warp as wp

from dynfab.kernels import sliding_terms, spatial_terms, status, structure_forces
from dynfab.kernels import structure_settings
from dynfab.kernels import structure_tangent, structure_variants
from dynfab.kernels.precision import KINEMATICS, epsilon

ROUNDING_FLOOR_FACTOR = 16.0
"""Rounding floor of the residual / (eps max_i |K_ii| max_i |x_i|) [-], as
`dynfab.solvers.static`'s."""
FLOOR_MIN_STEPS = 1000
"""Time steps before a stalled residual may be declared at the rounding floor."""
ENERGY_CHECK_INTERVAL = 16
"""The energy test runs every this many time steps (and at the step limit), on the largest
kinetic energy since the last test (docs/model.md, the dynamic solver's divergence test)."""
STALL_MIN_STEPS = 2_000
"""semi-implicit: time steps after which a relaxation whose residual has not reached a new low
during the last half of its steps stops (status.NO_PROGRESS); the fabric's choice (the
explicit relaxation of crossings that slide: `sliding_terms.STALL_MIN_STEPS`)."""


TANGENTS = {"planar": structure_tangent.functions, "spatial": spatial_terms.tangent_terms,
            "planar_sliding": sliding_terms.planar_tangent_terms,
            "spatial_sliding": sliding_terms.spatial_tangent_terms}
"""The tangent of each kinematics' elements: the semi-implicit method's (`tie_blocks`,
`assemble_chain`, `coupling_vector`) and the stiffest one's rows, which the masses take
(`stiffest_tie`, `stiffest_chain`, `gershgorin_row`, `largest_diagonal`)."""


@functools.cache
def functions(scalar, friction: bool, boundary: bool, merit: bool = False,
              kinematics: str = "planar") -> SimpleNamespace:
    """The start, sum and check `wp.func`s of one variant; with `merit`, every node's
    f^T M^-1 f term too (the semi-implicit time step rule's merit). The masses' Gershgorin
    rows are the kinematics' tangent's (`TANGENTS`)."""
    dim = KINEMATICS[kinematics]
    vec4 = wp.types.vector(4, scalar)
    Data, State, Settings = structure_variants.structs(scalar, dim)
    forces = structure_forces.functions(scalar, friction, boundary, kinematics)
    tangent = TANGENTS[kinematics](scalar, friction, boundary)
    floor_scale = ROUNDING_FLOOR_FACTOR * epsilon(scalar)

    @wp.func(inline=True)
    def larger(worst: scalar, value: scalar) -> scalar:
        """max(worst, |value|); a NaN, once met, stays."""
        size = wp.abs(value)  # a select, not a branch: which is larger is data, not a pattern
        return wp.where(worst == worst and not size <= worst, size, worst)

    # ------------------------------------------------------------- sums

    @wp.func(inline=True)
    def block_stage(b: int, data: Data, state: State):
        """block_values[b]: the block's node_values summed in node order; block_max[b]: the
        largest of their last component (the residual, where a force pass wrote them)."""
        total = vec4(scalar(0.0), scalar(0.0), scalar(0.0), scalar(0.0))
        worst = scalar(0.0)
        for i in range(data.block_start[b], data.block_start[b + 1]):
            value = state.node_values[i]
            total = total + value
            worst = larger(worst, value[3])
        state.block_values[b] = total
        state.block_max[b] = worst

    @wp.func(inline=True)
    def group_sum(g: int, data: Data, state: State) -> vec4:
        """The group's blocks' sums, in block order."""
        total = vec4(scalar(0.0), scalar(0.0), scalar(0.0), scalar(0.0))
        for b in range(data.group_block[g], data.group_block[g + 1]):
            total = total + state.block_values[b]
        return total

    @wp.func(inline=True)
    def group_max(g: int, data: Data, state: State) -> scalar:
        """The group's largest residual [N] (`block_max`)."""
        worst = scalar(0.0)
        for b in range(data.group_block[g], data.group_block[g + 1]):
            worst = larger(worst, state.block_max[b])
        return worst

    # ------------------------------------------------------------- evaluation

    @wp.func(inline=True)
    def energy_step(g: int, state: State, settings: Settings) -> bool:
        """The check after this time step tests the energy (`check_energy`)."""
        upcoming = state.steps[g] + 1
        return upcoming % ENERGY_CHECK_INTERVAL == 0 or upcoming >= settings.max_steps

    @wp.func(inline=True)
    def trial_step(g: int, state: State, settings: Settings) -> scalar:
        """dt [s] of the trial step whose kinetic energy a force pass sums (`force_values`):
        kinetic damping's before its viscous fallback; 0 otherwise (none)."""
        dt = scalar(0.0)
        if settings.damping == wp.static(structure_settings.KINETIC):
            if state.damping_coefficient[g] == scalar(0.0):
                dt = state.dt[g]
        return dt

    @wp.func(inline=True)
    def force_values(i: int, data: Data, state: State, energy: bool, trial: scalar) -> vec4:
        """Node i's force masked to its free dofs (in place) and its values: (1/2 m v^2 [J],
        f0 . (x - x0) [J] with `energy`, f^T f / m [N^2/kg] with `merit` or else, with `trial`
        dt > 0, the kinetic energy 1/2 m |v + (dt / m) f|^2 [J] a step of dt would reach
        (kinetic damping's peak test, `structure_explicit`), the largest force component [N]),
        the sums' terms counted at the node's share. At a relaxation's start, before its masses,
        the trial term is stale: read only after the first time step."""
        f = wp.cw_mul(state.force[i], data.free[i])
        state.force[i] = f
        v = state.velocity[i]
        share = data.share[i]
        work = scalar(0.0)
        if energy:
            work = share * wp.dot(state.start_force[i], state.position[i] - state.start_position[i])
        merit_or_trial = scalar(0.0)
        if wp.static(merit):
            merit_or_trial = share * (wp.dot(f, f) / state.mass[i])
        elif trial > scalar(0.0):
            m = state.mass[i]
            w = v + (trial / m) * f
            merit_or_trial = share * (scalar(0.5) * m * wp.dot(w, w))
        largest = scalar(0.0)
        for c in range(wp.static(dim)):
            largest = larger(largest, f[c])
        return vec4(scalar(0.5) * (state.mass[i] * share) * wp.dot(v, v), work, merit_or_trial,
                    largest)

    @wp.func(inline=True)
    def gather_node(i: int, data: Data, state: State, settings: Settings):
        """Node i's force gathered at the current positions, its values into node_values."""
        g = data.node_group[i]
        state.force[i] = forces.node_force(i, state.position, data, state)
        state.node_values[i] = force_values(i, data, state, energy_step(g, state, settings),
                                            trial_step(g, state, settings))

    @wp.func(inline=True)
    def values_blocks(g: int, data: Data, state: State, settings: Settings):
        """Every node's `force_values` summed straight into its block's sums (the grouped
        layout's scatter order: what `block_stage` sums, without storing the node values)."""
        energy = energy_step(g, state, settings)
        trial = trial_step(g, state, settings)
        for b in range(data.group_block[g], data.group_block[g + 1]):
            total = vec4(scalar(0.0), scalar(0.0), scalar(0.0), scalar(0.0))
            worst = scalar(0.0)
            for i in range(data.block_start[b], data.block_start[b + 1]):
                value = force_values(i, data, state, energy, trial)
                total = total + value
                worst = larger(worst, value[3])
            state.block_values[b] = total
            state.block_max[b] = worst

    @wp.func(inline=True)
    def scatter_group(g: int, data: Data, state: State, settings: Settings):
        """The group's forces in scatter order (ties included), its values and block sums."""
        forces.scatter_init(g, data, state)
        forces.scatter_terms(g, state.position, data, state)
        values_blocks(g, data, state, settings)

    # ------------------------------------------------------------- start

    @wp.func(inline=True)
    def rows_node(i: int, data: Data, state: State, settings: Settings):
        """Node i's Gershgorin row sum [N/m] into node_values[i][0], its own mass into
        state.mass[i] (module docstring) and, with physical masses, 2 sqrt(m / rows) [s] into
        node_values[i][1] (0 where rows = 0)."""
        rows = tangent.gershgorin_row(i, data, state)
        bound = scalar(0.0)
        if settings.fictitious != 0:
            dt = scalar(1.0)
            if settings.fixed_dt > scalar(0.0):
                dt = settings.fixed_dt
            state.mass[i] = dt * dt / (scalar(4.0) * settings.safety * settings.safety) * rows
        else:
            state.mass[i] = data.mass[i]
            if rows > scalar(0.0):
                bound = scalar(2.0) * wp.sqrt(data.mass[i] / rows)
        state.node_values[i] = vec4(rows, bound, scalar(0.0), scalar(0.0))

    @wp.func(inline=True)
    def tie_families(g: int, data: Data, state: State):
        """A tied family's nodes in group g take the family's summed mass."""
        if wp.static(boundary):
            for family in range(2):
                begin = data.plane_offsets[family]
                end = data.plane_offsets[family + 1]
                if end > begin:
                    first = data.plane_nodes[begin]
                    if data.node_tie[first] >= 0 and data.node_group[first] == g:
                        total = scalar(0.0)
                        for m in range(begin, end):
                            total += state.mass[data.plane_nodes[m]]
                        for m in range(begin, end):
                            state.mass[data.plane_nodes[m]] = total

    @wp.func(inline=True)
    def force_scale(g: int, data: Data, state: State) -> scalar:
        """The group's force scale [N]: the largest end load component, contact force and
        segment tension |k (l - l0)|."""
        scale = scalar(0.0)
        for i in range(data.group_node[g], data.group_node[g + 1]):
            for c in range(wp.static(dim)):
                scale = wp.max(scale, wp.abs(state.load[i][c]))
            j = data.next[i]
            if j >= 0:
                length = wp.length(state.position[j] - state.position[i])
                scale = wp.max(scale, wp.abs(data.stretch_stiffness[i]
                                             * (length - data.rest_length[i])))
        for t in range(data.group_tie[g], data.group_tie[g + 1]):
            scale = wp.max(scale, wp.abs(state.contact[t]))
        return scale

    @wp.func(inline=True)
    def start_group(g: int, data: Data, state: State, settings: Settings):
        """The group's masses, time step, rounding floor, tolerance and bookkeeping at the
        step's start (after the tie and node passes and their block sums, `stiffest_chain` and
        `rows_node`); with `merit`, its f^T M^-1 f."""
        state.merit[g] = scalar(0.0)
        tie_families(g, data, state)
        lo = data.group_node[g]
        hi = data.group_node[g + 1]
        bound = scalar(1.0e30)
        diagonal = scalar(0.0)
        coordinate = scalar(0.0)
        for i in range(lo, hi):
            if state.node_values[i][1] > scalar(0.0):
                bound = wp.min(bound, state.node_values[i][1])
            diagonal = wp.max(diagonal, tangent.largest_diagonal(i, data, state))
            for c in range(wp.static(dim)):
                coordinate = wp.max(coordinate, wp.abs(state.position[i][c]))
            state.start_position[i] = state.position[i]
            state.start_force[i] = state.force[i]
        if settings.fictitious != 0:
            dt = scalar(1.0)
            if settings.fixed_dt > scalar(0.0):
                dt = settings.fixed_dt
            state.dt[g] = dt
            state.stable_dt[g] = dt / settings.safety
        else:
            state.stable_dt[g] = bound
            state.dt[g] = settings.safety * bound
            if settings.fixed_dt > scalar(0.0):
                state.dt[g] = settings.fixed_dt
        floor = scalar(floor_scale) * diagonal * coordinate
        state.rounding_floor[g] = floor
        residual = group_max(g, data, state)
        if wp.static(merit):  # the masses are known now: every node's f^T f / m, summed
            for b in range(data.group_block[g], data.group_block[g + 1]):
                total = scalar(0.0)
                for i in range(data.block_start[b], data.block_start[b + 1]):
                    f = state.force[i]
                    total += data.share[i] * (wp.dot(f, f) / state.mass[i])
                state.merit[g] = state.merit[g] + total
        tolerance = settings.tolerance
        if settings.relative_tolerance > scalar(0.0):
            relative = settings.relative_tolerance * force_scale(g, data, state)
            tolerance = wp.min(tolerance, wp.max(relative, floor))
        state.tolerance[g] = tolerance
        state.residual[g] = residual
        state.start_residual[g] = residual
        state.best_residual[g] = residual
        state.steps_since_best[g] = 0
        state.steps[g] = 0
        state.kinetic_energy[g] = scalar(0.0)
        state.work_bound[g] = scalar(0.0)
        state.kinetic_peak[g] = scalar(0.0)
        state.energy_ratio[g] = scalar(0.0)
        state.damping_coefficient[g] = scalar(0.0)
        state.force_evaluations[g] = 1
        state.cg_iterations[g] = 0
        state.rejected[g] = 0
        state.shortened[g] = 0
        state.backtracks[g] = 0
        code = int(status.RUNNING)
        if not wp.isfinite(residual):
            code = int(status.NON_FINITE)
        elif residual <= tolerance:
            code = int(status.CONVERGED)
        elif settings.max_steps <= 0:
            code = int(status.MAX_STEPS)
        state.status[g] = code

    # ------------------------------------------------------------- checks

    @wp.func(inline=True)
    def at_rounding_floor(g: int, state: State) -> bool:
        """The best residual is within the rounding floor and has not fallen for half the steps."""
        return (state.best_residual[g] <= state.rounding_floor[g]
                and state.steps[g] >= FLOOR_MIN_STEPS
                and 2 * state.steps_since_best[g] > state.steps[g])

    @wp.func(inline=True)
    def check(g: int, data: Data, state: State, settings: Settings) -> int:
        """Count the step just taken; the residual (group_max), the kinetic energy
        (group_sum[0]) and the status after it."""
        state.steps[g] = state.steps[g] + 1
        state.force_evaluations[g] = state.force_evaluations[g] + 1
        residual = group_max(g, data, state)
        sums = group_sum(g, data, state)
        state.kinetic_energy[g] = sums[0]
        state.residual[g] = residual
        if residual < state.best_residual[g]:
            state.best_residual[g] = residual
            state.steps_since_best[g] = 0
        else:
            state.steps_since_best[g] = state.steps_since_best[g] + 1
        code = int(status.RUNNING)
        if not (wp.isfinite(residual) and wp.isfinite(sums[0])):
            code = int(status.NON_FINITE)
        elif residual <= state.tolerance[g]:
            code = int(status.CONVERGED)
        elif residual > scalar(status.DIVERGENCE_FACTOR) * wp.max(state.start_residual[g],
                                                                 state.tolerance[g]):
            code = int(status.DIVERGED)
        elif at_rounding_floor(g, state):
            code = int(status.ROUNDING_FLOOR)
        elif state.steps[g] >= settings.max_steps:
            code = int(status.MAX_STEPS)
        state.status[g] = code
        return code

    @wp.func(inline=True)
    def check_energy(g: int, data: Data, state: State, code: int) -> int:
        """`code`, or DIVERGED when the kinetic energy exceeds ENERGY_FACTOR x the largest
        f0 . (x - x0) of the step so far, tested every ENERGY_CHECK_INTERVAL steps on the
        largest kinetic energy since the last test (docs/model.md, the divergence test)."""
        if code != int(status.RUNNING) and code != int(status.MAX_STEPS):
            return code
        energy = wp.max(state.kinetic_peak[g], state.kinetic_energy[g])
        if code == int(status.RUNNING) and state.steps[g] % ENERGY_CHECK_INTERVAL != 0:
            state.kinetic_peak[g] = energy
            return code
        state.kinetic_peak[g] = scalar(0.0)
        bound = wp.max(state.work_bound[g], group_sum(g, data, state)[1])
        state.work_bound[g] = bound
        if energy > scalar(0.0):
            if energy > scalar(status.ENERGY_FACTOR) * bound:
                state.energy_ratio[g] = wp.max(state.energy_ratio[g],
                                               energy / wp.max(bound, scalar(1.0e-30)))
                state.kinetic_peak[g] = energy
                state.status[g] = int(status.DIVERGED)
                return int(status.DIVERGED)
            state.energy_ratio[g] = wp.max(state.energy_ratio[g], energy / bound)
        return code

    @wp.func(inline=True)
    def check_progress(g: int, state: State, code: int, min_steps: int) -> int:
        """`code`, or NO_PROGRESS where the best residual has not fallen during the last half
        of at least `min_steps` steps (above the rounding floor)."""
        result = code
        if code == int(status.RUNNING):
            if (state.steps[g] >= min_steps and 2 * state.steps_since_best[g] > state.steps[g]
                    and state.best_residual[g] > state.rounding_floor[g]):
                state.status[g] = int(status.NO_PROGRESS)
                result = int(status.NO_PROGRESS)
        return result

    return SimpleNamespace(larger=larger, block_stage=block_stage, group_sum=group_sum,
                           group_max=group_max, force_values=force_values, gather_node=gather_node,
                           values_blocks=values_blocks,
                           scatter_group=scatter_group, stiffest_tie=tangent.stiffest_tie,
                           stiffest_chain=tangent.stiffest_chain, rows_node=rows_node,
                           start_group=start_group, check=check, check_energy=check_energy,
                           check_progress=check_progress, energy_step=energy_step)


@functools.cache
def group_functions(scalar, friction: bool, boundary: bool, order: str,
                    merit: bool = False, kinematics: str = "planar") -> SimpleNamespace:
    """The grouped layout's whole-group `wp.func`s: `evaluate` (the forces at the positions in
    `order` "scatter" or "gather", every node's values and the block sums) and `start` (the
    start's stages in turn, as the node-parallel layout launches them)."""
    dim = KINEMATICS[kinematics]
    Data, State, Settings = structure_variants.structs(scalar, dim)
    checks = functions(scalar, friction, boundary, merit, kinematics)
    forces = structure_forces.functions(scalar, friction, boundary, kinematics)
    scatter = order == "scatter"

    @wp.func(inline=True)
    def blocks(g: int, data: Data, state: State):
        for b in range(data.group_block[g], data.group_block[g + 1]):
            checks.block_stage(b, data, state)

    @wp.func(inline=True)
    def evaluate(g: int, data: Data, state: State, settings: Settings):
        if wp.static(scatter):
            checks.scatter_group(g, data, state, settings)
        else:
            for t in range(data.group_tie[g], data.group_tie[g + 1]):
                forces.tie_pass(t, state.position, data, state)
            for i in range(data.group_node[g], data.group_node[g + 1]):
                checks.gather_node(i, data, state, settings)
            blocks(g, data, state)

    @wp.func(inline=True)
    def evaluate_set(g: int, data: Data, state: State, settings: Settings):
        """`evaluate` where the scatter's initial forces (the external ones) are set already."""
        if wp.static(scatter):
            forces.scatter_terms(g, state.position, data, state)
            checks.values_blocks(g, data, state, settings)
        else:
            evaluate(g, data, state, settings)

    @wp.func(inline=True)
    def start(g: int, data: Data, state: State, settings: Settings):
        evaluate(g, data, state, settings)
        for t in range(data.group_tie[g], data.group_tie[g + 1]):
            checks.stiffest_tie(t, data, state)
        for c in range(data.group_chain[g], data.group_chain[g + 1]):
            checks.stiffest_chain(c, data, state)
        for i in range(data.group_node[g], data.group_node[g + 1]):
            checks.rows_node(i, data, state, settings)
        checks.start_group(g, data, state, settings)

    return SimpleNamespace(blocks=blocks, evaluate=evaluate, evaluate_set=evaluate_set,
                           start=start)


def grouped_relax(scalar, start, step, dim: int = 2):
    """The grouped layout's kernel around a group's `start` and time `step` (`wp.func`s of (g,
    data, state, settings)): thread g runs group first + g, the start (`begin` != 0) or up to
    settings.chunk time steps while the group runs."""
    Data, State, Settings = structure_variants.structs(scalar, dim)

    @wp.kernel(module="unique", module_options=structure_settings.MODULE_OPTIONS)
    def relax(data: Data, state: State, settings: Settings, first: int, begin: int):
        g = first + wp.tid()
        if begin != 0:
            start(g, data, state, settings)
            return
        for _ in range(settings.chunk):
            if state.status[g] != int(status.RUNNING):
                break
            step(g, data, state, settings)

    return relax
