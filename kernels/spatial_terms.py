"""The spatial fabric's element forces and energies in a kernel (docs/model.md section 11): the
Warp form of `dynfab.model.terms.spatial` (its energies and exact gradients; the exact Hessians
stay on the host, where the masses' Gershgorin rows and the certificate take them), and the
semi-implicit method's positive semi-definite tangent (`tangent_terms`).

Nodes carry x, y, z (vec3, the fabric's plane x-y). Each force function adds -dE/dX of one
element to the nodes of its stencil in a force array (the scatter order of
`structure_forces`: a group's thread adds every element once); each energy function returns
E [J]. The elements (docs/model.md eqs. in section 11; the derivatives as
`dynfab.model.terms.spatial`'s docstring states them):

- bending in two planes (11.1) at node j between i and k: e1 = x_j - x_i, e2 = x_k - x_j,
  m_b = kb (theta(e2) - theta(e1) - theta0), m_l = kl (wrap(psi(e2) - psi(e1)) - psi0),
  G_m = m_b dtheta/de(e_m) + m_l dpsi/de(e_m); forces (-G1, G1 + G2, -G2) on (i, j, k);
- the crossing (11.2): q = (s_x, s_y, phi) of its stencil (a_prev, a, a_next, b_prev, b,
  b_next), the slip S = (s_x - xi_x, s_y - xi_y, rho wrap(phi - xi_phi)) from its anchor,
  E = Huber(S) + 1/2 K wrap(phi - phi_rest)^2 with F_T of the current contact force;
  dE/dq = (h_x, h_y, rho h_phi + K w), h = dHuber/dS, chained through
  ds/dd = R(-alpha), ds/dalpha = (s_y, -s_x), dphi/dalpha = -1, dphi/dbeta = 1,
  dalpha/dc_a = (-c_a,y, c_a,x) / |c_a|^2 (beta alike);
- the lateral contact (11.5): d = sign cross2(c, v) / |c|, E = E_lat(d) for d < w (1/2 k
  (w - d)^2, or Gutowski's compaction and the core below s_core: `compaction_law` of
  `dynfab.model.terms.spatial`, law columns (sign, w, k, A, s_a, s_core)),
  dd/dc = sign ((v_y, -v_x) / |c| - cross2 c / |c|^3), dd/dv = sign (-c_y, c_x) / |c|.

The stretch and the contact along z are the planar kernels' own (`structure_forces`), written
for any vector size.
"""

import functools
from types import SimpleNamespace

import numpy as np
import warp as wp

from dynfab.kernels import band_lu, host_rows, material_terms, structure_arrays, structure_state
from dynfab.kernels import tie_law
from dynfab.kernels.precision import vector

ROWS_FROM_HOST = True
"""The dynamic solver's masses take the stiffest tangent's rows from the host's exact Hessian
(`dynfab.model.terms.kinematics.stiffest_rows`): `tangent_terms`' blocks are Gauss-Newton's."""
BOUNDARY = False
"""No moving planes, wrap springs or tied families in space."""
REFUSALS = (
    ("precision", "float32", "float32 positions (a relative rounding of 6e-8) against the "
     "yarns' stretch stiffness leave a force floor far above the trellis mode's residual (a "
     "[specimen]'s: docs/results.md, \"float32 on a specimen\")"),
)
"""The dynamic options these elements refuse (docs/model.md section 11.11): (option, value,
why)."""
REFUSED_BY = ("a structure of spatial kinematics does not run", "section 11.11")
"""What refuses an option (its words, the verb included) and where docs/model.md says why
(`dynfab.solvers.dynamic`)."""
STIFFENS_IN_A_STEP = False
"""Whether a load step can stiffen the elements past the masses at its start (no:
`structure_explicit.check_step`)."""
PI = float(np.pi)
TWO_PI = 2.0 * float(np.pi)


