"""Nodal forces and energy of a fabric patch, gathered per node (docs/model.md sections 2, 3, 10).

Deterministic two-pass layout, no atomics: a per-crossing pass solves each contact
force R once and writes it to its own slot; a per-node pass then gathers everything
acting on its node from read-only data: the stretch of its two segments, the three
bending springs whose angle it enters (at the node before, itself, the node after;
positions i-2..i+2 along its chain), and +-sigma R of its crossing. A segment's
force is therefore computed twice (once at each end) and a bending spring three
times: cheap against a scatter that would need atomics or colouring, and every
node's force is the same sum in the same order whatever the thread schedule, so
runs are bit for bit repeatable on any device.

Terms (each a twin of the one-yarn kernels, written per node):
- stretch: E = 1/2 (EA / l0)(l - l0)^2 per segment; force on the node at the segment's
  end is -k (l - l0) e / l, e from the other end to it;
- bending: E = 1/2 (EI / lbar)(phi - phi0)^2 at each inner node, phi = atan2(a x b, a . b);
  with moment m = k (phi - phi0), g_a = (a_z, -a_x)/|a|^2, g_b = (-b_z, b_x)/|b|^2, the
  forces on (i-1, i, i+1) are (m g_a, -m g_a + m g_b, -m g_b);
- contact (docs/model.md section 10): g = c - sigma (z_wa - z_we); for g > 0 R solves
  R / k_c + C_wa (1 - exp(-a_wa R)) + C_we (1 - exp(-a_we R)) = g (monotone Newton
  from the lower bound k_c (g - C_wa - C_we), as in `kernels/contact.py`), energy
  R^2 / (2 k_c) + sum_m (C_m / a_m)(1 - exp(-a_m R)(1 + a_m R)); force +sigma R in z
  on the warp node, -sigma R on the weft node;
- friction (variants built with it; docs/model.md sections 4, 10): at crossing c the in-plane slip
  s = (x_wa - X_j - xi_x, y_we - Y_k - xi_y) (X_j, Y_k the nodes' as-woven in-plane
  coordinates plus, where the planes move, the weight times the summed end displacements
  of the family moving them, `plane_shift`; `anchors` holds xi relative to the as-woven
  coordinates) feels the isotropic
  Huber potential with F_T = alpha R + beta ell r_f (1 - exp(-R/R_0)) (R > 0) at the
  crossing's current R, frozen in the derivative: the force -k_t s while sticking
  (k_t |s| <= F_T), -F_T s/|s| while sliding; its first component acts on the warp
  node along x, its second on the weft node along y. The per-crossing pass writes it
  beside R. Where the planes move, each end node moving them feels -sum_c (w_c / n) f_c
  (the chain rule through X_j(u)): its thread gathers it over the crossings, in crossing
  order;
- the periodic wrap (docs/model.md section 10): the bending spring at a yarn's node 0 between
  segment N-1 (a = r_N - r_{N-1}) and segment 0's image (b = r_1 - r_0): forces m g_a on
  r_{N-1}, -m g_a on r_N, -m g_b on r_1, +m g_b on r_0;
- the tied cell length (periodic force control): each end node of a tied family carries the
  family's summed force (each member's own force, gathered in plane-node order);
- the end loads: a given external force per node (its work -f . (r - r0)).
Held dofs (`free` = 0) carry no force.
"""

import functools
from types import SimpleNamespace

import warp as wp

from dynfab.kernels import fabric_arrays, friction as friction_module
from dynfab.kernels.configuration import MODULE_OPTIONS
from dynfab.kernels.contact import NEWTON_STOP_EPS
from dynfab.kernels.precision import VECTORS, epsilon
from dynfab.terms.contact import MAX_NEWTON


