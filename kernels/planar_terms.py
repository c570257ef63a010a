"""The planar structure's elements in a kernel (docs/model.md sections 2-4, 10): every chain in
its own vertical plane, nodes (coordinate along the chain, z).

- bending on exact turning angles, E = 1/2 (EI / lbar)(phi - phi0)^2 at each inner node,
  phi = atan2(a x b, a . b): with m = k (phi - phi0), g_a = (a_z, -a_x) / |a|^2,
  g_b = (-b_z, b_x) / |b|^2, the forces (m g_a, -m g_a + m g_b, -m g_b) on (i-1, i, i+1);
- the wrap spring of a periodic chain (docs/model.md section 10) between a = r_N - r_{N-1} and
  b = r_1 - r_0: m g_a on r_{N-1}, -m g_a on r_N, m g_b on r_0, -m g_b on r_1;
- each tie's friction (variants built with it): the Huber force on the slip (its first
  component along node a's chain, its second along node b's), F_T from the current R (frozen
  only in derivatives), and where the planes move, -sum_t w_t f_t on each plane node of the
  family (the chain rule through the planes), in tie order;
- a tied family (periodic force control): each plane node of it carries the family's summed
  force, each member's own force in plane-node order.

Where the crossings slide (the "planar_sliding" kinematics, `sliding_terms`; docs/model.md 11.13) the
same elements see each node where it is (`base.physical`: a crossing's node on the plane it
crosses) with each segment's material now (rest length L = base + f (delta_R - delta_L), EA / L,
EI / lbar: `material_terms`); a crossing node's first dof is its slide delta, whose force is
the material's, -sum_k dV/dL_k dL_k/d delta over its two bays
(`material_terms.material_forces`), plus the friction's lambda H'(S) on S = lambda (delta -
xi) (`material_slip`; the anchors move on S in the return map). Where the planes move, a
crossing's node sits on its moving plane and the force on that coordinate goes to the plane
nodes (`held_force`, `plane_reaction`); a wrap spring bends over the material's lbar_0
(`wrap_stiffness`) and adds its dE/dL to its two end segments (`wrap_on_length`).

`structure_terms` gives them to `structure_forces` in the form every kinematics offers
(`plane_shift`, `tie_pass_at`, `node_force`, `scatter`, `add_node_energy`,
`add_tie_energy`, `lateral_energy`, `return_anchor`); the stretch, the contact along z and
the external force are `structure_forces`' own (its `base`).
"""

from types import SimpleNamespace

import warp as wp

from dynfab.kernels import material_terms, structure_arrays, structure_state, tie_law
from dynfab.kernels.precision import vector

ROWS_FROM_HOST = False
"""The dynamic solver's masses take the stiffest tangent's rows from the kernels' band
(`structure_tangent`), not from the host."""
BOUNDARY = True
"""The boundary couplings (moving planes, wrap springs, tied families) are planar elements."""
REFUSALS = ()
"""The dynamic options these elements refuse: none."""
REFUSED_BY = ("a structure of planar kinematics does not run", "section 11.11")
"""What refuses an option (its words, the verb included) and where docs/model.md says why
(`dynfab.solvers.dynamic`)."""
STIFFENS_IN_A_STEP = False
"""Whether a load step can stiffen the elements past the masses at its start (no: stretch
and bending at their rest lengths; `structure_explicit.check_step`)."""


