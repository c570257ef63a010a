"""Nodal forces and energy of any structure in a kernel (docs/model.md sections 2-4, 10, 11).

What every kinematics shares is written here once (`base`; f = -dV/dr):
- stretch, E = 1/2 (EA / l0)(l - l0)^2 per segment: the pull k (l - l0) e / l on the segment's
  first node, its opposite on the second (e from the first to the second);
- each tie's contact (`tie_law`): +sigma R along z on node a, -sigma R on node b, R from the
  closure g = c - sigma (z_a - z_b), and F_T from R where friction is compiled in;
- the external force: the end loads given per node (`StructureState.load`) plus gravity on
  the physical masses (`StructureArrays.weight`), work -f . (r - r0); and each node's node
  terms (`node_terms`: energies of a node alone, as a spring to its as-woven place);
- held dofs carry no force.

The elements of each kinematics, one module each, give the rest in one form
(`plane_shift`, `tie_pass_at`, `node_force`, `scatter`, `add_node_energy`,
`add_tie_energy`, `lateral_energy`, `return_anchor`): `planar_terms` (bending on turning
angles, the 2-D friction on the planes, wrap springs, moving planes, tied families) and
`spatial_terms` (bending in two planes, each crossing's three-component friction and rotation
spring on its six-node stencil, the lateral contacts). `KINDS` picks the module from the variant's
kinematics; nothing below asks which it is.

Two orders of the same sums. Gather (`tie_pass` per tie, then `node_force` per node: every
thread writes only its own slots, no atomics; an element is evaluated at every node of its
stencil): the node-parallel layout, bit for bit repeatable on any device, and the grouped
layout's "gather" order (the same bits). Scatter (`scatter_init`, `scatter_terms`, one
thread for a group: each element once, added to its nodes; the caller masks the held dofs):
the grouped layout's default, within rounding of the gather order.

Variants: `friction` compiles the friction terms (without, F_T = 0 is never evaluated);
`boundary` the moving planes, wrap springs and tied families; `kinematics` the element
module.
"""

import functools
from types import SimpleNamespace

import warp as wp

from dynfab.kernels import material_terms, node_terms, planar_terms, sliding_terms
from dynfab.kernels import spatial_terms
from dynfab.kernels import structure_arrays
from dynfab.kernels import structure_state, tie_law
from dynfab.kernels.precision import KINEMATICS, vector

KINDS = {"planar": planar_terms, "spatial": spatial_terms, "planar_sliding": sliding_terms,
         "spatial_sliding": sliding_terms}
"""The element module of each kinematics (module docstring)."""


@functools.cache
def base(scalar, friction: bool, dim: int, sliding: bool = False) -> SimpleNamespace:
    """The `wp.func`s every kinematics shares (module docstring); with `sliding`, the elements
    see each node where it is and each segment's material now (`material`, the
    `material_terms` of the variant: docs/model.md 11.13a)."""
    vec = vector(scalar, dim)
    Data = structure_arrays.struct(scalar, dim)
    State = structure_state.struct(scalar, dim)
    laws = tie_law.functions(scalar)
    node = node_terms.functions(scalar, dim)
    material = material_terms.functions(scalar, dim, sliding)
    physical, rest_length = material.physical, material.rest_length
    stretch_stiffness = material.stretch_stiffness
    Z = dim - 1  # the coordinate along the fabric's normal

    @wp.func(inline=True)
    def along_z(value: scalar) -> vec:
        """(0, .., value) [N]: a force along z."""
        result = vec()
        result[wp.static(Z)] = value
        return result

    @wp.func(inline=True)
    def segment_pull(pos: wp.array(dtype=vec), data: Data, i: int) -> vec:
        """k (l - l0) e / l [N] of segment (i, next): the force on node i."""
        e = physical(pos, data, data.next[i]) - physical(pos, data, i)
        length = wp.length(e)
        rest = rest_length(pos, data, i)
        return (stretch_stiffness(pos, data, i, rest) * (length - rest) / length) * e

    @wp.func(inline=True)
    def closure(pos: wp.array(dtype=vec), data: Data, t: int) -> scalar:
        """g = c - sigma (z_a - z_b) [m] of tie t, z_b = 0 for ground."""
        b = data.tie_b[t]
        z_b = scalar(0.0)
        if b >= 0:
            z_b = pos[b][wp.static(Z)]
        return data.tie_offset[t] - data.tie_side[t] * (pos[data.tie_a[t]][wp.static(Z)] - z_b)

    @wp.func(inline=True)
    def external(i: int, pos: wp.array(dtype=vec), data: Data, state: State) -> vec:
        """The force on node i that is its own [N]: its end load and weight, and the node
        terms' (`node_terms`)."""
        force = state.load[i] + data.weight[i]
        if wp.static(node.count > 0):
            force = force + node.force(i, pos, data)
        return force

    @wp.func(inline=True)
    def own_and_stretch(i: int, pos: wp.array(dtype=vec), data: Data, state: State) -> vec:
        """Node i's own force (`external`) and its segments' pulls [N]: where the gather of
        every kinematics starts."""
        force = external(i, pos, data, state)
        if data.next[i] >= 0:
            force = force + segment_pull(pos, data, i)
        if data.previous[i] >= 0:
            force = force - segment_pull(pos, data, data.previous[i])
        return force

    @wp.func(inline=True)
    def contact_pass(t: int, pos: wp.array(dtype=vec), data: Data, state: State) -> scalar:
        """R and dR/dg of tie t into the state, and F_T (into the state and returned) where
        friction is compiled in; 0 otherwise."""
        at_g = laws.contact(closure(pos, data, t), data.contact_law, t)
        state.contact[t] = at_g[0]
        state.tangent[t] = at_g[1]
        bound = scalar(0.0)
        if wp.static(friction):
            bound = laws.limit(at_g[0], data.friction_law, t)
            state.limit[t] = bound
        return bound

    return SimpleNamespace(along_z=along_z, segment_pull=segment_pull, closure=closure,
                           external=external, own_and_stretch=own_and_stretch,
                           contact_pass=contact_pass, node=node, sliding=sliding, dim=dim,
                           material=material, physical=physical, rest_length=rest_length,
                           stretch_stiffness=stretch_stiffness)