@functools.cache
def functions(scalar, has_friction: bool) -> SimpleNamespace:
    """The per-node and per-crossing `wp.func`s for one scalar type, with or without friction."""
    vec = VECTORS[scalar]
    mat = wp.types.matrix(shape=(2, 2), dtype=scalar)
    Fabric = fabric_arrays.struct(scalar)
    newton_stop = NEWTON_STOP_EPS * epsilon(scalar)
    limit = friction_module.functions(scalar).limit

    @wp.func
    def closure(pos: wp.array(dtype=vec), fabric: Fabric, c: int) -> scalar:
        """g = c - sigma (z_wa - z_we) [m] of crossing c."""
        return fabric.crossing_offset[c] - fabric.crossing_side[c] * (
            pos[fabric.crossing_warp[c]][1] - pos[fabric.crossing_weft[c]][1])

    @wp.func
    def series_law(R: scalar, law: wp.array(dtype=scalar)) -> vec:
        """(g(R) [m], dR/dg [N/m]): g = R/k_c + sum_m C_m (1 - exp(-a_m R))."""
        decay_wa = wp.exp(-law[2] * R)
        decay_we = wp.exp(-law[4] * R)
        g = R / law[0] + law[1] * (scalar(1.0) - decay_wa) + law[3] * (scalar(1.0) - decay_we)
        tangent = scalar(1.0) / (scalar(1.0) / law[0] + law[1] * law[2] * decay_wa
                                 + law[3] * law[4] * decay_we)
        return vec(g, tangent)

    @wp.func
    def contact_force(g: scalar, law: wp.array(dtype=scalar)) -> scalar:
        """R(g) [N], 0 where open (g <= 0); Newton increases R monotonically (concave law)."""
        R = scalar(0.0)
        if g > scalar(0.0):
            R = wp.max(scalar(0.0), law[0] * (g - law[1] - law[3]))
            for _ in range(MAX_NEWTON):
                at_R = series_law(R, law)
                step = (g - at_R[0]) * at_R[1]
                if not step > scalar(newton_stop) * R:
                    break
                R += step
        return R

    @wp.func
    def contact_energy(R: scalar, law: wp.array(dtype=scalar)) -> scalar:
        """R^2/(2 k_c) + sum_m (C_m/a_m)(1 - exp(-a_m R)(1 + a_m R)) [J]."""
        energy = R * R / (scalar(2.0) * law[0])
        energy += law[1] / law[2] * (scalar(1.0) - wp.exp(-law[2] * R) * (scalar(1.0) + law[2] * R))
        energy += law[3] / law[4] * (scalar(1.0) - wp.exp(-law[4] * R) * (scalar(1.0) + law[4] * R))
        return energy

    @wp.func
    def plane_shift(pos: wp.array(dtype=vec), fabric: Fabric) -> vec:
        """(sum of the in-plane displacements of the end nodes moving X_j, the same for Y_k)
        [m], in plane-node order; zero with fixed planes (no plane nodes)."""
        shift = vec(scalar(0.0), scalar(0.0))
        for family in range(2):
            total = scalar(0.0)
            for m in range(fabric.plane_offsets[family], fabric.plane_offsets[family + 1]):
                node = fabric.plane_nodes[m]
                total += pos[node][0] - fabric.rest_position[node][0]
            shift[family] = total
        return shift

    @wp.func
    def slip(pos: wp.array(dtype=vec), fabric: Fabric, anchors: wp.array(dtype=vec), c: int,
             shift: vec) -> vec:
        """s = (x_wa - X_j, y_we - Y_k) - xi [m] of crossing c, the planes moved by the
        crossing's weights times `shift` (`plane_shift`)."""
        warp_node = fabric.crossing_warp[c]
        weft_node = fabric.crossing_weft[c]
        return (vec(pos[warp_node][0] - fabric.rest_position[warp_node][0],
                    pos[weft_node][0] - fabric.rest_position[weft_node][0])
                - wp.cw_mul(fabric.crossing_plane_weight[c], shift)) - anchors[c]

    @wp.func
    def friction_limit(R: scalar, fabric: Fabric) -> scalar:
        """F_T [N] at contact force R (0 where open)."""
        law = fabric.friction_law
        return limit(R, law[0], law[1], law[2])

    @wp.func
    def huber_force(s: vec, bound: scalar, stick: scalar) -> vec:
        """-dH/ds [N]: -k_t s sticking (k_t |s| <= F_T), -F_T s / |s| sliding."""
        trial = -stick * s
        size = wp.length(trial)
        if size > bound:
            trial = trial * (bound / size)
        return trial

    @wp.func
    def huber_energy(s: vec, bound: scalar, stick: scalar) -> scalar:
        """H(s) [J]: k_t |s|^2 / 2 sticking, F_T |s| - F_T^2 / (2 k_t) sliding (0 if k_t = 0)."""
        energy = scalar(0.0)
        if stick > scalar(0.0):
            size = wp.length(s)
            if stick * size <= bound:
                energy = scalar(0.5) * stick * size * size
            else:
                energy = bound * size - bound * bound / (scalar(2.0) * stick)
        return energy

    @wp.func
    def crossing_friction(pos: wp.array(dtype=vec), fabric: Fabric, anchors: wp.array(dtype=vec),
                          c: int, R: scalar, shift: vec) -> vec:
        """Friction force [N] of crossing c: (on the warp node along x, on the weft node along y)."""
        return huber_force(slip(pos, fabric, anchors, c, shift), friction_limit(R, fabric),
                           fabric.friction_law[3])

    @wp.func
    def segment_pull(pos: wp.array(dtype=vec), fabric: Fabric, i: int) -> vec:
        """k (l - l0) e / l [N] of segment (i, next i), e = r_next - r_i: the force on node i."""
        e = pos[fabric.next[i]] - pos[i]
        length = wp.length(e)
        return (fabric.stretch_stiffness[i] * (length - fabric.rest_length[i]) / length) * e

    @wp.func
    def turning_angle(a: vec, b: vec) -> scalar:
        """phi [rad] from segment a to segment b."""
        return wp.atan2(a[0] * b[1] - a[1] * b[0], wp.dot(a, b))

    @wp.func
    def bend_moment(pos: wp.array(dtype=vec), fabric: Fabric, m: int, a: vec, b: vec) -> scalar:
        """k (phi - phi0) [N m] of the bending spring at node m."""
        return fabric.bend_stiffness[m] * (turning_angle(a, b) - fabric.rest_angle[m])

    @wp.func
    def wrap_forces(pos: wp.array(dtype=vec), fabric: Fabric, first: int) -> mat:
        """(m g_a, m g_b) [N] of the wrap spring at node `first` (rows): r_{N-1} feels +m g_a,
        r_N -m g_a, r_1 -m g_b, r_0 +m g_b."""
        last = fabric.yarn_last[first]
        a = pos[last] - pos[last - 1]
        b = pos[first + 1] - pos[first]
        moment = fabric.wrap_stiffness[first] * (turning_angle(a, b) - fabric.wrap_rest_angle[first])
        ga = moment * vec(a[1], -a[0]) / wp.dot(a, a)
        gb = moment * vec(-b[1], b[0]) / wp.dot(b, b)
        return mat(ga[0], ga[1], gb[0], gb[1])

    @wp.func
    def plane_reaction(fabric: Fabric, friction: wp.array(dtype=vec), family: int) -> scalar:
        """-sum_c (w_c / n) f_c [N] along the yarn on each end node moving family `family`'s
        planes, in crossing order."""
        total = scalar(0.0)
        for c in range(fabric.crossing_warp.shape[0]):
            total += fabric.crossing_plane_weight[c][family] * friction[c][family]
        return -total

    @wp.func
    def own_force(i: int, pos: wp.array(dtype=vec), fabric: Fabric, contact: wp.array(dtype=scalar),
                  friction: wp.array(dtype=vec), external: wp.array(dtype=vec)) -> vec:
        """-dV/dr_i [N] of node i alone, unmasked, but for the planes' reaction: its chain,
        its crossing, the wrap spring."""
        before = fabric.previous[i]
        after = fabric.next[i]
        force = external[i]
        if after >= 0:
            force = force + segment_pull(pos, fabric, i)
        if before >= 0:
            force = force - segment_pull(pos, fabric, before)
        if before >= 0 and after >= 0:  # spring at i: -m g_a + m g_b
            a = pos[i] - pos[before]
            b = pos[after] - pos[i]
            moment = bend_moment(pos, fabric, i, a, b)
            force = force + moment * (vec(-a[1], a[0]) / wp.dot(a, a) + vec(-b[1], b[0]) / wp.dot(b, b))
        if before >= 0:
            earlier = fabric.previous[before]
            if earlier >= 0:  # spring at i-1, node i is its third: -m g_b
                a = pos[before] - pos[earlier]
                b = pos[i] - pos[before]
                moment = bend_moment(pos, fabric, before, a, b)
                force = force - moment * vec(-b[1], b[0]) / wp.dot(b, b)
        if after >= 0:
            later = fabric.next[after]
            if later >= 0:  # spring at i+1, node i is its first: +m g_a
                a = pos[after] - pos[i]
                b = pos[later] - pos[after]
                moment = bend_moment(pos, fabric, after, a, b)
                force = force + moment * vec(a[1], -a[0]) / wp.dot(a, a)
        c = fabric.node_crossing[i]
        if c >= 0:
            force = force + vec(scalar(0.0), fabric.node_side[i] * contact[c])
            if wp.static(has_friction):
                along = friction[c][1]
                if fabric.crossing_warp[c] == i:
                    along = friction[c][0]
                force = force + vec(along, scalar(0.0))
        first = fabric.node_wrap[i]
        if first >= 0:  # one of the four nodes of its yarn's wrap spring
            last = fabric.yarn_last[first]
            g = wrap_forces(pos, fabric, first)
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
    def node_force(i: int, pos: wp.array(dtype=vec), fabric: Fabric, contact: wp.array(dtype=scalar),
                   friction: wp.array(dtype=vec), external: wp.array(dtype=vec)) -> vec:
        """-dV/dr_i [N] on the free dofs of node i, gathered from its chain and its crossing,
        and on an end node moving the planes their reaction; on a tied end node, the family's
        summed force: its n members' own forces and n times the reaction (module docstring)."""
        family = fabric.node_tie[i]
        force = vec(scalar(0.0), scalar(0.0))
        members = scalar(1.0)
        if family >= 0:
            for m in range(fabric.plane_offsets[family], fabric.plane_offsets[family + 1]):
                force = force + own_force(fabric.plane_nodes[m], pos, fabric, contact, friction,
                                          external)
            members = scalar(fabric.plane_offsets[family + 1] - fabric.plane_offsets[family])
        else:
            force = own_force(i, pos, fabric, contact, friction, external)
        if wp.static(has_friction):
            plane = fabric.node_plane[i]
            if plane >= 0:
                force = force + vec(members * plane_reaction(fabric, friction, plane), scalar(0.0))
        return wp.cw_mul(force, fabric.free[i])

    @wp.func
    def node_energy(i: int, pos: wp.array(dtype=vec), fabric: Fabric,
                    external: wp.array(dtype=vec)) -> scalar:
        """Energy [J] owned by node i: its segment (i, next), its bending spring, minus the
        work of its external force. Crossings own their contact energy."""
        energy = -wp.dot(external[i], pos[i] - fabric.rest_position[i])
        before = fabric.previous[i]
        after = fabric.next[i]
        if after >= 0:
            stretch = wp.length(pos[after] - pos[i]) - fabric.rest_length[i]
            energy += scalar(0.5) * fabric.stretch_stiffness[i] * stretch * stretch
        if before >= 0 and after >= 0:
            turn = turning_angle(pos[i] - pos[before], pos[after] - pos[i]) - fabric.rest_angle[i]
            energy += scalar(0.5) * fabric.bend_stiffness[i] * turn * turn
        if fabric.wrap_stiffness[i] > scalar(0.0):  # node 0 of a periodic yarn: its wrap spring
            last = fabric.yarn_last[i]
            turn = turning_angle(pos[last] - pos[last - 1], pos[i + 1] - pos[i]) - fabric.wrap_rest_angle[i]
            energy += scalar(0.5) * fabric.wrap_stiffness[i] * turn * turn
        return energy

    @wp.func
    def scatter_forces(pos: wp.array(dtype=vec), fabric: Fabric, anchors: wp.array(dtype=vec),
                       contact: wp.array(dtype=scalar), friction: wp.array(dtype=vec),
                       external: wp.array(dtype=vec), force: wp.array(dtype=vec)):
        """force = -dV/dr [N] on the free dofs, every term evaluated once and scattered to its
        nodes (one thread: the single-threaded layout's cheaper order of the same sums);
        contact[c] = R [N] and friction[c] of every crossing."""
        for i in range(pos.shape[0]):
            force[i] = external[i]
        for i in range(pos.shape[0]):
            j = fabric.next[i]
            if j >= 0:  # segment (i, j), then the bending spring at j
                pull = segment_pull(pos, fabric, i)
                force[i] = force[i] + pull
                force[j] = force[j] - pull
                k = fabric.next[j]
                if k >= 0:
                    a = pos[j] - pos[i]
                    b = pos[k] - pos[j]
                    moment = bend_moment(pos, fabric, j, a, b)
                    ga = moment * vec(a[1], -a[0]) / wp.dot(a, a)
                    gb = moment * vec(-b[1], b[0]) / wp.dot(b, b)
                    force[i] = force[i] + ga
                    force[j] = force[j] - ga + gb
                    force[k] = force[k] - gb
        for m in range(fabric.plane_nodes.shape[0]):  # wrap springs: periodic yarns' ends move planes
            last = fabric.plane_nodes[m]
            first = fabric.node_wrap[last]
            if first >= 0:
                g = wrap_forces(pos, fabric, first)
                force[last - 1] = force[last - 1] + vec(g[0, 0], g[0, 1])
                force[last] = force[last] - vec(g[0, 0], g[0, 1])
                force[first + 1] = force[first + 1] - vec(g[1, 0], g[1, 1])
                force[first] = force[first] + vec(g[1, 0], g[1, 1])
        shift = plane_shift(pos, fabric)
        reaction = vec(scalar(0.0), scalar(0.0))
        for c in range(contact.shape[0]):
            R = contact_force(closure(pos, fabric, c), fabric.contact_law)
            contact[c] = R
            up = vec(scalar(0.0), fabric.crossing_side[c] * R)
            force[fabric.crossing_warp[c]] = force[fabric.crossing_warp[c]] + up
            force[fabric.crossing_weft[c]] = force[fabric.crossing_weft[c]] - up
            if wp.static(has_friction):
                drag = crossing_friction(pos, fabric, anchors, c, R, shift)
                friction[c] = drag
                force[fabric.crossing_warp[c]] = force[fabric.crossing_warp[c]] + vec(drag[0], scalar(0.0))
                force[fabric.crossing_weft[c]] = force[fabric.crossing_weft[c]] + vec(drag[1], scalar(0.0))
                reaction = reaction - wp.cw_mul(fabric.crossing_plane_weight[c], drag)
        for family in range(2):  # the planes' reaction, then a tied family's summed force
            begin = fabric.plane_offsets[family]
            end = fabric.plane_offsets[family + 1]
            for m in range(begin, end):
                node = fabric.plane_nodes[m]
                force[node] = force[node] + vec(reaction[family], scalar(0.0))
            if end > begin:
                if fabric.node_tie[fabric.plane_nodes[begin]] >= 0:
                    total = vec(scalar(0.0), scalar(0.0))
                    for m in range(begin, end):
                        total = total + force[fabric.plane_nodes[m]]
                    for m in range(begin, end):
                        force[fabric.plane_nodes[m]] = total
        for i in range(pos.shape[0]):
            force[i] = wp.cw_mul(force[i], fabric.free[i])

    @wp.func
    def crossing_pass_at(pos: wp.array(dtype=vec), fabric: Fabric, anchors: wp.array(dtype=vec),
                         contact: wp.array(dtype=scalar), friction: wp.array(dtype=vec), c: int,
                         shift: vec):
        """`crossing_pass` with the planes' `plane_shift` given."""
        R = contact_force(closure(pos, fabric, c), fabric.contact_law)
        contact[c] = R
        if wp.static(has_friction):
            friction[c] = crossing_friction(pos, fabric, anchors, c, R, shift)

    @wp.func
    def crossing_pass(pos: wp.array(dtype=vec), fabric: Fabric, anchors: wp.array(dtype=vec),
                      contact: wp.array(dtype=scalar), friction: wp.array(dtype=vec), c: int):
        """contact[c] = R [N] and (with friction) friction[c] [N] of crossing c (the planes'
        shift summed by this thread: `crossing_pass_at` with a shift computed once)."""
        crossing_pass_at(pos, fabric, anchors, contact, friction, c, plane_shift(pos, fabric))

    @wp.func
    def crossing_energy(pos: wp.array(dtype=vec), fabric: Fabric, anchors: wp.array(dtype=vec),
                        c: int) -> scalar:
        """Contact energy [J] of crossing c, plus its Huber term with F_T at the current R."""
        R = contact_force(closure(pos, fabric, c), fabric.contact_law)
        energy = contact_energy(R, fabric.contact_law)
        if wp.static(has_friction):
            energy += huber_energy(slip(pos, fabric, anchors, c, plane_shift(pos, fabric)),
                                   friction_limit(R, fabric),
                                   fabric.friction_law[3])
        return energy

    @wp.func
    def return_map(pos: wp.array(dtype=vec), fabric: Fabric, anchors: wp.array(dtype=vec), c: int):
        """Radial return of anchor c after a converged step: where k_t |s| > F_T, xi moves
        along s until k_t |s| = F_T (docs/model.md sections 4, 10)."""
        R = contact_force(closure(pos, fabric, c), fabric.contact_law)
        bound = friction_limit(R, fabric)
        stick = fabric.friction_law[3]
        s = slip(pos, fabric, anchors, c, plane_shift(pos, fabric))
        size = wp.length(s)
        if stick * size > bound:
            anchors[c] = anchors[c] + (scalar(1.0) - bound / (stick * size)) * s

    return SimpleNamespace(closure=closure, contact_force=contact_force, crossing_pass=crossing_pass,
                           crossing_pass_at=crossing_pass_at, plane_shift=plane_shift,
                           slip=slip, turning_angle=turning_angle,
                           crossing_energy=crossing_energy, return_map=return_map,
                           node_force=node_force, node_energy=node_energy,
                           scatter_forces=scatter_forces)


