"""The tangent stiffness K of a planar structure in a kernel: each chain's band and the couplings
outside it (docs/model.md sections 5, 6, 10; a spatial structure's is
`spatial_terms.tangent_terms`, with the same `tie_blocks`, `assemble_chain`, `coupling_vector`).

`assemble_chain` fills chain c's rows of the flat band (`band_lu`, the chain's dofs
contiguous) with
- stretch: k [e e^T / l^2 + (1 - l0/l)(I - e e^T / l^2)] per segment;
- bending: k dphi dphi^T + k (phi - phi0) d2phi over (i-1, i, i+1), d2phi from
  d2theta/dv2 = [[2 v_x v_z, v_z^2 - v_x^2], [v_z^2 - v_x^2, -2 v_x v_z]] / |v|^4;
- the wrap spring (boundary variants): k dphi dphi^T and the moment term within each of its
  two pairs of nodes, (r_{N-1}, r_N) and (r_0, r_1); the blocks between the pairs lie outside
  the band (`wrap_cross`);
- every tie's diagonal part on the chain's nodes: dR/dg on z_a (and z_b), the Huber block's
  h_xx on x_a (h_yy on x_b), from `StructureState.coupling` (t) = (dR/dg, h_xx, h_xy, h_yy);
  a tie to ground lies wholly on node a's diagonal, so a chain whose ties are all grounded has
  its whole K in its band. The off-diagonal parts (-dR/dg between z_a and z_b, h_xy between
  x_a and x_b, the moving planes' rows) are the semi-implicit product's.

Modes: `definite` drops a compressed segment's negative geometric part and bending's moment
term (the semi-implicit matrix, positive semi-definite; docs/model.md (5.4)); the couplings
are then set by `tie_blocks`. `stiffest` (the Gershgorin masses, docs/model.md (5.5)) takes
the exact stretch and bending and every tie at its stiffest: contact at k_s, sticking at k_t
(`stiffest_tie`).
"""

import functools
from types import SimpleNamespace

import warp as wp

from dynfab.kernels import band_lu, structure_arrays, structure_forces, structure_state, tie_law
from dynfab.kernels.precision import vector
from dynfab.linalg.banded import BANDWIDTH


