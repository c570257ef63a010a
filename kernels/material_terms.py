"""What the elements of every kinematics read of the yarns' material, in a kernel: where the
crossings slide (docs/model.md 11.13) each node where it is and each segment's material now,
and the slides' material force; where they do not, the structure's constants.

- `physical`: node i where the elements see it, each coordinate from the dof
  `physical_source` names (a crossing's node on the plane it crosses, or a spatial crossing's
  node b at node a's x and y) or its rest position;
- `rest_length`: L = base + f (delta_R - delta_L) of a segment, delta its bay ends' slides
  (11.13a); `stretch_stiffness` EA / L; `bend_stiffness` and `lateral_bend_stiffness`
  EI / lbar, lbar = (L_{i-1} + L_i) / 2 (11.13b);
- `material_forces` (given a kinematics' bending energy at a node): dV/dL of a segment,
  EA (L^2 - l^2) / (2 L^2) plus -E_m / (2 lbar_m) from each of its two nodes' bendings, and a
  slide's material force -sum_k dV/dL_k dL_k/d delta over its two bays (dL/d delta = +f on
  the bay before the crossing, -f on the one after).
"""

import functools
from types import SimpleNamespace

import warp as wp

from dynfab.kernels import structure_arrays
from dynfab.kernels.precision import vector


@functools.cache
def functions(scalar, dim: int, sliding: bool) -> SimpleNamespace:
    """The material's `wp.func`s (module docstring) for one scalar type, `dim` coordinates
    per node, crossings that slide (`sliding_functions`) or not (`fixed_functions`): two
    sets, not one with static branches, so that a fixed crossings' kernel holds no code of
    the sliding ones (Warp compiles the code after an early static return)."""
    return (sliding_functions if sliding else fixed_functions)(scalar, dim)


@functools.cache
def fixed_functions(scalar, dim: int) -> SimpleNamespace:
    """`functions` where the crossings do not slide: the dofs and the structure's constants."""
    vec = vector(scalar, dim)
    Data = structure_arrays.struct(scalar, dim)

    @wp.func(inline=True)
    def physical(pos: wp.array(dtype=vec), data: Data, i: int) -> vec:
        """Node i [m]: its dofs."""
        return pos[i]

    @wp.func(inline=True)
    def rest_length(pos: wp.array(dtype=vec), data: Data, i: int) -> scalar:
        """l0 [m] of segment (i, next)."""
        return data.rest_length[i]

    @wp.func(inline=True)
    def stretch_stiffness(pos: wp.array(dtype=vec), data: Data, i: int, rest: scalar) -> scalar:
        """k [N/m] of segment (i, next)."""
        return data.stretch_stiffness[i]

    @wp.func(inline=True)
    def bend_stiffness(pos: wp.array(dtype=vec), data: Data, m: int) -> scalar:
        """k_b [N m] of the bending spring (out of the plane, in space) at node m."""
        return data.bend_stiffness[m]

    @wp.func(inline=True)
    def lateral_bend_stiffness(pos: wp.array(dtype=vec), data: Data, m: int) -> scalar:
        """k_l [N m] of the in-plane bending spring at node m (space only)."""
        return data.lateral_bend_stiffness[m]

    return SimpleNamespace(physical=physical, rest_length=rest_length,
                           stretch_stiffness=stretch_stiffness, bend_stiffness=bend_stiffness,
                           lateral_bend_stiffness=lateral_bend_stiffness, sliding=False, dim=dim)


@functools.cache
def plane_shift(scalar, dim: int):
    """`family_shift(pos, data, family)`: the summed displacement along their chains of the
    plane nodes of `family` [m] (`StructureArrays.plane_nodes`; docs/model.md section 10), in
    plane-node order: what moves the planes of the fixed crossings' slips and the sliding
    crossings' nodes held on them."""
    vec = vector(scalar, dim)
    Data = structure_arrays.struct(scalar, dim)

    @wp.func
    def family_shift(pos: wp.array(dtype=vec), data: Data, family: int) -> scalar:
        """The summed displacement of the plane nodes of `family` [m]."""
        total = scalar(0.0)
        for m in range(data.plane_offsets[family], data.plane_offsets[family + 1]):
            node = data.plane_nodes[m]
            total += pos[node][0] - data.rest_position[node][0]
        return total

    return family_shift