@functools.cache
def functions(scalar, friction: bool, boundary: bool,
              kinematics: str = "planar") -> SimpleNamespace:
    """The force and energy `wp.func`s of one variant (module docstring): `base`'s, the
    kinematics' element module's, and the passes built on them."""
    dim = KINEMATICS[kinematics]
    vec = vector(scalar, dim)
    Data = structure_arrays.struct(scalar, dim)
    State = structure_state.struct(scalar, dim)
    laws = tie_law.functions(scalar)
    shared = base(scalar, friction, dim, kinematics.endswith("_sliding"))
    kind = KINDS[kinematics].structure_terms(scalar, friction, boundary, shared)

    @wp.func(inline=True)
    def tie_pass(t: int, pos: wp.array(dtype=vec), data: Data, state: State):
        """R, dR/dg, F_T and the friction force of tie t into the state, the planes' shift
        summed by this thread."""
        kind.tie_pass_at(t, pos, data, state, kind.plane_shift(pos, data))

    @wp.func(inline=True)
    def node_force(i: int, pos: wp.array(dtype=vec), data: Data, state: State) -> vec:
        """-dV/dr_i [N] on node i's free dofs, gathered (module docstring)."""
        return wp.cw_mul(kind.node_force(i, pos, data, state), data.free[i])

    @wp.func(inline=True)
    def scatter_init(group: int, data: Data, state: State):
        """state.force = the external force on the group's nodes (the scatter's start)."""
        for i in range(data.group_node[group], data.group_node[group + 1]):
            state.force[i] = shared.external(i, state.position, data, state)

    @wp.func(inline=True)
    def scatter_terms(group: int, pos: wp.array(dtype=vec), data: Data, state: State):
        """state.force += -dV/dr [N] of every element on the group's nodes (and every tie's R,
        dR/dg, F_T, friction force), each element evaluated once and added to its nodes
        (module docstring), unmasked: after `scatter_init`; the held dofs are masked by the
        caller."""
        kind.scatter(group, pos, data, state)

    @wp.func(inline=True)
    def node_energy(i: int, pos: wp.array(dtype=vec), data: Data, state: State) -> scalar:
        """Energy [J] owned by node i: its segment (i, next), its bending spring (and wrap
        spring at a chain's first node), minus the work of its external force."""
        external = state.load[i] + data.weight[i]
        here = shared.physical(pos, data, i)
        energy = -wp.dot(external, here - data.rest_position[i])
        if wp.static(shared.node.count > 0):
            energy += shared.node.energy(i, pos, data)
        after = data.next[i]
        if after >= 0:
            rest = shared.rest_length(pos, data, i)
            stretch = wp.length(shared.physical(pos, data, after) - here) - rest
            energy += scalar(0.5) * shared.stretch_stiffness(pos, data, i, rest) \
                * stretch * stretch
        return kind.add_node_energy(i, pos, data, energy)

    @wp.func(inline=True)
    def tie_energy(t: int, pos: wp.array(dtype=vec), data: Data, state: State) -> scalar:
        """Contact energy [J] of tie t, plus its kinematics' tie terms (the Huber term with
        F_T at the current R; spatial: the rotation spring)."""
        R = laws.contact(shared.closure(pos, data, t), data.contact_law, t)[0]
        return kind.add_tie_energy(t, pos, data, state, R,
                                   laws.contact_energy(R, data.contact_law, t))

    @wp.func(inline=True)
    def return_map(t: int, pos: wp.array(dtype=vec), data: Data, state: State) -> scalar:
        """Radial return of tie t's anchor at `pos` (docs/model.md sections 4, 10, 11.4):
        where k_t |s| > F_T the anchor moves along s until k_t |s| = F_T; the energy
        dissipated F_T |delta xi| [J]."""
        lost = scalar(0.0)
        if wp.static(friction):
            R = laws.contact(shared.closure(pos, data, t), data.contact_law, t)[0]
            lost = kind.return_anchor(t, pos, data, state, laws.limit(R, data.friction_law, t))
        return lost

    return SimpleNamespace(**{**vars(shared), **vars(kind), **dict(
        tie_pass=tie_pass, node_force=node_force, scatter_init=scatter_init,
        scatter_terms=scatter_terms, node_energy=node_energy, tie_energy=tie_energy,
        return_map=return_map)})