def structure_terms(scalar, friction: bool, boundary: bool, base) -> SimpleNamespace:
    """The planar elements' `wp.func`s of one variant (module docstring), on `base`
    (`structure_forces.base`: along_z, segment_pull, closure, external, own_and_stretch,
    contact_pass)."""
    vec = vector(scalar, 2)
    mat = wp.types.matrix(shape=(2, 2), dtype=scalar)
    Data = structure_arrays.struct(scalar, 2)
    State = structure_state.struct(scalar, 2)
    laws = tie_law.functions(scalar)
    segment_pull = base.segment_pull
    sliding = base.sliding
    P = base.physical  # noqa: N806 (node i where the elements see it)
    bend_stiffness = base.material.bend_stiffness
    slide = material_terms.sliding_functions(scalar, 2).slide
    family_shift = material_terms.plane_shift(scalar, 2)

    @wp.func(inline=True)
    def turning_angle(a: vec, b: vec) -> scalar:
        """phi [rad] from segment a to segment b."""
        return wp.atan2(a[0] * b[1] - a[1] * b[0], wp.dot(a, b))

    @wp.func(inline=True)
    def bend_moment(pos: wp.array(dtype=vec), data: Data, m: int, a: vec, b: vec) -> scalar:
        """k (phi - phi0) [N m] of the bending spring at node m."""
        return bend_stiffness(pos, data, m) * (turning_angle(a, b) - data.rest_angle[m])

    @wp.func(inline=True)
    def wrap_stiffness(pos: wp.array(dtype=vec), data: Data, first: int) -> scalar:
        """EI / lbar_0 [N m] of the wrap spring at chain node `first`: where the crossings
        slide, lbar_0 = (L_first + L_last) / 2 of the material now (docs/model.md 11.13)."""
        k = data.wrap_stiffness[first]
        if wp.static(sliding):
            last = data.chain_last[first] - 1  # the chain's last segment
            k = k * (data.rest_length[first] + data.rest_length[last]) / (
                base.material.rest_length(pos, data, first)
                + base.material.rest_length(pos, data, last))
        return k

    @wp.func(inline=True)
    def wrap_forces(pos: wp.array(dtype=vec), data: Data, first: int) -> mat:
        """Rows (m g_a, m g_b) [N] of the wrap spring at chain node `first`."""
        last = data.chain_last[first]
        a = P(pos, data, last) - P(pos, data, last - 1)
        b = P(pos, data, first + 1) - P(pos, data, first)
        moment = wrap_stiffness(pos, data, first) * (turning_angle(a, b)
                                                      - data.wrap_rest_angle[first])
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
                shift[family] = family_shift(pos, data, family)
        return shift

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
    def material_slip(pos: wp.array(dtype=vec), data: Data, state: State, t: int) -> vec:
        """S = (lambda_a (delta_a - xi_a), lambda_b (delta_b - xi_b)) [m] of crossing t (its
        nodes' first dofs hold its slides; 11.13c)."""
        slides = vec(slide(pos, data, t, 0), slide(pos, data, t, 1))
        return wp.cw_mul(state.stretch[t], slides - state.anchors[t])

    @wp.func(inline=True)
    def bend_energy(pos: wp.array(dtype=vec), data: Data, m: int) -> scalar:
        """E_m [J] of the bending spring at node m (0 at a chain's ends)."""
        before = data.previous[m]
        after = data.next[m]
        energy = scalar(0.0)
        if before >= 0 and after >= 0:
            here = P(pos, data, m)
            turn = turning_angle(here - P(pos, data, before), P(pos, data, after) - here) \
                - data.rest_angle[m]
            energy = scalar(0.5) * bend_stiffness(pos, data, m) * turn * turn
        return energy

    @wp.func(inline=True)
    def wrap_energy(pos: wp.array(dtype=vec), data: Data, first: int) -> scalar:
        """E_w [J] of the wrap spring at chain node `first`."""
        last = data.chain_last[first]
        turn = turning_angle(P(pos, data, last) - P(pos, data, last - 1),
                             P(pos, data, first + 1) - P(pos, data, first)) \
            - data.wrap_rest_angle[first]
        return scalar(0.5) * wrap_stiffness(pos, data, first) * turn * turn

    @wp.func(inline=True)
    def wrap_on_length(pos: wp.array(dtype=vec), data: Data, k: int) -> scalar:
        """-E_w / (2 lbar_0) [N]: what a periodic chain's wrap spring adds to dV/dL_k of its
        first and its last segment (11.13b at the wrap, lbar_0 = (L_first + L_last) / 2)."""
        value = scalar(0.0)
        first = data.node_wrap[k]
        if first >= 0:
            last = data.chain_last[first] - 1
            if (k == first or k == last) and data.wrap_stiffness[first] > scalar(0.0):
                lbar = scalar(0.5) * (base.material.rest_length(pos, data, first)
                                      + base.material.rest_length(pos, data, last))
                value = -scalar(0.5) * wrap_energy(pos, data, first) / lbar
        return value

    material = material_terms.material_forces(scalar, 2, bend_energy,
                                              wrap_on_length if boundary else None)
    own_force_function = wp.func if sliding and boundary else wp.func(inline=True)
    """`own_force` a function of its own where it is largest, crossings that slide on moving
    planes or a periodic cell (inlined at each call it doubled the variant's compile time:
    docs/model.md 11.13, "Compile time"); inlined elsewhere, as it was."""

    @wp.func(inline=True)
    def elastic_force(i: int, pos: wp.array(dtype=vec), data: Data, state: State) -> vec:
        """-dV/dr_i [N] of node i's own terms, its segments' stretch and the bendings that
        read it (no tie, no wrap spring)."""
        before = data.previous[i]
        after = data.next[i]
        force = base.own_and_stretch(i, pos, data, state)
        here = P(pos, data, i)
        if before >= 0 and after >= 0:  # the spring at i: -m g_a + m g_b
            a = here - P(pos, data, before)
            b = P(pos, data, after) - here
            moment = bend_moment(pos, data, i, a, b)
            force = force + moment * (vec(-a[1], a[0]) / wp.dot(a, a)
                                      + vec(-b[1], b[0]) / wp.dot(b, b))
        if before >= 0:
            earlier = data.previous[before]
            if earlier >= 0:  # the spring at i-1, node i its third: -m g_b
                a = P(pos, data, before) - P(pos, data, earlier)
                b = here - P(pos, data, before)
                moment = bend_moment(pos, data, before, a, b)
                force = force - moment * vec(-b[1], b[0]) / wp.dot(b, b)
        if after >= 0:
            later = data.next[after]
            if later >= 0:  # the spring at i+1, node i its first: +m g_a
                a = P(pos, data, after) - here
                b = P(pos, data, later) - P(pos, data, after)
                moment = bend_moment(pos, data, after, a, b)
                force = force + moment * vec(a[1], -a[0]) / wp.dot(a, a)
        return force

    @wp.func(inline=True)
    def wrap_force(i: int, pos: wp.array(dtype=vec), data: Data) -> vec:
        """-dV/dr_i [N] of the wrap spring on node i (variants with the boundary)."""
        force = vec()
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

    @wp.func
    def held_force(i: int, pos: wp.array(dtype=vec), data: Data, state: State) -> scalar:
        """-dV/dx_i [N] along its chain of a crossing's node i where the crossing holds that
        coordinate on a moving plane (its elastic and wrap forces), else 0."""
        value = scalar(0.0)
        if data.physical_plane[i, 0] >= 0:
            value = (elastic_force(i, pos, data, state) + wrap_force(i, pos, data))[0]
        return value

    @wp.func(inline=True)
    def tie_pass_at(t: int, pos: wp.array(dtype=vec), data: Data, state: State, shift: vec):
        """R, dR/dg (and F_T, the friction force) of tie t into the state's tie arrays; where
        the crossings slide, the friction force on the two slides, lambda H'(S) (11.13c), and
        where they slide on moving planes the force on each of its nodes' coordinates held on
        a plane (`held_force`), which the plane nodes take (`node_force`)."""
        bound = base.contact_pass(t, pos, data, state)
        if wp.static(friction):
            if wp.static(sliding):
                state.friction[t] = wp.cw_mul(state.stretch[t], laws.huber_force(
                    material_slip(pos, data, state, t), bound, data.friction_law[t, 3]))
            else:
                state.friction[t] = laws.huber_force(slip(pos, data, state.anchors, t, shift),
                                                     bound, data.friction_law[t, 3])
        if wp.static(sliding and boundary):
            state.held[t] = vec(held_force(data.tie_a[t], pos, data, state),
                                held_force(data.tie_b[t], pos, data, state))

    @own_force_function
    def own_force(i: int, pos: wp.array(dtype=vec), data: Data, state: State) -> vec:
        """-dV/dr_i (+ friction) [N] of node i alone, unmasked, without the planes' reaction."""
        force = elastic_force(i, pos, data, state)
        if wp.static(sliding):
            walk = data.node_slide[i, 0]
            if walk >= 0:  # its first dof a slide: the material's force
                force[0] = material.material_force(pos, data, walk, 2 * i)
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
            force = force + wrap_force(i, pos, data)
        return force

    @wp.func(inline=True)
    def plane_reaction(data: Data, state: State, group: int, family: int) -> scalar:
        """-sum_t w_t f_t [N] along the chain on each plane node of `family`, in tie order:
        the friction's on the planes, or where the crossings slide, +sum_t w_t h_t of the forces
        on their nodes held on the planes (`held_force`; 11.13)."""
        total = scalar(0.0)
        for t in range(data.group_tie[group], data.group_tie[group + 1]):
            if wp.static(sliding):
                total -= data.tie_weight[t][family] * state.held[t][family]
            else:
                total += data.tie_weight[t][family] * state.friction[t][family]
        return -total

    @wp.func(inline=True)
    def node_force(i: int, pos: wp.array(dtype=vec), data: Data, state: State) -> vec:
        """-dV/dr_i [N] on node i, gathered, unmasked; on a plane node the planes' reaction;
        on a tied node its family's summed force (module docstring)."""
        force = vec()
        if wp.static(boundary):
            family = data.node_tie[i]
            begin = 0
            count = 1
            if family >= 0:  # a tied family: its members' forces in plane-node order
                begin = data.plane_offsets[family]
                count = data.plane_offsets[family + 1] - begin
            for m in range(count):  # own_force inlined once (compile time)
                node = i
                if family >= 0:
                    node = data.plane_nodes[begin + m]
                force = force + own_force(node, pos, data, state)
            members = scalar(count)
            if wp.static(friction or sliding):
                plane = data.node_plane[i]
                if plane >= 0:
                    reaction = plane_reaction(data, state, data.node_group[i], plane)
                    force = force + vec(members * reaction, scalar(0.0))
        else:
            force = own_force(i, pos, data, state)
        return force

    @wp.func(inline=True)
    def scatter(group: int, pos: wp.array(dtype=vec), data: Data, state: State):
        """state.force += -dV/dr of the group's elements, each once (`structure_forces`)."""
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
                    moment = bend_moment(pos, data, j, a, b)
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
    def add_node_energy(i: int, pos: wp.array(dtype=vec), data: Data, energy: scalar) -> scalar:
        """`energy` + the bending spring at node i and, at a chain's first node, its wrap
        spring [J]."""
        total = energy + bend_energy(pos, data, i)
        if data.wrap_stiffness[i] > scalar(0.0):
            total += wrap_energy(pos, data, i)
        return total

    @wp.func(inline=True)
    def add_tie_energy(t: int, pos: wp.array(dtype=vec), data: Data, state: State, R: scalar,
                       energy: scalar) -> scalar:
        """`energy` + tie t's Huber term with F_T at R [J] (variants with friction)."""
        total = energy
        if wp.static(friction):
            bound = laws.limit(R, data.friction_law, t)
            if wp.static(sliding):
                total += laws.huber_energy(material_slip(pos, data, state, t), bound,
                                           data.friction_law[t, 3])
            else:
                total += laws.huber_energy(slip(pos, data, state.anchors, t,
                                                plane_shift(pos, data)),
                                           bound, data.friction_law[t, 3])
        return total

    @wp.func(inline=True)
    def lateral_energy(e: int, pos: wp.array(dtype=vec), data: Data) -> scalar:
        """0 [J]: a planar structure has no lateral contacts (its pass runs over none)."""
        return scalar(0.0)

    @wp.func(inline=True)
    def return_anchor(t: int, pos: wp.array(dtype=vec), data: Data, state: State,
                      bound: scalar) -> scalar:
        """Tie t's anchor moved along s until k_t |s| = F_T where k_t |s| > F_T; the energy
        dissipated F_T |delta xi| [J]."""
        if wp.static(sliding):  # on S, the anchors' move in material (11.13c)
            move = laws.return_anchor(material_slip(pos, data, state, t), bound,
                                      data.friction_law[t, 3])
            state.anchors[t] = state.anchors[t] + wp.cw_div(move, state.stretch[t])
        else:
            move = laws.return_anchor(slip(pos, data, state.anchors, t, plane_shift(pos, data)),
                                      bound, data.friction_law[t, 3])
            state.anchors[t] = state.anchors[t] + move
        return bound * wp.length(move)

    return SimpleNamespace(turning_angle=turning_angle, wrap_forces=wrap_forces,
                           plane_shift=plane_shift, slip=slip, tie_pass_at=tie_pass_at,
                           own_force=own_force, node_force=node_force, scatter=scatter,
                           add_node_energy=add_node_energy, add_tie_energy=add_tie_energy,
                           lateral_energy=lateral_energy, return_anchor=return_anchor)