@functools.cache
def kernels(scalar, has_friction: bool) -> SimpleNamespace:
    """Kernels of one scalar type and term selection: the two force passes, the energy (tests),
    and the anchors' return map."""
    vec = VECTORS[scalar]
    Fabric = fabric_arrays.struct(scalar)
    ops = functions(scalar, has_friction)

    @wp.kernel(module="unique", module_options=MODULE_OPTIONS)
    def crossing_pass(pos: wp.array(dtype=vec), fabric: Fabric, anchors: wp.array(dtype=vec),
                      contact: wp.array(dtype=scalar), friction: wp.array(dtype=vec)):
        """R [N] (and friction [N]) of crossing c (one thread per crossing)."""
        ops.crossing_pass(pos, fabric, anchors, contact, friction, wp.tid())

    @wp.kernel(module="unique", module_options=MODULE_OPTIONS)
    def node_pass(pos: wp.array(dtype=vec), fabric: Fabric, contact: wp.array(dtype=scalar),
                  friction: wp.array(dtype=vec), external: wp.array(dtype=vec),
                  force: wp.array(dtype=vec)):
        """force[i] = -dV/dr_i (+ friction) [N] on the free dofs (one thread per node)."""
        i = wp.tid()
        force[i] = ops.node_force(i, pos, fabric, contact, friction, external)

    @wp.kernel(module="unique", module_options=MODULE_OPTIONS)
    def energy_pass(pos: wp.array(dtype=vec), fabric: Fabric, anchors: wp.array(dtype=vec),
                    external: wp.array(dtype=vec), node_energy: wp.array(dtype=scalar),
                    crossing_energy: wp.array(dtype=scalar)):
        """Per-node energy [J] (and, in the first C threads, per-crossing energy)."""
        i = wp.tid()
        node_energy[i] = ops.node_energy(i, pos, fabric, external)
        if i < crossing_energy.shape[0]:
            crossing_energy[i] = ops.crossing_energy(pos, fabric, anchors, i)

    @wp.kernel(module="unique", module_options=MODULE_OPTIONS)
    def return_map(pos: wp.array(dtype=vec), fabric: Fabric, anchors: wp.array(dtype=vec)):
        """Return-map every anchor (one thread per crossing)."""
        ops.return_map(pos, fabric, anchors, wp.tid())

    return SimpleNamespace(crossing_pass=crossing_pass, node_pass=node_pass, energy_pass=energy_pass,
                           return_map=return_map)