@functools.cache
def functions(scalar, sliding: bool = False) -> SimpleNamespace:
    """The spatial elements' `wp.func`s for one scalar type (module docstring); with `sliding`
    each element sees its nodes where they are and its springs' material now
    (`material_terms`, docs/model.md 11.13)."""
    vec = vector(scalar, 3)
    M = material_terms.functions(scalar, 3, sliding)  # noqa: N806
    P = M.physical  # noqa: N806 (node i where the elements see it)
    huber_law = tie_law.huber_term(vec)
    Data = structure_arrays.struct(scalar, 3)
    pair = wp.types.matrix(shape=(2, 3), dtype=scalar)
    triple = wp.types.matrix(shape=(3, 3), dtype=scalar)

    @wp.func(inline=True)
    def rows2(a: vec, b: vec) -> pair:
        """The 2 x 3 matrix of rows a, b."""
        return pair(a[0], a[1], a[2], b[0], b[1], b[2])

    @wp.func(inline=True)
    def rows3(a: vec, b: vec, c: vec) -> triple:
        """The 3 x 3 matrix of rows a, b, c."""
        return triple(a[0], a[1], a[2], b[0], b[1], b[2], c[0], c[1], c[2])

    @wp.func(inline=True)
    def wrap(angle: scalar) -> scalar:
        """The angle [rad] in (-pi, pi] that differs from `angle` by a multiple of 2 pi."""
        return angle - scalar(TWO_PI) * wp.ceil((angle - scalar(PI)) / scalar(TWO_PI))

    @wp.func(inline=True)
    def elevation(e: vec) -> scalar:
        """theta(e) = atan2(e_z, |e_xy|) [rad]."""
        return wp.atan2(e[2], wp.sqrt(e[0] * e[0] + e[1] * e[1]))

    @wp.func(inline=True)
    def elevation_gradient(e: vec) -> vec:
        """dtheta/de = (-z n_x, -z n_y, r) / |e|^2 [1/m], n = e_xy / r."""
        r = wp.sqrt(e[0] * e[0] + e[1] * e[1])
        z = e[2]
        rr = r * r + z * z
        return vec(-z * (e[0] / r) / rr, -z * (e[1] / r) / rr, r / rr)

    @wp.func(inline=True)
    def direction(e: vec) -> scalar:
        """psi(e) = atan2(e_y, e_x) [rad]."""
        return wp.atan2(e[1], e[0])

    @wp.func(inline=True)
    def direction_gradient(e: vec) -> vec:
        """dpsi/de = (-e_y, e_x, 0) / r^2 [1/m]."""
        r2 = e[0] * e[0] + e[1] * e[1]
        return vec(-e[1] / r2, e[0] / r2, scalar(0.0))

    @wp.func(inline=True)
    def elevation_excess(data: Data, j: int, a: vec, b: vec) -> scalar:
        """theta(b) - theta(a) - theta0 [rad] at node j."""
        return elevation(b) - elevation(a) - data.rest_angle[j]

    @wp.func(inline=True)
    def lateral_excess(data: Data, j: int, a: vec, b: vec) -> scalar:
        """wrap(psi(b) - psi(a)) - psi0 [rad] at node j."""
        return wrap(direction(b) - direction(a)) - data.lateral_rest_angle[j]

    @wp.func(inline=True)
    def bend_gradients(pos: wp.array(dtype=vec), data: Data, i: int, j: int, k: int) -> pair:
        """Rows (G1, G2) [N] of the bending spring at j (neighbours i, k): its forces are
        (-G1, G1 + G2, -G2) on (i, j, k) (module docstring)."""
        a = P(pos, data, j) - P(pos, data, i)
        b = P(pos, data, k) - P(pos, data, j)
        mb = M.bend_stiffness(pos, data, j) * elevation_excess(data, j, a, b)
        ml = M.lateral_bend_stiffness(pos, data, j) * lateral_excess(data, j, a, b)
        return rows2(mb * elevation_gradient(a) + ml * direction_gradient(a),
                     mb * elevation_gradient(b) + ml * direction_gradient(b))

    @wp.func(inline=True)
    def bend_forces(pos: wp.array(dtype=vec), data: Data, i: int, j: int, k: int,
                    force: wp.array(dtype=vec)):
        """force += -dE/dX of the bending spring at j (neighbours i, k) (module docstring)."""
        g = bend_gradients(pos, data, i, j, k)
        g1 = g[0]
        g2 = g[1]
        force[i] = force[i] - g1
        force[j] = force[j] + g1 + g2
        force[k] = force[k] - g2

    @wp.func(inline=True)
    def bend_energy(pos: wp.array(dtype=vec), data: Data, i: int, j: int, k: int) -> scalar:
        """E [J] of the bending spring at j (docs/model.md (11.1))."""
        a = P(pos, data, j) - P(pos, data, i)
        b = P(pos, data, k) - P(pos, data, j)
        out_of_plane = elevation_excess(data, j, a, b)
        lateral = lateral_excess(data, j, a, b)
        return (scalar(0.5) * M.bend_stiffness(pos, data, j) * out_of_plane * out_of_plane
                + scalar(0.5) * M.lateral_bend_stiffness(pos, data, j) * lateral * lateral)

    @wp.func(inline=True)
    def crossing_coordinates(pos: wp.array(dtype=vec), data: Data, t: int) -> vec:
        """q = (s_x [m], s_y [m], phi [rad]) of crossing t (docs/model.md (11.2))."""
        st = data.tie_stencil
        p0 = P(pos, data, st[t, 0])
        p2 = P(pos, data, st[t, 2])
        p3 = P(pos, data, st[t, 3])
        p5 = P(pos, data, st[t, 5])
        alpha = wp.atan2(p2[1] - p0[1], p2[0] - p0[0])
        beta = wp.atan2(p5[1] - p3[1], p5[0] - p3[0])
        dx = P(pos, data, st[t, 4])[0] - P(pos, data, st[t, 1])[0]
        dy = P(pos, data, st[t, 4])[1] - P(pos, data, st[t, 1])[1]
        c = wp.cos(alpha)
        s = wp.sin(alpha)
        return vec(c * dx + s * dy, -s * dx + c * dy, wrap(beta - alpha))

    @wp.func(inline=True)
    def crossing_slip(pos: wp.array(dtype=vec), data: Data, anchor: vec, t: int) -> vec:
        """S [m] of crossing t from its anchor (docs/model.md section 11.4)."""
        q = crossing_coordinates(pos, data, t)
        return vec(q[0] - anchor[0], q[1] - anchor[1],
                   data.rotation_law[t, 0] * wrap(q[2] - anchor[2]))

    @wp.func(inline=True)
    def spring_excess(data: Data, t: int, q: vec) -> scalar:
        """wrap(phi - phi_rest) [rad] of crossing t's rotation spring."""
        return wrap(q[2] - data.rotation_law[t, 2])

    @wp.func(inline=True)
    def crossing_gradients(pos: wp.array(dtype=vec), data: Data, t: int, huber: vec) -> triple:
        """Rows (g_ca, g_d, g_cb) [N] of crossing t, dHuber/dS = `huber` (module docstring):
        its forces are +g_ca, +g_d, +g_cb on stencil slots 0, 1, 3 and their opposites on
        slots 2, 4, 5 (`slot_force`)."""
        st = data.tie_stencil
        p0 = P(pos, data, st[t, 0])
        p2 = P(pos, data, st[t, 2])
        p3 = P(pos, data, st[t, 3])
        p5 = P(pos, data, st[t, 5])
        cax = p2[0] - p0[0]
        cay = p2[1] - p0[1]
        cbx = p5[0] - p3[0]
        cby = p5[1] - p3[1]
        alpha = wp.atan2(cay, cax)
        beta = wp.atan2(cby, cbx)
        dx = P(pos, data, st[t, 4])[0] - P(pos, data, st[t, 1])[0]
        dy = P(pos, data, st[t, 4])[1] - P(pos, data, st[t, 1])[1]
        c = wp.cos(alpha)
        s = wp.sin(alpha)
        sx = c * dx + s * dy
        sy = -s * dx + c * dy
        w = wrap(wrap(beta - alpha) - data.rotation_law[t, 2])
        f0 = huber[0]
        f1 = huber[1]
        f2 = data.rotation_law[t, 0] * huber[2] + data.rotation_law[t, 1] * w
        gd = vec(f0 * c - f1 * s, f0 * s + f1 * c, scalar(0.0))
        galpha = f0 * sy - f1 * sx - f2
        ra = cax * cax + cay * cay
        rb = cbx * cbx + cby * cby
        return rows3(galpha * vec(-cay / ra, cax / ra, scalar(0.0)), gd,
                     f2 * vec(-cby / rb, cbx / rb, scalar(0.0)))

    @wp.func(inline=True)
    def crossing_forces(pos: wp.array(dtype=vec), data: Data, t: int, huber: vec,
                        force: wp.array(dtype=vec)):
        """force += -dE/dX of crossing t, dHuber/dS = `huber` (module docstring)."""
        st = data.tie_stencil
        g = crossing_gradients(pos, data, t, huber)
        gca = g[0]
        gd = g[1]
        gcb = g[2]
        force[st[t, 0]] = force[st[t, 0]] + gca
        force[st[t, 2]] = force[st[t, 2]] - gca
        force[st[t, 1]] = force[st[t, 1]] + gd
        force[st[t, 4]] = force[st[t, 4]] - gd
        force[st[t, 3]] = force[st[t, 3]] + gcb
        force[st[t, 5]] = force[st[t, 5]] - gcb

    @wp.func(inline=True)
    def crossing_slot_force(g: triple, slot: int) -> vec:
        """The force [N] of a crossing with rows `g` (`crossing_gradients`) on its stencil's
        node `slot` (0..5): +g_ca, +g_d, -g_ca, +g_cb, -g_d, -g_cb."""
        force = vec()
        if slot == 0:
            force = g[0]
        elif slot == 1:
            force = g[1]
        elif slot == 2:
            force = -g[0]
        elif slot == 3:
            force = g[2]
        elif slot == 4:
            force = -g[1]
        else:
            force = -g[2]
        return force

    @wp.func(inline=True)
    def gutowski_potential(s: scalar, w: scalar, packed: scalar) -> scalar:
        """Phi(s) of Gutowski's compaction [m] (`dynfab.model.terms.spatial._gutowski`)."""
        ra = wp.sqrt(packed)
        v = wp.sqrt(s) / ra - scalar(1.0)
        return scalar(2.0) * ra * (ra / (scalar(2.0) * v * v)
                                   - (wp.sqrt(w) - ra) / (scalar(3.0) * v * v * v))

    @wp.func(inline=True)
    def gutowski_pressure(s: scalar, w: scalar, packed: scalar) -> scalar:
        """sigma(s) = (sqrt(w / s) - 1) / v^4, v = sqrt(s / s_a) - 1 [-]."""
        v = wp.sqrt(s / packed) - scalar(1.0)
        return (wp.sqrt(w / s) - scalar(1.0)) / (v * v * v * v)

    @wp.func(inline=True)
    def lateral_slope(data: Data, e: int, d: scalar) -> scalar:
        """dE_lat/dd [N] of lateral contact e at centreline distance d (module docstring)."""
        w = data.lateral_law[e, 1]
        k = data.lateral_law[e, 2]
        A = data.lateral_law[e, 3]
        packed = data.lateral_law[e, 4]
        core = data.lateral_law[e, 5]
        slope = -k * (w - d)
        if A > scalar(0.0):
            if d >= core:
                slope = -A * gutowski_pressure(d, w, packed)
            else:
                slope = -A * gutowski_pressure(core, w, packed) + k * (d - core)
        return slope

    @wp.func(inline=True)
    def lateral_law_energy(data: Data, e: int, gap: scalar) -> scalar:
        """E_lat [J] of lateral contact e at w - d = `gap` (module docstring)."""
        w = data.lateral_law[e, 1]
        k = data.lateral_law[e, 2]
        A = data.lateral_law[e, 3]
        packed = data.lateral_law[e, 4]
        core = data.lateral_law[e, 5]
        energy = scalar(0.5) * k * gap * gap
        if A > scalar(0.0):
            d = w - gap
            at = wp.max(d, core)
            energy = A * (gutowski_potential(w, w, packed) - gutowski_potential(at, w, packed))
            if d < core:
                x = d - core
                energy = (energy - A * gutowski_pressure(core, w, packed) * x
                          + scalar(0.5) * k * x * x)
        return energy

    @wp.func(inline=True)
    def lateral_distance(pos: wp.array(dtype=vec), data: Data, e: int) -> scalar:
        """d = sign cross2(c, v) / |c| [m] of lateral contact e (module docstring)."""
        st = data.lateral_stencil
        c = P(pos, data, st[e, 1]) - P(pos, data, st[e, 0])
        v = P(pos, data, st[e, 3]) - P(pos, data, st[e, 2])
        return data.lateral_law[e, 0] * (c[0] * v[1] - c[1] * v[0]) / wp.sqrt(c[0] * c[0]
                                                                              + c[1] * c[1])

    @wp.func(inline=True)
    def lateral_gap(pos: wp.array(dtype=vec), data: Data, e: int) -> scalar:
        """w - d [m] of lateral contact e (positive where the yarns press)."""
        return data.lateral_law[e, 1] - lateral_distance(pos, data, e)

    @wp.func(inline=True)
    def lateral_distance_rows(pos: wp.array(dtype=vec), data: Data, e: int) -> pair:
        """(dd/dc, dd/dv) [-] of lateral contact e (module docstring): dd/dX = -dd/dc,
        +dd/dc, -dd/dv, +dd/dv on stencil slots 0..3."""
        st = data.lateral_stencil
        c = P(pos, data, st[e, 1]) - P(pos, data, st[e, 0])
        v = P(pos, data, st[e, 3]) - P(pos, data, st[e, 2])
        sign = data.lateral_law[e, 0]
        n2 = c[0] * c[0] + c[1] * c[1]
        n = wp.sqrt(n2)
        n3 = n2 * n
        f = c[0] * v[1] - c[1] * v[0]
        return rows2(sign * vec(v[1] / n - f * c[0] / n3, -v[0] / n - f * c[1] / n3,
                                scalar(0.0)),
                     sign * vec(-c[1] / n, c[0] / n, scalar(0.0)))

    @wp.func(inline=True)
    def lateral_gradients(pos: wp.array(dtype=vec), data: Data, e: int) -> pair:
        """Rows (g_c, g_v) [N] of lateral contact e, dE/dd (dd/dc, dd/dv), zero where it is
        open: its forces are +g_c, -g_c, +g_v, -g_v on stencil slots 0..3 (module
        docstring)."""
        d = lateral_distance(pos, data, e)
        g = pair()
        if data.lateral_law[e, 1] - d > scalar(0.0):
            g = lateral_slope(data, e, d) * lateral_distance_rows(pos, data, e)
        return g

    @wp.func(inline=True)
    def lateral_forces(pos: wp.array(dtype=vec), data: Data, e: int,
                       force: wp.array(dtype=vec)):
        """force += -dE/dX of lateral contact e (module docstring)."""
        st = data.lateral_stencil
        g = lateral_gradients(pos, data, e)
        gc = g[0]
        gv = g[1]
        force[st[e, 1]] = force[st[e, 1]] - gc
        force[st[e, 0]] = force[st[e, 0]] + gc
        force[st[e, 3]] = force[st[e, 3]] - gv
        force[st[e, 2]] = force[st[e, 2]] + gv

    @wp.func(inline=True)
    def lateral_energy(pos: wp.array(dtype=vec), data: Data, e: int) -> scalar:
        """E = E_lat(d) for d < w, else 0 [J]."""
        gap = lateral_gap(pos, data, e)
        energy = scalar(0.0)
        if gap > scalar(0.0):
            energy = lateral_law_energy(data, e, gap)
        return energy

    @wp.func(inline=True)
    def return_anchor(S: vec, bound: scalar, stick: scalar, rho: scalar) -> vec:
        """The anchor's move [m, m, rad]: m (S_x, S_y, S_phi / rho), m = 1 - F_T / (k_t |S|),
        where k_t |S| > F_T (F_T <= 0 counting as 0), else 0 (`dynfab.model.terms.spatial`)."""
        size = wp.length(S)
        limit = wp.max(bound, scalar(0.0))
        move = vec()
        if stick * size > limit:
            m = scalar(1.0) - limit / (stick * size)
            move = vec(m * S[0], m * S[1], m * S[2] / rho)
        return move

    return SimpleNamespace(rows3=rows3, wrap=wrap, bend_forces=bend_forces,
                           bend_gradients=bend_gradients, elevation_gradient=elevation_gradient,
                           direction_gradient=direction_gradient, lateral_gap=lateral_gap,
                           lateral_slope=lateral_slope, lateral_distance=lateral_distance,
                           lateral_distance_rows=lateral_distance_rows,
                           bend_energy=bend_energy, crossing_gradients=crossing_gradients,
                           crossing_slot_force=crossing_slot_force,
                           lateral_gradients=lateral_gradients,
                           crossing_coordinates=crossing_coordinates, crossing_slip=crossing_slip,
                           huber_force=huber_law.force, huber_energy=huber_law.energy,
                           spring_excess=spring_excess, crossing_forces=crossing_forces,
                           lateral_forces=lateral_forces, lateral_energy=lateral_energy,
                           return_anchor=return_anchor)