@functools.cache
def functions(scalar, friction: bool, boundary: bool) -> SimpleNamespace:
    """The tangent `wp.func`s of one variant (`structure_forces.functions`' flags)."""
    vec = vector(scalar)
    vec3 = wp.types.vector(3, scalar)
    vec4 = wp.types.vector(4, scalar)
    mat = wp.types.matrix((2, 2), scalar)
    Data = structure_arrays.struct(scalar)
    State = structure_state.struct(scalar)
    band_ops = band_lu.functions(scalar)
    forces = structure_forces.functions(scalar, friction, boundary)
    laws = tie_law.functions(scalar)

    @wp.func(inline=True)
    def theta_hessian(v: vec) -> mat:
        """d2theta/dv2 [1/m^2]."""
        n2 = wp.dot(v, v) * wp.dot(v, v)
        hxx = scalar(2.0) * v[0] * v[1] / n2
        hxz = (v[1] * v[1] - v[0] * v[0]) / n2
        return mat(hxx, hxz, hxz, -hxx)

    @wp.func(inline=True)
    def add_stretch(band: wp.array2d(dtype=scalar), pos: wp.array(dtype=vec), data: Data,
                    i: int, definite: int):
        """Segment (i, i+1)'s block."""
        e = pos[i + 1] - pos[i]
        l2 = wp.dot(e, e)
        geometric = scalar(1.0) - data.rest_length[i] / wp.sqrt(l2)
        if definite != 0:
            geometric = wp.max(geometric, scalar(0.0))
        axial = wp.outer(e, e) / l2
        block = data.stretch_stiffness[i] * (axial + geometric * (wp.identity(2, scalar) - axial))
        band_ops.add_pair(band, i, i + 1, block)

    @wp.func(inline=True)
    def add_bending(band: wp.array2d(dtype=scalar), pos: wp.array(dtype=vec), data: Data,
                    i: int, definite: int):
        """The spring at node i over (i-1, i, i+1)."""
        a = pos[i] - pos[i - 1]
        b = pos[i + 1] - pos[i]
        k = data.bend_stiffness[i]
        moment = k * (forces.turning_angle(a, b) - data.rest_angle[i])
        if definite != 0:
            moment = scalar(0.0)
        ga = vec(a[1], -a[0]) / wp.dot(a, a)
        gb = vec(-b[1], b[0]) / wp.dot(b, b)
        ha = -moment * theta_hessian(a)
        hb = moment * theta_hessian(b)
        g0 = -ga
        g1 = ga - gb
        g2 = gb
        band_ops.add_block(band, i - 1, i - 1, k * wp.outer(g0, g0) + ha)
        band_ops.add_block(band, i - 1, i, k * wp.outer(g0, g1) - ha)
        band_ops.add_block(band, i - 1, i + 1, k * wp.outer(g0, g2))
        band_ops.add_block(band, i, i - 1, k * wp.outer(g1, g0) - ha)
        band_ops.add_block(band, i, i, k * wp.outer(g1, g1) + ha + hb)
        band_ops.add_block(band, i, i + 1, k * wp.outer(g1, g2) - hb)
        band_ops.add_block(band, i + 1, i - 1, k * wp.outer(g2, g0))
        band_ops.add_block(band, i + 1, i, k * wp.outer(g2, g1) - hb)
        band_ops.add_block(band, i + 1, i + 1, k * wp.outer(g2, g2) + hb)

    @wp.func(inline=True)
    def wrap_gradients(pos: wp.array(dtype=vec), data: Data, first: int) -> mat:
        """Rows (g_a, g_b) [1/m]: dphi/dr = (-g_a, g_a, -g_b, g_b) on (r_{N-1}, r_N, r_0, r_1)."""
        last = data.chain_last[first]
        a = pos[last] - pos[last - 1]
        b = pos[first + 1] - pos[first]
        ga = vec(a[1], -a[0]) / wp.dot(a, a)
        gb = vec(-b[1], b[0]) / wp.dot(b, b)
        return mat(ga[0], ga[1], gb[0], gb[1])

    @wp.func(inline=True)
    def add_wrap(band: wp.array2d(dtype=scalar), pos: wp.array(dtype=vec), data: Data,
                 first: int, definite: int):
        """The wrap spring's blocks within its two pairs of nodes (module docstring)."""
        last = data.chain_last[first]
        a = pos[last] - pos[last - 1]
        b = pos[first + 1] - pos[first]
        k = data.wrap_stiffness[first]
        moment = k * (forces.turning_angle(a, b) - data.wrap_rest_angle[first])
        if definite != 0:
            moment = scalar(0.0)
        g = wrap_gradients(pos, data, first)
        ga = vec(g[0, 0], g[0, 1])
        gb = vec(g[1, 0], g[1, 1])
        band_ops.add_pair(band, last - 1, last, k * wp.outer(ga, ga) - moment * theta_hessian(a))
        band_ops.add_pair(band, first, first + 1, k * wp.outer(gb, gb) + moment * theta_hessian(b))

    @wp.func(inline=True)
    def wrap_node_gradient(pos: wp.array(dtype=vec), data: Data, i: int) -> vec:
        """dphi/dr_i [1/m] of the wrap spring node i belongs to (`data.node_wrap`)."""
        first = data.node_wrap[i]
        g = wrap_gradients(pos, data, first)
        value = vec(g[1, 0], g[1, 1])
        last = data.chain_last[first]
        if i == last - 1:
            value = -vec(g[0, 0], g[0, 1])
        elif i == last:
            value = vec(g[0, 0], g[0, 1])
        elif i == first:
            value = -vec(g[1, 0], g[1, 1])
        return value

    @wp.func(inline=True)
    def wrap_partner(data: Data, i: int) -> int:
        """The first node of the other pair of node i's wrap spring."""
        first = data.node_wrap[i]
        other = first
        if i < data.chain_last[first] - 1:  # i in (r_0, r_1): the other pair ends the chain
            other = data.chain_last[first] - 1
        return other

    @wp.func(inline=True)
    def wrap_cross(pos: wp.array(dtype=vec), data: Data, i: int, x: wp.array(dtype=scalar),
                   comp: int) -> scalar:
        """The wrap spring's k dphi dphi^T between its pairs times x (flat dofs), at dof
        (node i, comp) [N]; 0 off the wrap's nodes."""
        value = scalar(0.0)
        if data.node_wrap[i] >= 0:
            other = wrap_partner(data, i)
            along = (wp.dot(wrap_node_gradient(pos, data, other),
                            vec(x[2 * other], x[2 * other + 1]))
                     + wp.dot(wrap_node_gradient(pos, data, other + 1),
                              vec(x[2 * other + 2], x[2 * other + 3])))
            stiffness = data.wrap_stiffness[data.node_wrap[i]]
            value = stiffness * wrap_node_gradient(pos, data, i)[comp] * along
        return value

    @wp.func(inline=True)
    def wrap_cross_rows(pos: wp.array(dtype=vec), data: Data, i: int) -> vec:
        """sum_j |(k dphi dphi^T)_ij| over the other pair's dofs, per component [N/m]."""
        rows = vec(scalar(0.0), scalar(0.0))
        if data.node_wrap[i] >= 0:
            other = wrap_partner(data, i)
            g1 = wrap_node_gradient(pos, data, other)
            g2 = wrap_node_gradient(pos, data, other + 1)
            spread = wp.abs(g1[0]) + wp.abs(g1[1]) + wp.abs(g2[0]) + wp.abs(g2[1])
            own = wrap_node_gradient(pos, data, i)
            k = data.wrap_stiffness[data.node_wrap[i]]
            rows = vec(k * wp.abs(own[0]) * spread, k * wp.abs(own[1]) * spread)
        return rows

    @wp.func(inline=True)
    def tie_blocks(t: int, pos: wp.array(dtype=vec), data: Data, state: State, shift: vec,
                   secant: int):
        """coupling[t] = (dR/dg, h_xx, h_xy, h_yy) [N/m] at the tie pass's R and F_T (F_T
        frozen): dR/dg where closed, the Huber Hessian at the slip (`secant`: the secant
        while sliding); h_yy and h_xy zero for a tie to ground."""
        tangent = scalar(0.0)
        if forces.closure(pos, data, t) > scalar(0.0):
            tangent = laws.series_law(state.contact[t], data.contact_law, t)[1]
        h = vec3(scalar(0.0), scalar(0.0), scalar(0.0))
        if wp.static(friction):
            h = laws.huber_hessian(forces.slip(pos, data, state.anchors, t, shift),
                                   state.limit[t], data.friction_law[t, 3], secant)
            if data.tie_b[t] < 0:
                h = vec3(h[0], scalar(0.0), scalar(0.0))
        state.coupling[t] = vec4(tangent, h[0], h[1], h[2])

    @wp.func(inline=True)
    def stiffest_tie(t: int, data: Data, state: State):
        """coupling[t] = (k_s, k_t, 0, k_t): every contact at its bound, every tie sticking
        (k_t's y part 0 for a tie to ground)."""
        stick = scalar(0.0)
        if wp.static(friction):
            stick = data.friction_law[t, 3]
        other = stick
        if data.tie_b[t] < 0:
            other = scalar(0.0)
        state.coupling[t] = vec4(data.contact_law[t, 0], stick, scalar(0.0), other)

    @wp.func(inline=True)
    def add_tie_diagonals(band: wp.array2d(dtype=scalar), data: Data, state: State, i: int):
        """Node i's diagonal parts of its ties' blocks (module docstring)."""
        for k in range(data.node_tie_start[i], data.node_tie_start[i + 1]):
            t = data.node_ties[k]
            blk = state.coupling[t]
            band[2 * i + 1, BANDWIDTH] += blk[0]
            if data.tie_a[t] == i:
                band[2 * i, BANDWIDTH] += blk[1]
            else:
                band[2 * i, BANDWIDTH] += blk[3]

    @wp.func(inline=True)
    def assemble_chain(c: int, pos: wp.array(dtype=vec), data: Data, state: State,
                       band: wp.array2d(dtype=scalar), definite: int):
        """band = chain c's K [N/m] in its rows (module docstring); the ties' blocks from
        `state.coupling`."""
        a = data.chain_start[c]
        b = data.chain_start[c + 1]
        band_ops.clear(band, 2 * a, 2 * b)
        for i in range(a, b - 1):
            add_stretch(band, pos, data, i, definite)
        for i in range(a + 1, b - 1):
            add_bending(band, pos, data, i, definite)
        if wp.static(boundary):
            if data.wrap_stiffness[a] > scalar(0.0):
                add_wrap(band, pos, data, a, definite)
        for i in range(a, b):
            add_tie_diagonals(band, data, state, i)

    @wp.func(inline=True)
    def coupling_vector(i: int, x: wp.array(dtype=scalar), data: Data, state: State) -> vec:
        """The ties' off-diagonal parts times x (flat dofs) at node i's dofs [N]: h_xy
        x_partner on the in-plane dof, -dR/dg x_partner on z (ties between nodes)."""
        total = vec(scalar(0.0), scalar(0.0))
        for k in range(data.node_tie_start[i], data.node_tie_start[i + 1]):
            t = data.node_ties[k]
            b = data.tie_b[t]
            if b >= 0:
                partner = data.tie_a[t]
                if partner == i:
                    partner = b
                blk = state.coupling[t]
                total[0] = total[0] + blk[2] * x[2 * partner]
                total[1] = total[1] - blk[0] * x[2 * partner + 1]
        return total

    @wp.func(inline=True)
    def coupling_rows(i: int, data: Data, state: State) -> vec:
        """sum_j |K_ij| of the ties' off-diagonal parts at node i's dofs [N/m]."""
        rows = vec(scalar(0.0), scalar(0.0))
        for k in range(data.node_tie_start[i], data.node_tie_start[i + 1]):
            t = data.node_ties[k]
            if data.tie_b[t] >= 0:
                blk = state.coupling[t]
                rows = rows + vec(wp.abs(blk[2]), wp.abs(blk[0]))
        return rows

    # ------------------------------------------------ the stiffest tangent's rows (5.5)

    @wp.func(inline=True)
    def plane_rows(i: int, data: Data, state: State) -> scalar:
        """sum_j |K_ij| of the moving planes' friction coupling at node i's in-plane dof
        beyond its ties' own k_t, every tie sticking [N/m] (J^T k_t J, J carrying -w on the
        plane nodes: docs/model.md section 10)."""
        rows = scalar(0.0)
        if wp.static(boundary and friction):
            counts = vec(scalar(data.plane_offsets[1] - data.plane_offsets[0]),
                         scalar(data.plane_offsets[2] - data.plane_offsets[1]))
            for k in range(data.node_tie_start[i], data.node_tie_start[i + 1]):
                t = data.node_ties[k]
                f = 1
                if data.tie_a[t] == i:
                    f = 0
                rows += data.friction_law[t, 3] * data.tie_weight[t][f] * counts[f]
            family = data.node_plane[i]
            if family >= 0:
                g = data.node_group[i]
                for t in range(data.group_tie[g], data.group_tie[g + 1]):
                    w = data.tie_weight[t][family]
                    rows += data.friction_law[t, 3] * wp.abs(w) * (scalar(1.0)
                                                                    + wp.abs(w) * counts[family])
        return rows

    @wp.func(inline=True)
    def stiffest_chain(c: int, data: Data, state: State):
        """Chain c's stiffest band into state.band (after its ties' `stiffest_tie`)."""
        assemble_chain(c, state.position, data, state, state.band, 0)

    @wp.func(inline=True)
    def gershgorin_row(i: int, data: Data, state: State) -> scalar:
        """The larger over node i's two dofs of sum_j |K_ij| [N/m] of the stiffest tangent:
        its chain's band, its ties' and (boundary variants) the wraps' and moving planes'
        couplings, its node terms' stiffness."""
        off = coupling_rows(i, data, state)
        if wp.static(boundary):
            off = off + wrap_cross_rows(state.position, data, i)
            off = off + vec(plane_rows(i, data, state), scalar(0.0))
        rows = wp.max(band_ops.absolute_row_sum(state.band, 2 * i) + off[0],
                      band_ops.absolute_row_sum(state.band, 2 * i + 1) + off[1])
        if wp.static(forces.node.count > 0):  # the band holds no node term
            rows = rows + forces.node.stiffness(i, state.position, data)
        return rows

    @wp.func(inline=True)
    def largest_diagonal(i: int, data: Data, state: State) -> scalar:
        """max |K_ii| [N/m] over node i's dofs of the stiffest band."""
        return wp.max(wp.abs(state.band[2 * i, BANDWIDTH]),
                      wp.abs(state.band[2 * i + 1, BANDWIDTH]))

    return SimpleNamespace(assemble_chain=assemble_chain, tie_blocks=tie_blocks,
                           stiffest_tie=stiffest_tie, stiffest_chain=stiffest_chain,
                           gershgorin_row=gershgorin_row, largest_diagonal=largest_diagonal,
                           coupling_vector=coupling_vector, wrap_cross=wrap_cross,
                           theta_hessian=theta_hessian)
