"""Nodal forces and energy of any structure in a kernel (docs/model.md sections 2-4, 10).

The terms, each written once (f = -dV/dr, the friction force beside it):
- stretch, E = 1/2 (EA / l0)(l - l0)^2 per segment: the pull k (l - l0) e / l on the segment's
  first node, its opposite on the second (e from the first to the second);
- bending on exact turning angles, E = 1/2 (EI / lbar)(phi - phi0)^2 at each inner node,
  phi = atan2(a x b, a . b): with m = k (phi - phi0), g_a = (a_z, -a_x) / |a|^2,
  g_b = (-b_z, b_x) / |b|^2, the forces (m g_a, -m g_a + m g_b, -m g_b) on (i-1, i, i+1);
- the wrap spring of a periodic chain (docs/model.md section 10) between a = r_N - r_{N-1} and
  b = r_1 - r_0: m g_a on r_{N-1}, -m g_a on r_N, m g_b on r_0, -m g_b on r_1;
- each tie's contact (`tie_law`): +sigma R along z on node a, -sigma R on node b;
- each tie's friction (variants built with it): the Huber force on the slip (its first
  component along node a's chain, its second along node b's), F_T from the current R (frozen
  only in derivatives), and where the planes move, -sum_t w_t f_t on each plane node of the
  family (the chain rule through the planes), in tie order;
- the external force: the end loads given per node (`StructureState.load`) plus gravity on
  the physical masses (`StructureArrays.weight`), work -f . (r - r0);
- a tied family (periodic force control): each plane node of it carries the family's summed
  force, each member's own force in plane-node order;
- held dofs carry no force.

Two orders of the same sums. Gather (`tie_pass` per tie, then `node_force` per node: every
thread writes only its own slots, no atomics; a segment is evaluated at both its nodes and a
bending spring at three): the node-parallel layout, bit for bit repeatable on any device, and
the grouped layout's "gather" order (the same bits). Scatter (`scatter_init`, `scatter_terms`,
one thread for a group: each term once, added to its nodes; the caller masks the held dofs):
the grouped layout's default, within rounding of
the gather order.

Variants: `friction` compiles the friction terms (without, F_T = 0 is never evaluated);
`boundary` the moving planes, wrap springs and tied families; `kinematics` "spatial" (docs/model.md
section 11) makes the nodes vec3 (x, y, z) and selects the spatial terms
(`spatial_terms`: bending in two planes, each crossing's three-component Huber friction and
rotation spring on its six-node stencil, the lateral contacts) beside the same stretch and
contact along z, in both orders: the scatter adds each element's stencil forces once, the
gather (`spatial_own_force`) evaluates each element at every node of its stencil, found in
the per-node lists `node_stencil` and `node_lateral`; each element's forces come from one
function either way (`spatial_terms`' `*_gradients`). Each tie's `friction` is then the
force on its three-component slip, -dHuber/dS [N].
"""

import functools
from types import SimpleNamespace

import warp as wp

from dynfab.kernels import spatial_terms, structure_arrays, structure_state, tie_law
from dynfab.kernels.precision import KINEMATICS, vector