def structure_terms(scalar, friction: bool, boundary: bool, base) -> SimpleNamespace:
    """The spatial elements in the form every kinematics gives `structure_forces`
    (`plane_shift`, `tie_pass_at`, `node_force`, `scatter`, `add_node_energy`,
    `add_tie_energy`, `lateral_energy`, `return_anchor`), on `base` (`structure_forces.base`). A
    spatial structure has no moving planes, wraps or tied dofs (`structure_arrays.build`), so
    `boundary` compiles nothing here.

    Where the crossings slide (`base.sliding`, docs/model.md 11.13) node b of a crossing sees
    node a's x and y, and its own x and y hold the two slides: node a's force gathers node
    b's in-plane force (`node_force`), the slides' force is the material's
    (`material_terms.material_forces`) plus lambda_k H'(S)_k, and the crossing's physical
    force is its rotation's alone (`slip`: S = (lambda_a (delta_a - xi_a), lambda_b (delta_b -
    xi_b), rho wrap(phi - phi_anchor)), 11.13c)."""
    vec = vector(scalar, 3)
    Data = structure_arrays.struct(scalar, 3)
    State = structure_state.struct(scalar, 3)
    laws = tie_law.functions(scalar)
    sliding = base.sliding
    terms = functions(scalar, sliding)
    segment_pull = base.segment_pull
    slide = material_terms.sliding_functions(scalar, 3).slide

    @wp.func(inline=True)
    def plane_shift(pos: wp.array(dtype=vec), data: Data) -> vec:
        """Zero [m]: a spatial structure has no moving planes."""
        return vec()

    @wp.func(inline=True)
    def node_bend_energy(pos: wp.array(dtype=vec), data: Data, m: int) -> scalar:
        """E_m [J] of the two-plane bending spring at node m, 0 at a chain's ends."""
        before = data.previous[m]
        after = data.next[m]
        energy = scalar(0.0)
        if before >= 0 and after >= 0:
            energy = terms.bend_energy(pos, data, before, m, after)
        return energy

    material = material_terms.material_forces(scalar, 3, node_bend_energy)

    @wp.func(inline=True)
    def fixed_slip(pos: wp.array(dtype=vec), data: Data, state: State, t: int) -> vec:
        """S [m] of crossing t from its anchor (docs/model.md section 11.4)."""
        return terms.crossing_slip(pos, data, state.anchors[t], t)

    @wp.func(inline=True)
    def sliding_slip(pos: wp.array(dtype=vec), data: Data, state: State, t: int) -> vec:
        """S = (lambda_a (delta_a - xi_a), lambda_b (delta_b - xi_b), rho wrap(phi -
        phi_anchor)) [m] of crossing t (11.13c)."""
        anchor = state.anchors[t]
        stretch = state.stretch[t]
        phi = terms.crossing_coordinates(pos, data, t)[2]
        return vec(stretch[0] * (slide(pos, data, t, 0) - anchor[0]),
                   stretch[1] * (slide(pos, data, t, 1) - anchor[1]),
                   data.rotation_law[t, 0] * terms.wrap(phi - anchor[2]))

    slip = sliding_slip if sliding else fixed_slip

    @wp.func(inline=True)
    def stencil_huber(state: State, t: int) -> vec:
        """dHuber/dS [N] of crossing t that its stencil's positions take: all of it, or where
        the crossings slide the rotation's part alone (the slides take the rest)."""
        huber = vec()
        if wp.static(friction):
            huber = -state.friction[t]
            if wp.static(sliding):
                huber = vec(scalar(0.0), scalar(0.0), huber[2])
        return huber

    @wp.func(inline=True)
    def tie_pass_at(t: int, pos: wp.array(dtype=vec), data: Data, state: State, shift: vec):
        """R, dR/dg (and F_T, the force -dHuber/dS on the three-component slip) of crossing t
        into the state's tie arrays; `shift` unused (no moving planes)."""
        bound = base.contact_pass(t, pos, data, state)
        if wp.static(friction):
            state.friction[t] = terms.huber_force(slip(pos, data, state, t), bound,
                                                  data.friction_law[t, 3])

    @wp.func(inline=True)
    def physical_force(i: int, pos: wp.array(dtype=vec), data: Data, state: State) -> vec:
        """-dV/dr_i (+ friction) [N] at node i's physical position, unmasked: its segments, the
        bending springs at i and its neighbours, the crossings and lateral contacts whose
        stencils hold it (each element evaluated at every node of its stencil), its ties'
        contact along z."""
        before = data.previous[i]
        after = data.next[i]
        force = base.own_and_stretch(i, pos, data, state)
        if before >= 0:
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
            up = base.along_z(data.tie_side[t] * state.contact[t])
            if data.tie_a[t] == i:
                force = force + up
            else:
                force = force - up
        for k in range(data.node_stencil_start[i], data.node_stencil_start[i + 1]):
            code = data.node_stencil[k]
            t = code / 6
            force = force + terms.crossing_slot_force(
                terms.crossing_gradients(pos, data, t, stencil_huber(state, t)), code - 6 * t)
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
    def slide_friction(i: int, c: int, data: Data, state: State) -> scalar:
        """lambda_k H'(S)_k [N]: the friction force on the slide in node i's dof c (11.13c)."""
        total = scalar(0.0)
        if wp.static(friction):
            for k in range(data.node_tie_start[i], data.node_tie_start[i + 1]):
                t = data.node_ties[k]
                for side in range(2):
                    if data.tie_slide[t, side] == 3 * i + c:
                        total += state.stretch[t][side] * state.friction[t][side]
        return total

    @wp.func(inline=True)
    def sliding_node_force(i: int, pos: wp.array(dtype=vec), data: Data, state: State) -> vec:
        """-dV/d(dofs of node i) [N], gathered, unmasked, where the crossings slide: each
        coordinate's physical force (`physical_force`) on the dof that holds it
        (`physical_source`: node a's x and y hold its crossing's node b's too, node b's hold
        its slides), and on a dof holding a slide the material's force and the friction's
        (`structure_terms`). Loops that Warp does not unroll (`while`), so that each large
        function is compiled in once."""
        force = vec()
        first = data.node_tie_start[i]
        k = first - 1  # node i itself, then the other node of each of its ties
        while k < data.node_tie_start[i + 1]:
            j = i
            if k >= first:
                t = data.node_ties[k]
                j = data.tie_a[t] + data.tie_b[t] - i
            source = data.physical_source[j, 0]
            if j == i or (source >= 0 and source // 3 == i):
                seen = physical_force(j, pos, data, state)
                for c in range(3):
                    source = data.physical_source[j, c]
                    if source >= 0 and source // 3 == i:
                        force[source % 3] = force[source % 3] + seen[c]
            k += 1
        c = int(0)
        while c < 3:
            walk = data.node_slide[i, c]
            if walk >= 0:
                force[c] = material.material_force(pos, data, walk, 3 * i + c) \
                    + slide_friction(i, c, data, state)
            c += 1
        return force

    node_force = sliding_node_force if sliding else physical_force  # -dV/d(dofs of node i)

    @wp.func(inline=True)
    def scatter(group: int, pos: wp.array(dtype=vec), data: Data, state: State):
        """state.force += -dV/dr of the group's elements, each once: each segment's stretch and
        each inner node's two-plane bending, each crossing's contact along z, Huber friction
        (F_T at the current R) and rotation spring, each lateral contact (fixed crossings:
        where they slide, the gather order runs)."""
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
            up = base.along_z(data.tie_side[t] * state.contact[t])
            force[data.tie_a[t]] = force[data.tie_a[t]] + up
            force[data.tie_b[t]] = force[data.tie_b[t]] - up
            terms.crossing_forces(pos, data, t, stencil_huber(state, t), force)
        for e in range(data.group_lateral[group], data.group_lateral[group + 1]):
            terms.lateral_forces(pos, data, e, force)

    @wp.func(inline=True)
    def add_node_energy(i: int, pos: wp.array(dtype=vec), data: Data, energy: scalar) -> scalar:
        """`energy` + the two-plane bending spring at node i [J] (docs/model.md (11.1))."""
        return energy + node_bend_energy(pos, data, i)

    @wp.func(inline=True)
    def add_tie_energy(t: int, pos: wp.array(dtype=vec), data: Data, state: State, R: scalar,
                       energy: scalar) -> scalar:
        """`energy` + crossing t's rotation spring and (with friction) its Huber term with F_T
        at R [J]."""
        q = terms.crossing_coordinates(pos, data, t)
        w = terms.spring_excess(data, t, q)
        total = energy + scalar(0.5) * data.rotation_law[t, 1] * w * w
        if wp.static(friction):
            total += terms.huber_energy(slip(pos, data, state, t),
                                        laws.limit(R, data.friction_law, t),
                                        data.friction_law[t, 3])
        return total

    @wp.func(inline=True)
    def lateral_energy(e: int, pos: wp.array(dtype=vec), data: Data) -> scalar:
        """Energy [J] of lateral contact e."""
        return terms.lateral_energy(pos, data, e)

    @wp.func(inline=True)
    def return_anchor(t: int, pos: wp.array(dtype=vec), data: Data, state: State,
                      bound: scalar) -> scalar:
        """Crossing t's anchor moved radially in S (docs/model.md section 11.4; where the
        crossings slide, the material anchors by the move over their stretches, 11.13c); the
        energy dissipated F_T |delta S| [J]."""
        rho = data.rotation_law[t, 0]
        move = terms.return_anchor(slip(pos, data, state, t), bound, data.friction_law[t, 3],
                                   rho)
        shift = vec(move[0], move[1], rho * move[2])
        if wp.static(sliding):
            stretch = state.stretch[t]
            move = vec(move[0] / stretch[0], move[1] / stretch[1], move[2])
        state.anchors[t] = state.anchors[t] + move
        return wp.max(bound, scalar(0.0)) * wp.length(shift)

    return SimpleNamespace(plane_shift=plane_shift, tie_pass_at=tie_pass_at,
                           node_force=node_force, scatter=scatter,
                           add_node_energy=add_node_energy, add_tie_energy=add_tie_energy,
                           lateral_energy=lateral_energy, return_anchor=return_anchor)


@functools.cache
def tangent_terms(scalar, friction: bool, boundary: bool) -> SimpleNamespace:
    """The semi-implicit tangent of the spatial elements (docs/model.md section 11.11; the
    planar form is `structure_tangent`'s): positive semi-definite Gauss-Newton blocks, each a
    term's second derivative in its own coordinate times the outer product of that
    coordinate's gradient, the coordinates' curvature left out (as the planar `definite`
    mode leaves out bending's moment term):

    - stretch: k [e e^T / l^2 + max(0, 1 - l0/l) (I - e e^T / l^2)];
    - bending: kb dTheta dTheta^T + kl dPsi dPsi^T over (i, j, k), dTheta = (dtheta(e1),
      -dtheta(e1) - dtheta(e2), dtheta(e2)), dPsi alike;
    - a crossing: J^T H_q J on its stencil, J = dq/dX (q = (s_x, s_y, phi)), H_q = D H D
      + K e_phi e_phi^T, H in S k_t I sticking and the secant (F_T / |S|) I sliding (not the
      Huber Hessian's (F_T / |S|)(I - S S^T / |S|^2), which leaves a sliding crossing no
      stiffness along its slip: docs/model.md 11.11 has the measurement), D = diag(1, 1,
      rho); its contact along z dR/dg on (z_a, z_b);
    - a lateral contact: E_lat''(d) dd dd^T where it presses (E_lat'' by a central difference
      of E_lat', clipped at 0).

    `assemble_chain` puts into a chain's band every block that lies in it (`in_band`: both
    nodes on the chain, at most two apart): its stretch and bending, its ties' dR/dg on z, and
    those blocks of its crossings and lateral contacts; `coupling_vector` applies the rest to x
    (a crossing's chord ends, four nodes apart at four segments per spacing, the blocks
    joining two yarns, the contact's -dR/dg between z_a and z_b), so the CG's product is the
    whole tangent and the bands its preconditioner. `tie_blocks` stores each crossing's dR/dg
    and H_q (`StructureState.tie_hessian`). No moving planes, wraps or tied dofs in space."""
    vec = vector(scalar, 3)
    mat = wp.types.matrix(shape=(3, 3), dtype=scalar)
    pair = wp.types.matrix(shape=(2, 3), dtype=scalar)
    Data = structure_arrays.struct(scalar, 3)
    State = structure_state.struct(scalar, 3)
    terms = functions(scalar)
    band_ops = band_lu.functions(scalar, 3)
    DIAGONAL = band_lu.bandwidth(3)  # noqa: N806 (a band row's diagonal entry)
    rows3 = terms.rows3

    @wp.func(inline=True)
    def add_stretch(band: wp.array2d(dtype=scalar), pos: wp.array(dtype=vec), data: Data,
                    i: int):
        """Segment (i, next)'s block."""
        j = data.next[i]
        e = pos[j] - pos[i]
        l2 = wp.dot(e, e)
        geometric = wp.max(scalar(1.0) - data.rest_length[i] / wp.sqrt(l2), scalar(0.0))
        axial = wp.outer(e, e) / l2
        band_ops.add_pair(band, i, j,
                          data.stretch_stiffness[i] * (axial + geometric
                                                       * (wp.identity(3, scalar) - axial)))

    @wp.func(inline=True)
    def add_outer3(band: wp.array2d(dtype=scalar), n0: int, n1: int, n2: int, k: scalar,
                   g0: vec, g1: vec, g2: vec):
        """k g g^T over nodes (n0, n1, n2), g = (g0, g1, g2)."""
        band_ops.add_block(band, n0, n0, k * wp.outer(g0, g0))
        band_ops.add_block(band, n0, n1, k * wp.outer(g0, g1))
        band_ops.add_block(band, n0, n2, k * wp.outer(g0, g2))
        band_ops.add_block(band, n1, n0, k * wp.outer(g1, g0))
        band_ops.add_block(band, n1, n1, k * wp.outer(g1, g1))
        band_ops.add_block(band, n1, n2, k * wp.outer(g1, g2))
        band_ops.add_block(band, n2, n0, k * wp.outer(g2, g0))
        band_ops.add_block(band, n2, n1, k * wp.outer(g2, g1))
        band_ops.add_block(band, n2, n2, k * wp.outer(g2, g2))

    @wp.func(inline=True)
    def add_bending(band: wp.array2d(dtype=scalar), pos: wp.array(dtype=vec), data: Data,
                    i: int, j: int, k: int):
        """The two-plane spring at j (neighbours i, k)."""
        a = pos[j] - pos[i]
        b = pos[k] - pos[j]
        ta = terms.elevation_gradient(a)
        tb = terms.elevation_gradient(b)
        add_outer3(band, i, j, k, data.bend_stiffness[j], ta, -ta - tb, tb)
        pa = terms.direction_gradient(a)
        pb = terms.direction_gradient(b)
        add_outer3(band, i, j, k, data.lateral_bend_stiffness[j], pa, -pa - pb, pb)

    @wp.func(inline=True)
    def crossing_jacobian(pos: wp.array(dtype=vec), data: Data, t: int, slot: int) -> mat:
        """dq/dX of crossing t's stencil node `slot` (rows s_x, s_y, phi; module docstring
        of `functions`): d = X_4 - X_1 turned by -alpha, alpha of the chord X_2 - X_0, beta
        of X_5 - X_3."""
        st = data.tie_stencil
        p0 = pos[st[t, 0]]
        p2 = pos[st[t, 2]]
        p3 = pos[st[t, 3]]
        p5 = pos[st[t, 5]]
        ca = p2 - p0
        cb = p5 - p3
        alpha = wp.atan2(ca[1], ca[0])
        c = wp.cos(alpha)
        s = wp.sin(alpha)
        d = pos[st[t, 4]] - pos[st[t, 1]]
        sx = c * d[0] + s * d[1]
        sy = -s * d[0] + c * d[1]
        ga = vec(-ca[1], ca[0], scalar(0.0)) / (ca[0] * ca[0] + ca[1] * ca[1])
        gb = vec(-cb[1], cb[0], scalar(0.0)) / (cb[0] * cb[0] + cb[1] * cb[1])
        zero = vec()
        J = mat()
        if slot == 0:
            J = rows3(-sy * ga, sx * ga, ga)
        elif slot == 2:
            J = rows3(sy * ga, -sx * ga, -ga)
        elif slot == 1:
            J = rows3(vec(-c, -s, scalar(0.0)), vec(s, -c, scalar(0.0)), zero)
        elif slot == 4:
            J = rows3(vec(c, s, scalar(0.0)), vec(-s, c, scalar(0.0)), zero)
        elif slot == 3:
            J = rows3(zero, zero, -gb)
        else:
            J = rows3(zero, zero, gb)
        return J

    @wp.func(inline=True)
    def crossing_hessian(state: State, t: int) -> mat:
        """H_q of crossing t from `tie_blocks` [N/m, N, N m]."""
        h = state.tie_hessian
        return mat(h[t, 1], h[t, 2], h[t, 3], h[t, 2], h[t, 4], h[t, 5], h[t, 3], h[t, 5],
                   h[t, 6])

    @wp.func(inline=True)
    def tie_blocks(t: int, pos: wp.array(dtype=vec), data: Data, state: State, shift: vec,
                   secant: int):
        """tie_hessian[t] = (dR/dg, H_q's upper triangle) at the tie pass's R and F_T (F_T
        frozen; `shift` and `secant` unused: no moving planes, and a sliding crossing always
        takes its secant (F_T / |S|) I, module docstring)."""
        rho = data.rotation_law[t, 0]
        H = mat()
        if wp.static(friction):
            S = terms.crossing_slip(pos, data, state.anchors[t], t)
            stick = data.friction_law[t, 3]
            size = wp.length(S)
            bound = wp.max(state.limit[t], scalar(0.0))
            if stick * size <= bound:
                H = stick * wp.identity(3, scalar)
            else:  # the secant: docs/model.md 11.11 measured it against the Hessian
                H = (bound / size) * wp.identity(3, scalar)
        D = wp.diag(vec(scalar(1.0), scalar(1.0), rho))
        H = D * H * D
        H[2, 2] = H[2, 2] + data.rotation_law[t, 1]
        h = state.tie_hessian
        h[t, 0] = state.tangent[t]
        h[t, 1] = H[0, 0]
        h[t, 2] = H[0, 1]
        h[t, 3] = H[0, 2]
        h[t, 4] = H[1, 1]
        h[t, 5] = H[1, 2]
        h[t, 6] = H[2, 2]

    @wp.func(inline=True)
    def lateral_curvature(pos: wp.array(dtype=vec), data: Data, e: int) -> scalar:
        """E_lat''(d) [N/m] of lateral contact e, clipped at 0; 0 where it is open (central
        difference of E_lat' over 1e-6 w)."""
        d = terms.lateral_distance(pos, data, e)
        value = scalar(0.0)
        if data.lateral_law[e, 1] - d > scalar(0.0):
            h = scalar(1.0e-6) * data.lateral_law[e, 1]
            value = wp.max((terms.lateral_slope(data, e, d + h)
                            - terms.lateral_slope(data, e, d - h)) / (scalar(2.0) * h),
                           scalar(0.0))
        return value

    @wp.func(inline=True)
    def lateral_slot_row(rows: pair, slot: int) -> vec:
        """dd/dX of a lateral contact's stencil node `slot` from its distance rows
        (`functions`' lateral_distance_rows)."""
        row = rows[slot / 2]
        if slot % 2 == 0:
            row = -row
        return row

    @wp.func(inline=True)
    def in_band(data: Data, p: int, q: int) -> bool:
        """Whether the block (p, q) lies in a chain's band: both nodes on one chain, at most
        two apart (`band_lu.bandwidth`)."""
        return data.node_chain[p] == data.node_chain[q] and wp.abs(p - q) <= 2

    @wp.func(inline=True)
    def assemble_chain(c: int, pos: wp.array(dtype=vec), data: Data, state: State,
                       band: wp.array2d(dtype=scalar), definite: int):
        """band = the blocks of K [N/m] in chain c's band (`in_band`; `definite` unused: the
        blocks are positive semi-definite by construction): its stretch and bending, its
        ties' dR/dg on z, and each crossing's and lateral contact's blocks between nodes of
        c that lie in the band."""
        a = data.chain_start[c]
        b = data.chain_start[c + 1]
        band_ops.clear(band, 3 * a, 3 * b)
        for i in range(a, b - 1):
            add_stretch(band, pos, data, i)
        for j in range(a + 1, b - 1):
            add_bending(band, pos, data, j - 1, j, j + 1)
        for i in range(a, b):
            for k in range(data.node_tie_start[i], data.node_tie_start[i + 1]):
                band[3 * i + 2, DIAGONAL] += state.tie_hessian[data.node_ties[k], 0]
            for k in range(data.node_stencil_start[i], data.node_stencil_start[i + 1]):
                code = data.node_stencil[k]
                t = code / 6
                row = wp.transpose(crossing_jacobian(pos, data, t, code - 6 * t)) \
                    * crossing_hessian(state, t)
                for v in range(6):
                    other = data.tie_stencil[t, v]
                    if in_band(data, i, other):
                        band_ops.add_block(band, i, other,
                                           row * crossing_jacobian(pos, data, t, v))
            for k in range(data.node_lateral_start[i], data.node_lateral_start[i + 1]):
                code = data.node_lateral[k]
                e = code / 4
                kappa = lateral_curvature(pos, data, e)
                if kappa > scalar(0.0):
                    rows = terms.lateral_distance_rows(pos, data, e)
                    own = kappa * lateral_slot_row(rows, code - 4 * e)
                    for v in range(4):
                        other = data.lateral_stencil[e, v]
                        if in_band(data, i, other):
                            band_ops.add_block(band, i, other,
                                               wp.outer(own, lateral_slot_row(rows, v)))

    @wp.func(inline=True)
    def node_vector(x: wp.array(dtype=scalar), i: int) -> vec:
        return vec(x[3 * i], x[3 * i + 1], x[3 * i + 2])

    @wp.func(inline=True)
    def coupling_vector(i: int, x: wp.array(dtype=scalar), data: Data, state: State) -> vec:
        """The blocks of K outside the chains' bands times x, at node i's dofs [N]: the
        contact's -dR/dg between z_a and z_b, and each crossing's and lateral contact's
        blocks (i, q) with q not `in_band`."""
        pos = state.position
        total = vec()
        for k in range(data.node_tie_start[i], data.node_tie_start[i + 1]):
            t = data.node_ties[k]
            partner = data.tie_a[t]
            if partner == i:
                partner = data.tie_b[t]
            total[2] = total[2] - state.tie_hessian[t, 0] * x[3 * partner + 2]
        for k in range(data.node_stencil_start[i], data.node_stencil_start[i + 1]):
            code = data.node_stencil[k]
            t = code / 6
            Jx = vec()
            for v in range(6):
                other = data.tie_stencil[t, v]
                if not in_band(data, i, other):
                    Jx = Jx + crossing_jacobian(pos, data, t, v) * node_vector(x, other)
            total = total + wp.transpose(crossing_jacobian(pos, data, t, code - 6 * t)) * (
                crossing_hessian(state, t) * Jx)
        for k in range(data.node_lateral_start[i], data.node_lateral_start[i + 1]):
            code = data.node_lateral[k]
            e = code / 4
            kappa = lateral_curvature(pos, data, e)
            if kappa > scalar(0.0):
                rows = terms.lateral_distance_rows(pos, data, e)
                along = scalar(0.0)
                for v in range(4):
                    other = data.lateral_stencil[e, v]
                    if not in_band(data, i, other):
                        along += wp.dot(lateral_slot_row(rows, v), node_vector(x, other))
                total = total + (kappa * along) * lateral_slot_row(rows, code - 4 * e)
        return total

    # The stiffest tangent's rows (docs/model.md (5.5)) come from the host, from the exact
    # Hessian (`host_rows`): the blocks above are Gauss-Newton's, which may
    # not bound it.
    return SimpleNamespace(tie_blocks=tie_blocks, assemble_chain=assemble_chain,
                           coupling_vector=coupling_vector,
                           **vars(host_rows.functions(scalar, 3)))