@functools.cache
def sliding_functions(scalar, dim: int) -> SimpleNamespace:
    """`functions` where the crossings slide: each node where it is, each segment's material
    now (module docstring)."""
    vec = vector(scalar, dim)
    Data = structure_arrays.struct(scalar, dim)

    family_shift = plane_shift(scalar, dim)

    @wp.func(inline=True)
    def physical(pos: wp.array(dtype=vec), data: Data, i: int) -> vec:
        """Node i where the elements see it [m]: each coordinate from the dof
        `data.physical_source` names (its rest position for -1: a crossing's node on the
        plane it crosses, moved with that plane where it moves)."""
        out = vec()
        for c in range(wp.static(dim)):
            source = data.physical_source[i, c]
            if source < 0:
                out[c] = data.rest_position[i][c]
                family = data.physical_plane[i, c]
                if family >= 0:  # on a moving plane: X + w U (docs/model.md 11.13)
                    out[c] += data.physical_plane_weight[i, c] * family_shift(pos, data, family)
            else:
                out[c] = pos[source // wp.static(dim)][source % wp.static(dim)]
        return out

    @wp.func(inline=True)
    def dof(pos: wp.array(dtype=vec), flat: int) -> scalar:
        """The value of flat dof `flat` [m]."""
        return pos[flat // wp.static(dim)][flat % wp.static(dim)]

    @wp.func(inline=True)
    def slide(pos: wp.array(dtype=vec), data: Data, t: int, side: int) -> scalar:
        """delta [m] of tie t along node a's chain (side 0) or node b's (side 1), from the dof
        `data.tie_slide` names."""
        return dof(pos, data.tie_slide[t, side])

    @wp.func(inline=True)
    def bay_end(pos: wp.array(dtype=vec), data: Data, i: int, side: int) -> scalar:
        """The slide delta [m] at side 0 (left) or 1 (right) of segment (i, next)'s bay."""
        source = data.segment_material[i, side]
        value = data.segment_material_end[i, side]
        if source >= 0:
            value = dof(pos, source)
        return value

    @wp.func(inline=True)
    def rest_length(pos: wp.array(dtype=vec), data: Data, i: int) -> scalar:
        """L = base + f (delta_R - delta_L) [m] of segment (i, next) (11.13a)."""
        return data.segment_base[i] + data.segment_fraction[i] * (
            bay_end(pos, data, i, 1) - bay_end(pos, data, i, 0))

    @wp.func(inline=True)
    def stretch_stiffness(pos: wp.array(dtype=vec), data: Data, i: int, rest: scalar) -> scalar:
        """EA / L [N/m] of segment (i, next) of rest length `rest` (0 for a retired segment,
        EA = 0, whatever its L)."""
        k = scalar(0.0)
        if data.stretch_modulus[i] != scalar(0.0):
            k = data.stretch_modulus[i] / rest
        return k

    @wp.func(inline=True)
    def mean_length(pos: wp.array(dtype=vec), data: Data, m: int) -> scalar:
        """lbar_m = (L_{m-1} + L_m) / 2 [m] at inner node m, the material's now (11.13b)."""
        return scalar(0.5) * (rest_length(pos, data, data.previous[m])
                              + rest_length(pos, data, m))

    @wp.func(inline=True)
    def over_mean_length(pos: wp.array(dtype=vec), data: Data, m: int, modulus: scalar) -> scalar:
        """modulus / lbar_m [N m] at inner node m, 0 where the modulus is (11.13b)."""
        k = scalar(0.0)
        if modulus != scalar(0.0):
            k = modulus / mean_length(pos, data, m)
        return k

    @wp.func(inline=True)
    def bend_stiffness(pos: wp.array(dtype=vec), data: Data, m: int) -> scalar:
        """EI / lbar [N m] of the bending spring (out of the plane, in space) at inner node m,
        the material's lbar now (11.13b)."""
        return over_mean_length(pos, data, m, data.bend_modulus[m])

    @wp.func(inline=True)
    def lateral_bend_stiffness(pos: wp.array(dtype=vec), data: Data, m: int) -> scalar:
        """EI_lateral / lbar [N m] of the in-plane bending spring at inner node m (space
        only), as `bend_stiffness`."""
        return over_mean_length(pos, data, m, data.lateral_bend_modulus[m])

    return SimpleNamespace(physical=physical, dof=dof, slide=slide, rest_length=rest_length,
                           stretch_stiffness=stretch_stiffness, mean_length=mean_length,
                           bend_stiffness=bend_stiffness,
                           lateral_bend_stiffness=lateral_bend_stiffness, sliding=True, dim=dim)


def material_forces(scalar, dim: int, node_bend_energy, wrap_on_length=None) -> SimpleNamespace:
    """`on_length` and `material_force` (module docstring) of crossings that slide, on a
    kinematics' `node_bend_energy(pos, data, m)` (its bending energy E_m [J] at node m, 0 at a
    chain's ends) and `wrap_on_length(pos, data, k)` (what a periodic chain's wrap spring adds
    to dV/dL_k [N]; none where None)."""
    vec = vector(scalar, dim)
    Data = structure_arrays.struct(scalar, dim)
    own = sliding_functions(scalar, dim)
    P = own.physical  # noqa: N806 (node i where the elements see it)
    wraps = wrap_on_length is not None

    @wp.func(inline=True)
    def bend_on_length(pos: wp.array(dtype=vec), data: Data, m: int) -> scalar:
        """1/2 dE_m/dlbar_m = -E_m / (2 lbar_m) [N]: what node m's bending adds to dE/dL of each
        of its two segments (11.13b)."""
        energy = node_bend_energy(pos, data, m)
        value = scalar(0.0)
        if energy != scalar(0.0):
            value = -scalar(0.5) * energy / own.mean_length(pos, data, m)
        return value

    @wp.func(inline=True)
    def on_length(pos: wp.array(dtype=vec), data: Data, k: int) -> scalar:
        """dV/dL_k [N] of segment (k, next): its stretch's EA (L^2 - l^2) / (2 L^2) (11.13a) and
        its two nodes' bendings' (`bend_on_length`)."""
        after = data.next[k]
        rest = own.rest_length(pos, data, k)
        value = scalar(0.0)
        if data.stretch_modulus[k] != scalar(0.0):
            length = wp.length(P(pos, data, after) - P(pos, data, k))
            value = scalar(0.5) * data.stretch_modulus[k] * (rest * rest - length * length) \
                / (rest * rest)
        value = value + bend_on_length(pos, data, k) + bend_on_length(pos, data, after)
        if wp.static(wraps):
            value += wrap_on_length(pos, data, k)
        return value

    @wp.func(inline=True)
    def material_force(pos: wp.array(dtype=vec), data: Data, i: int, slot: int) -> scalar:
        """-dV/d delta [N] of the slide in flat dof `slot`, its elastic part, over the
        segments of its two bays on the chain of node i, the crossing's node on it (module
        docstring)."""
        total = scalar(0.0)
        k = data.previous[i]
        while k >= 0:
            if data.segment_material[k, 1] != slot:
                break
            total -= data.segment_fraction[k] * on_length(pos, data, k)
            k = data.previous[k]
        k = i
        while data.next[k] >= 0:
            if data.segment_material[k, 0] != slot:
                break
            total += data.segment_fraction[k] * on_length(pos, data, k)
            k = data.next[k]
        return total

    return SimpleNamespace(on_length=on_length, material_force=material_force)