@functools.cache
def functions(scalar, friction: bool, boundary: bool,
              kinematics: str = "planar") -> SimpleNamespace:
    """The force and energy `wp.func`s of one variant (module docstring)."""
    dim = KINEMATICS[kinematics]
    spatial = dim == 3
    vec = vector(scalar, dim)
    mat = wp.types.matrix(shape=(2, 2), dtype=scalar)
    Data = structure_arrays.struct(scalar, dim)
    State = structure_state.struct(scalar, dim)
    laws = tie_law.functions(scalar)
    terms = spatial_terms.functions(scalar) if spatial else None
    Z = dim - 1  # the coordinate along the fabric's normal

    @wp.func(inline=True)
    def along_z(value: scalar) -> vec:
        """(0, .., value) [N]: a force along z."""
        result = vec()
        result[wp.static(Z)] = value
        return result

    @wp.func(inline=True)
    def turning_angle(a: vec, b: vec) -> scalar:
        """phi [rad] from segment a to segment b."""
        return wp.atan2(a[0] * b[1] - a[1] * b[0], wp.dot(a, b))

    @wp.func(inline=True)
    def segment_pull(pos: wp.array(dtype=vec), data: Data, i: int) -> vec:
        """k (l - l0) e / l [N] of segment (i, next): the force on node i."""
        e = pos[data.next[i]] - pos[i]
        length = wp.length(e)
        return (data.stretch_stiffness[i] * (length - data.rest_length[i]) / length) * e

    @wp.func(inline=True)
    def bend_moment(data: Data, m: int, a: vec, b: vec) -> scalar:
        """k (phi - phi0) [N m] of the bending spring at node m."""
        return data.bend_stiffness[m] * (turning_angle(a, b) - data.rest_angle[m])

    @wp.func(inline=True)
    def wrap_forces(pos: wp.array(dtype=vec), data: Data, first: int) -> mat:
        """Rows (m g_a, m g_b) [N] of the wrap spring at chain node `first`."""
        last = data.chain_last[first]
        a = pos[last] - pos[last - 1]
        b = pos[first + 1] - pos[first]
        moment = data.wrap_stiffness[first] * (turning_angle(a, b) - data.wrap_rest_angle[first])
        ga = moment * vec(a[1], -a[0]) / wp.dot(a, a)
        gb = moment * vec(-b[1], b[0]) / wp.dot(b, b)
        return mat(ga[0], ga[1], gb[0], gb[1])

    @wp.func(inline=True)
    def plane_shift(pos: wp.array(dtype=vec), data: Data) -> vec:
        """(U_0, U_1) [m]: each plane family's summed end displacement, in plane-node order;
        zero without moving planes."""
        shift = vec()
        if wp.static(boundary):
            for family in range(2):
                total = scalar(0.0)
                for m in range(data.plane_offsets[family], data.plane_offsets[family + 1]):
                    node = data.plane_nodes[m]
                    total += pos[node][0] - data.rest_position[node][0]
                shift[family] = total
        return shift

    @wp.func(inline=True)
    def closure(pos: wp.array(dtype=vec), data: Data, t: int) -> scalar:
        """g = c - sigma (z_a - z_b) [m] of tie t, z_b = 0 for ground."""
        b = data.tie_b[t]
        z_b = scalar(0.0)
        if b >= 0:
            z_b = pos[b][wp.static(Z)]
        return data.tie_offset[t] - data.tie_side[t] * (pos[data.tie_a[t]][wp.static(Z)] - z_b)

    @wp.func(inline=True)
    def slip(pos: wp.array(dtype=vec), data: Data, anchors: wp.array(dtype=vec), t: int,
             shift: vec) -> vec:
        """s [m] of tie t (module docstring of `structure_arrays`); (s_x, 0) for ground."""
        b = data.tie_b[t]
        planes = data.tie_plane[t] + wp.cw_mul(data.tie_weight[t], shift)
        along_b = scalar(0.0)
        if b >= 0:
            along_b = pos[b][0] - planes[1] - anchors[t][1]
        return vec(pos[data.tie_a[t]][0] - planes[0] - anchors[t][0], along_b)

    @wp.func(inline=True)
    def tie_pass_at(t: int, pos: wp.array(dtype=vec), data: Data, state: State, shift: vec):
        """R, dR/dg (and F_T, the friction force) of tie t into the state's tie arrays."""
        at_g = laws.contact(closure(pos, data, t), data.contact_law, t)
        state.contact[t] = at_g[0]
        state.tangent[t] = at_g[1]
        if wp.static(friction):
            bound = laws.limit(at_g[0], data.friction_law, t)
            state.limit[t] = bound
            if wp.static(spatial):
                state.friction[t] = terms.huber_force(
                    terms.crossing_slip(pos, data, state.anchors[t], t), bound,
                    data.friction_law[t, 3])
            else:
                state.friction[t] = laws.huber_force(slip(pos, data, state.anchors, t, shift),
                                                     bound, data.friction_law[t, 3])

    @wp.func(inline=True)
    def tie_pass(t: int, pos: wp.array(dtype=vec), data: Data, state: State):
        """`tie_pass_at` with the planes' shift summed by this thread."""
        tie_pass_at(t, pos, data, state, plane_shift(pos, data))

    @wp.func(inline=True)
    def own_force(i: int, pos: wp.array(dtype=vec), data: Data, state: State) -> vec:
        """-dV/dr_i (+ friction) [N] of node i alone, unmasked, without the planes' reaction."""
        before = data.previous[i]
        after = data.next[i]
        force = state.load[i] + data.weight[i]
        if after >= 0:
            force = force + segment_pull(pos, data, i)
        if before >= 0:
            force = force - segment_pull(pos, data, before)
        if before >= 0 and after >= 0:  # the spring at i: -m g_a + m g_b
            a = pos[i] - pos[before]
            b = pos[after] - pos[i]
            moment = bend_moment(data, i, a, b)
            force = force + moment * (vec(-a[1], a[0]) / wp.dot(a, a)
                                      + vec(-b[1], b[0]) / wp.dot(b, b))
        if before >= 0:
            earlier = data.previous[before]
            if earlier >= 0:  # the spring at i-1, node i its third: -m g_b
                a = pos[before] - pos[earlier]
                b = pos[i] - pos[before]
                moment = bend_moment(data, before, a, b)
                force = force - moment * vec(-b[1], b[0]) / wp.dot(b, b)
        if after >= 0:
            later = data.next[after]
            if later >= 0:  # the spring at i+1, node i its first: +m g_a
                a = pos[after] - pos[i]
                b = pos[later] - pos[after]
                moment = bend_moment(data, after, a, b)
                force = force + moment * vec(a[1], -a[0]) / wp.dot(a, a)
        for k in range(data.node_tie_start[i], data.node_tie_start[i + 1]):
            t = data.node_ties[k]
            up = data.tie_side[t] * state.contact[t]
            if data.tie_a[t] == i:
                along = scalar(0.0)
                if wp.static(friction):
                    along = state.friction[t][0]
                force = force + vec(along, up)
            else:
                along = scalar(0.0)
                if wp.static(friction):
                    along = state.friction[t][1]
                force = force + vec(along, -up)
        if wp.static(boundary):
            first = data.node_wrap[i]
            if first >= 0:
                last = data.chain_last[first]
                g = wrap_forces(pos, data, first)
                if i == last - 1:
                    force = force + vec(g[0, 0], g[0, 1])
                if i == last:
                    force = force - vec(g[0, 0], g[0, 1])
                if i == first + 1:
                    force = force - vec(g[1, 0], g[1, 1])
                if i == first:
                    force = force + vec(g[1, 0], g[1, 1])
        return force

    @wp.func(inline=True)
    def spatial_own_force(i: int, pos: wp.array(dtype=vec), data: Data, state: State) -> vec:
        """-dV/dr_i (+ friction) [N] of node i of a spatial structure, gathered: its segments,
        the bending springs at i and its neighbours, the crossings and lateral contacts whose
        stencils hold it (each element evaluated at every node of its stencil), its ties'
        contact along z; unmasked."""
        before = data.previous[i]
        after = data.next[i]
        force = state.load[i] + data.weight[i]
        if after >= 0:
            force = force + segment_pull(pos, data, i)
        if before >= 0:
            force = force - segment_pull(pos, data, before)
            if after >= 0:  # the spring at i
                g = terms.bend_gradients(pos, data, before, i, after)
                force = force + g[0] + g[1]
            earlier = data.previous[before]
            if earlier >= 0:  # the spring at i-1, node i its third
                force = force - terms.bend_gradients(pos, data, earlier, before, i)[1]
        if after >= 0:
            later = data.next[after]
            if later >= 0:  # the spring at i+1, node i its first
                force = force - terms.bend_gradients(pos, data, i, after, later)[0]
        for k in range(data.node_tie_start[i], data.node_tie_start[i + 1]):
            t = data.node_ties[k]
            up = along_z(data.tie_side[t] * state.contact[t])
            if data.tie_a[t] == i:
                force = force + up
            else:
                force = force - up
        for k in range(data.node_stencil_start[i], data.node_stencil_start[i + 1]):
            code = data.node_stencil[k]
            t = code / 6
            huber = vec()
            if wp.static(friction):
                huber = -state.friction[t]
            force = force + terms.crossing_slot_force(
                terms.crossing_gradients(pos, data, t, huber), code - 6 * t)
        for k in range(data.node_lateral_start[i], data.node_lateral_start[i + 1]):
            code = data.node_lateral[k]
            e = code / 4
            slot = code - 4 * e
            row = terms.lateral_gradients(pos, data, e)[slot / 2]
            if slot % 2 == 0:
                force = force + row
            else:
                force = force - row
        return force

    @wp.func(inline=True)
    def plane_reaction(data: Data, state: State, group: int, family: int) -> scalar:
        """-sum_t w_t f_t [N] along the chain on each plane node of `family`, in tie order."""
        total = scalar(0.0)
        for t in range(data.group_tie[group], data.group_tie[group + 1]):
            total += data.tie_weight[t][family] * state.friction[t][family]
        return -total

    @wp.func(inline=True)
    def node_force(i: int, pos: wp.array(dtype=vec), data: Data, state: State) -> vec:
        """-dV/dr_i [N] on node i's free dofs, gathered; on a plane node the planes' reaction;
        on a tied node its family's summed force (module docstring)."""
        force = vec()
        if wp.static(spatial):
            force = spatial_own_force(i, pos, data, state)
        elif wp.static(boundary):
            family = data.node_tie[i]
            members = scalar(1.0)
            if family >= 0:
                for m in range(data.plane_offsets[family], data.plane_offsets[family + 1]):
                    force = force + own_force(data.plane_nodes[m], pos, data, state)
                members = scalar(data.plane_offsets[family + 1] - data.plane_offsets[family])
            else:
                force = own_force(i, pos, data, state)
            if wp.static(friction):
                plane = data.node_plane[i]
                if plane >= 0:
                    reaction = plane_reaction(data, state, data.node_group[i], plane)
                    force = force + vec(members * reaction, scalar(0.0))
        else:
            force = own_force(i, pos, data, state)
        return wp.cw_mul(force, data.free[i])

    @wp.func(inline=True)
    def scatter_init(group: int, data: Data, state: State):
        """state.force = the external force on the group's nodes (the scatter's start)."""
        for i in range(data.group_node[group], data.group_node[group + 1]):
            state.force[i] = state.load[i] + data.weight[i]

    @wp.func(inline=True)
    def spatial_scatter(group: int, pos: wp.array(dtype=vec), data: Data, state: State):
        """`scatter_terms` of a spatial structure (docs/model.md section 11): each segment's
        stretch and each inner node's two-plane bending, each crossing's contact along z,
        Huber friction (F_T at the current R) and rotation spring, each lateral contact."""
        force = state.force
        for i in range(data.group_node[group], data.group_node[group + 1]):
            j = data.next[i]
            if j >= 0:
                pull = segment_pull(pos, data, i)
                force[i] = force[i] + pull
                force[j] = force[j] - pull
                k = data.next[j]
                if k >= 0:
                    terms.bend_forces(pos, data, i, j, k, force)
        for t in range(data.group_tie[group], data.group_tie[group + 1]):
            tie_pass_at(t, pos, data, state, vec())
            up = along_z(data.tie_side[t] * state.contact[t])
            force[data.tie_a[t]] = force[data.tie_a[t]] + up
            force[data.tie_b[t]] = force[data.tie_b[t]] - up
            huber = vec()
            if wp.static(friction):
                huber = -state.friction[t]
            terms.crossing_forces(pos, data, t, huber, force)
        for e in range(data.group_lateral[group], data.group_lateral[group + 1]):
            terms.lateral_forces(pos, data, e, force)

    @wp.func(inline=True)
    def planar_scatter(group: int, pos: wp.array(dtype=vec), data: Data, state: State):
        """`scatter_terms` of a planar structure."""
        force = state.force
        lo = data.group_node[group]
        hi = data.group_node[group + 1]
        for i in range(lo, hi):
            j = data.next[i]
            if j >= 0:  # segment (i, j), then the bending spring at j
                pull = segment_pull(pos, data, i)
                force[i] = force[i] + pull
                force[j] = force[j] - pull
                k = data.next[j]
                if k >= 0:
                    a = pos[j] - pos[i]
                    b = pos[k] - pos[j]
                    moment = bend_moment(data, j, a, b)
                    ga = moment * vec(a[1], -a[0]) / wp.dot(a, a)
                    gb = moment * vec(-b[1], b[0]) / wp.dot(b, b)
                    force[i] = force[i] + ga
                    force[j] = force[j] - ga + gb
                    force[k] = force[k] - gb
        shift = plane_shift(pos, data)
        if wp.static(boundary):
            for chain in range(data.group_chain[group], data.group_chain[group + 1]):
                first = data.chain_start[chain]
                if data.wrap_stiffness[first] > scalar(0.0):
                    last = data.chain_last[first]
                    g = wrap_forces(pos, data, first)
                    force[last - 1] = force[last - 1] + vec(g[0, 0], g[0, 1])
                    force[last] = force[last] - vec(g[0, 0], g[0, 1])
                    force[first + 1] = force[first + 1] - vec(g[1, 0], g[1, 1])
                    force[first] = force[first] + vec(g[1, 0], g[1, 1])
        reaction = vec(scalar(0.0), scalar(0.0))
        for t in range(data.group_tie[group], data.group_tie[group + 1]):
            tie_pass_at(t, pos, data, state, shift)
            node_a = data.tie_a[t]
            node_b = data.tie_b[t]
            up = data.tie_side[t] * state.contact[t]
            along = vec(scalar(0.0), scalar(0.0))
            if wp.static(friction):
                along = state.friction[t]
                if wp.static(boundary):
                    reaction = reaction - wp.cw_mul(data.tie_weight[t], along)
            force[node_a] = force[node_a] + vec(along[0], up)
            if node_b >= 0:
                force[node_b] = force[node_b] + vec(along[1], -up)
        if wp.static(boundary):
            for family in range(2):  # the planes' reaction, then a tied family's summed force
                begin = data.plane_offsets[family]
                end = data.plane_offsets[family + 1]
                if wp.static(friction):
                    for m in range(begin, end):
                        node = data.plane_nodes[m]
                        force[node] = force[node] + vec(reaction[family], scalar(0.0))
                if end > begin:
                    if data.node_tie[data.plane_nodes[begin]] >= 0:
                        total = vec(scalar(0.0), scalar(0.0))
                        for m in range(begin, end):
                            total = total + force[data.plane_nodes[m]]
                        for m in range(begin, end):
                            force[data.plane_nodes[m]] = total

    @wp.func(inline=True)
    def scatter_terms(group: int, pos: wp.array(dtype=vec), data: Data, state: State):
        """state.force += -dV/dr [N] of every term on the group's nodes (and every tie's R,
        dR/dg, F_T, friction force), each term evaluated once and added to its nodes (module
        docstring), unmasked: after `scatter_init`; the held dofs are masked by the caller."""
        if wp.static(spatial):
            spatial_scatter(group, pos, data, state)
        else:
            planar_scatter(group, pos, data, state)

    @wp.func(inline=True)
    def node_energy(i: int, pos: wp.array(dtype=vec), data: Data, state: State) -> scalar:
        """Energy [J] owned by node i: its segment (i, next), its bending spring, its wrap
        spring (at a chain's first node), minus the work of its external force."""
        external = state.load[i] + data.weight[i]
        energy = -wp.dot(external, pos[i] - data.rest_position[i])
        before = data.previous[i]
        after = data.next[i]
        if after >= 0:
            stretch = wp.length(pos[after] - pos[i]) - data.rest_length[i]
            energy += scalar(0.5) * data.stretch_stiffness[i] * stretch * stretch
        if before >= 0 and after >= 0:
            if wp.static(spatial):
                energy += terms.bend_energy(pos, data, before, i, after)
            else:
                turn = turning_angle(pos[i] - pos[before], pos[after] - pos[i]) \
                    - data.rest_angle[i]
                energy += scalar(0.5) * data.bend_stiffness[i] * turn * turn
        if wp.static(not spatial):
            if data.wrap_stiffness[i] > scalar(0.0):
                last = data.chain_last[i]
                turn = turning_angle(pos[last] - pos[last - 1], pos[i + 1] - pos[i]) \
                    - data.wrap_rest_angle[i]
                energy += scalar(0.5) * data.wrap_stiffness[i] * turn * turn
        return energy

    @wp.func(inline=True)
    def tie_energy(t: int, pos: wp.array(dtype=vec), data: Data, state: State) -> scalar:
        """Contact energy [J] of tie t, plus its Huber term with F_T at the current R (spatial:
        plus its rotation spring)."""
        R = laws.contact(closure(pos, data, t), data.contact_law, t)[0]
        energy = laws.contact_energy(R, data.contact_law, t)
        if wp.static(spatial):
            q = terms.crossing_coordinates(pos, data, t)
            w = terms.spring_excess(data, t, q)
            energy += scalar(0.5) * data.rotation_law[t, 1] * w * w
            if wp.static(friction):
                energy += terms.huber_energy(terms.crossing_slip(pos, data, state.anchors[t], t),
                                             laws.limit(R, data.friction_law, t),
                                             data.friction_law[t, 3])
        elif wp.static(friction):
            energy += laws.huber_energy(slip(pos, data, state.anchors, t, plane_shift(pos, data)),
                                        laws.limit(R, data.friction_law, t),
                                        data.friction_law[t, 3])
        return energy

    @wp.func(inline=True)
    def lateral_energy(e: int, pos: wp.array(dtype=vec), data: Data) -> scalar:
        """Energy [J] of lateral contact e (spatial; 0 in a planar structure, which has none)."""
        energy = scalar(0.0)
        if wp.static(spatial):
            energy = terms.lateral_energy(pos, data, e)
        return energy

    @wp.func(inline=True)
    def return_map(t: int, pos: wp.array(dtype=vec), data: Data, state: State) -> scalar:
        """Radial return of tie t's anchor at `pos` (docs/model.md sections 4, 10): where
        k_t |s| > F_T the anchor moves along s until k_t |s| = F_T; the energy dissipated
        F_T |delta xi| [J]."""
        lost = scalar(0.0)
        if wp.static(friction):
            R = laws.contact(closure(pos, data, t), data.contact_law, t)[0]
            bound = laws.limit(R, data.friction_law, t)
            if wp.static(spatial):  # radially in S (docs/model.md section 11.4)
                S = terms.crossing_slip(pos, data, state.anchors[t], t)
                move = terms.return_anchor(S, bound, data.friction_law[t, 3],
                                           data.rotation_law[t, 0])
                state.anchors[t] = state.anchors[t] + move
                shift = vec(move[0], move[1], data.rotation_law[t, 0] * move[2])
                lost = wp.max(bound, scalar(0.0)) * wp.length(shift)
            else:
                s = slip(pos, data, state.anchors, t, plane_shift(pos, data))
                move = laws.return_anchor(s, bound, data.friction_law[t, 3])
                state.anchors[t] = state.anchors[t] + move
                lost = bound * wp.length(move)
        return lost

    return SimpleNamespace(turning_angle=turning_angle, closure=closure, slip=slip,
                           plane_shift=plane_shift, tie_pass=tie_pass, tie_pass_at=tie_pass_at,
                           own_force=own_force, node_force=node_force,
                           scatter_init=scatter_init, scatter_terms=scatter_terms,
                           node_energy=node_energy, lateral_energy=lateral_energy,
                           tie_energy=tie_energy, along_z=along_z, return_map=return_map, wrap_forces=wrap_forces)
