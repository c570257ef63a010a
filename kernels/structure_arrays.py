"""Any `dynfab.model.structure.Structure` as flat arrays for the Warp kernels: per node, per tie,
per chain, and the groups and blocks the two layouts run on (docs/model.md sections 2-5, 10).

Every node of every chain is one entry of one flat array, in the structure's order (chain after
chain). A node knows its chain neighbours (`previous`, `next`, -1 past an end), so a thread can
gather its own stretch and bending forces, and its incident ties (`node_tie_start`,
`node_ties`: a CSR list, in tie order), so it can gather their contact and friction forces.
Per node, the segment (node, next) carries its rest length and stiffness (0 at a last node).

Ties (docs/model.md sections 3, 4, 10): tie t joins node a to node b, or to ground (b = -1:
the closure with z_b = 0, its forces on node a only, its slip along node a's chain alone, from
plane 0: the anchor is a position). Each tie has its own contact law (T, 5) = (k_s, C_a, a_a,
C_b, a_b) and friction law (T, 4) = (alpha, beta ell r_f, R_0, k_t). The slip of tie t is
s = (x_a - X_t - w_a U_a - xi_x, y_b - Y_t - w_b U_b - xi_y), (X_t, Y_t) = `tie_plane`, U_f the
summed end displacements of the plane nodes of family f (0: those moving the a slips' planes,
1: the b slips'), w_f = `tie_plane_weight` / the family's node count; anchors xi in the
structure's convention (from the planes).

The boundary couplings (docs/model.md section 10): moving planes (`plane_nodes` split at `plane_offsets`, `node_plane`), wrap springs
(`node_wrap`, `chain_last`, `wrap_stiffness` and `wrap_rest_angle` at each chain's first
node), and tied dofs: a family's plane nodes whose in-plane dofs move as one (`node_tie`, the
periodic cell's length under force control); other dof ties are refused.

Groups: the chains split into connected groups, chains joined by ties, tied dofs, the planes
(every chain with a plane node or a tie whose slip the planes move) or a wrap, widened to
contiguous ranges of chains whose ties are contiguous too (a one-yarn [sweep] of 64 yarns is
64 groups, a fabric patch one). A group converges and stops on its own. Blocks: each group's
nodes cut into runs of at most BLOCK nodes; a sum over a group's nodes is the sum over its
blocks of each block's sum in node order, in both layouts (the same bits).
"""


import functools
from dataclasses import dataclass, field

import numpy as np
import warp as wp

from dynfab.kernels.precision import numpy_dtype, vector
from dynfab.model.fabric.sliding import moving_planes
from dynfab.model.structure import GROUND, Structure, chain_count, chain_of_node
from dynfab.model.terms import nodes

BLOCK = 256
"""Nodes per block of a group's sums (module docstring)."""


@dataclass
class StructureArrays:
    """The numpy arrays of a structure for the kernels (float64; indices int32).
    n nodes, T ties, Y chains, G groups, B blocks."""

    rest_position: np.ndarray
    """(n, 2) stress-free (along the chain, z) [m]."""
    previous: np.ndarray
    """(n,) chain neighbour before the node, -1 at a first node."""
    next: np.ndarray
    """(n,) chain neighbour after the node, -1 at a last node."""
    rest_length: np.ndarray
    """(n,) l0 of segment (node, next) [m]; 0 at a last node."""
    stretch_stiffness: np.ndarray
    """(n,) EA / l0 of segment (node, next) [N/m]; 0 at a last node."""
    bend_stiffness: np.ndarray
    """(n,) EI / lbar [N m]; 0 at the end nodes."""
    rest_angle: np.ndarray
    """(n,) rest turning angle phi0 [rad]."""
    free: np.ndarray
    """(n, 2) 1 for a free dof, 0 for a held one."""
    mass: np.ndarray
    """(n,) physical masses rho_l lbar [kg] (docs/model.md (5.1))."""
    weight: np.ndarray
    """(n, 2) gravity's constant force (0, -m g) [N] (docs/model.md (2.6)); zeros without it."""
    load_direction: np.ndarray
    """(n, 2) each chain's load factor on its last node's coordinate 0 [-]."""
    load_family: np.ndarray
    """(n,) the family whose load value drives the node (its chain's, at a load node), else -1."""
    node_chain: np.ndarray
    """(n,) the node's chain."""
    node_tie_start: np.ndarray
    """(n + 1,) node i's incident ties are node_ties[node_tie_start[i]:node_tie_start[i+1]]."""
    node_ties: np.ndarray
    """The incident ties of every node, in tie order."""
    chain_last: np.ndarray
    """(n,) the last node of the node's chain."""
    node_wrap: np.ndarray
    """(n,) first node of the chain whose wrap spring joins the node (N-1, N, 0, 1), else -1."""
    wrap_stiffness: np.ndarray
    """(n,) EI / lbar_0 of the wrap spring at each chain's first node [N m], 0 elsewhere."""
    wrap_rest_angle: np.ndarray
    """(n,) rest angle across the wrap at each chain's first node [rad]."""
    plane_nodes: np.ndarray
    """Plane nodes of family 0 then family 1 (module docstring)."""
    plane_offsets: np.ndarray
    """(3,) family f's plane nodes are plane_nodes[plane_offsets[f]:plane_offsets[f+1]]."""
    node_plane: np.ndarray
    """(n,) the plane family the node moves, -1 for none."""
    node_tie: np.ndarray
    """(n,) the family whose plane nodes' in-plane dofs move as one with this node's, -1."""
    share: np.ndarray
    """(n,) 1, or 1 / m on each of the m nodes of a tied family: one dof counted once."""
    tie_a: np.ndarray
    """(T,) node a."""
    tie_b: np.ndarray
    """(T,) node b, -1 for ground."""
    tie_side: np.ndarray
    """(T,) sigma [-]."""
    tie_offset: np.ndarray
    """(T,) c of g = c - sigma (z_a - z_b) [m]."""
    contact_law: np.ndarray
    """(T, 5) (k_s [N/m], C_a [m], a_a [1/N], C_b [m], a_b [1/N])."""
    friction_law: np.ndarray
    """(T, 4) (alpha [-], beta ell r_f [N], R_0 [N], k_t [N/m])."""
    tie_plane: np.ndarray
    """(T, 2) (X, Y) as woven [m]; 0 for ground ties."""
    tie_weight: np.ndarray
    """(T, 2) plane weights over the family's node count [-] (module docstring)."""
    chain_start: np.ndarray
    """(Y + 1,) first node of each chain, then n."""
    group_chain: np.ndarray
    """(G + 1,) group g holds chains group_chain[g]..group_chain[g+1]-1."""
    group_node: np.ndarray
    """(G + 1,) group g's nodes."""
    group_tie: np.ndarray
    """(G + 1,) group g's ties."""
    group_block: np.ndarray
    """(G + 1,) group g's blocks."""
    group_exact: np.ndarray
    """(G,) 1 where the group is one chain without couplings outside its band (its ties
    grounded, no wrap, planes or tied dofs): the banded preconditioner is its whole matrix."""
    block_start: np.ndarray
    """(B + 1,) block b holds nodes block_start[b]..block_start[b+1]-1."""
    node_group: np.ndarray
    """(n,) the node's group."""
    tie_group: np.ndarray
    """(T,) the tie's group."""
    chain_group: np.ndarray
    """(Y,) the chain's group."""
    block_group: np.ndarray
    """(B,) the block's group."""
    families: int
    """Load families (1 + the largest chain family)."""
    dim: int = 2
    """Coordinates per node: 2 planar (along the chain, z), 3 spatial (x, y, z; docs/model.md
    section 11): then every (n, 2) array above is (n, 3), the anchors (T, 3) and the spatial
    terms' arrays below are filled (a planar structure has none: empty)."""
    lateral_bend_stiffness: np.ndarray = field(default_factory=lambda: np.zeros(0))
    """spatial: (n,) EI_lateral / lbar [N m]; 0 at the end nodes."""
    lateral_rest_angle: np.ndarray = field(default_factory=lambda: np.zeros(0))
    """spatial: (n,) rest in-plane turning psi0 [rad]."""
    tie_stencil: np.ndarray = field(default_factory=lambda: np.zeros((0, 6), np.int64))
    """spatial: (T, 6) (a_prev, a, a_next, b_prev, b, b_next) of each crossing."""
    rotation_law: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    """spatial: (T, 3) (rho [m], K [N m/rad], phi_rest [rad]) of each crossing."""
    lateral_stencil: np.ndarray = field(default_factory=lambda: np.zeros((0, 4), np.int64))
    """spatial: (L, 4) (A_prev, A_next, A, B) of each lateral contact."""
    lateral_law: np.ndarray = field(default_factory=lambda: np.zeros((0, 6)))
    """spatial: (L, 6) (sign, width [m], k [N/m], A [N], s_a [m], s_core [m]) of each lateral
    contact (`dynfab.model.structure.Structure.lateral_law` without its branch)."""
    group_lateral: np.ndarray = field(default_factory=lambda: np.zeros(1, np.int64))
    """spatial: (G + 1,) group g's lateral contacts."""
    node_stencil_start: np.ndarray = field(default_factory=lambda: np.zeros(1, np.int64))
    """spatial: (n + 1,) node i's places in crossing stencils are
    node_stencil[node_stencil_start[i]:node_stencil_start[i+1]] (the gather order's CSR)."""
    node_stencil: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    """spatial: 6 t + slot for each crossing t whose stencil holds the node at `slot`, in
    crossing order."""
    node_lateral_start: np.ndarray = field(default_factory=lambda: np.zeros(1, np.int64))
    """spatial: (n + 1,) node i's places in lateral stencils, as `node_stencil_start`."""
    node_lateral: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    """spatial: 4 e + slot for each lateral contact e whose stencil holds the node at `slot`."""
    node_parameters: np.ndarray = field(default_factory=lambda: np.zeros((1, 1)))
    """(n, P) the node terms' parameters (`Structure.node_parameters`; (1, 1) zeros without
    any)."""
    node_term_first: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    """(K,) each registry node term's first column in `node_parameters`, -1 where the structure
    lacks it (`dynfab.model.terms.nodes.firsts`)."""
    physical_source: np.ndarray = field(default_factory=lambda: np.zeros((0, 2), np.int64))
    """sliding: (n, dim) the flat dof holding each coordinate the elements see, -1 for its
    rest position (`Structure.physical_source`, docs/model.md 11.13)."""
    node_slide: np.ndarray = field(default_factory=lambda: np.zeros((0, 2), np.int64))
    """sliding: (n, dim) where a dof holds a crossing's slide delta (its force the material's
    and the friction's), the crossing's node on the slide's chain (its bays the material
    force walks), else -1."""
    tie_slide: np.ndarray = field(default_factory=lambda: np.zeros((0, 2), np.int64))
    """sliding: (T, 2) the flat dofs of each tie's slides along node a's chain and node b's
    (`Structure.tie_material`)."""
    segment_material: np.ndarray = field(default_factory=lambda: np.zeros((0, 2), np.int64))
    """sliding: (n, 2) the flat dofs of the slides at segment (i, next)'s bay ends, -1 for a
    constant (`segment_material_end`)."""
    segment_material_end: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))
    """sliding: (n, 2) the constant slide [m] of a bay end no dof holds."""
    segment_fraction: np.ndarray = field(default_factory=lambda: np.zeros(0))
    """sliding: (n,) segment (i, next)'s share f of its bay [-]."""
    segment_base: np.ndarray = field(default_factory=lambda: np.zeros(0))
    """sliding: (n,) its rest length at no slide [m]: L = base + f (delta_R - delta_L)."""
    stretch_modulus: np.ndarray = field(default_factory=lambda: np.zeros(0))
    """sliding: (n,) EA [N] of segment (i, next)."""
    bend_modulus: np.ndarray = field(default_factory=lambda: np.zeros(0))
    """sliding: (n,) EI [N m^2] of node i's bending spring (0 at a chain's ends)."""
    lateral_bend_modulus: np.ndarray = field(default_factory=lambda: np.zeros(0))
    """sliding, spatial: (n,) EI_lateral [N m^2] of node i's in-plane bending spring."""
    physical_plane: np.ndarray = field(default_factory=lambda: np.zeros((0, 2), np.int64))
    """sliding: (n, dim) the plane family (0: the a slips', 1: the b slips') whose shift
    moves a coordinate a crossing holds on a moving plane, else -1
    (`dynfab.model.fabric.sliding.moving_planes`)."""
    physical_plane_weight: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))
    """sliding: (n, dim) w / (the family's plane nodes) [-] of such a coordinate: it lies at
    its rest position plus this times the family's summed shift."""

    @property
    def sliding(self) -> bool:
        """Its crossings slide (docs/model.md 11.13)."""
        return self.node_slide.size > 0

    @property
    def nodes(self) -> int:
        return self.rest_position.shape[0]

    @property
    def ties(self) -> int:
        return self.tie_a.shape[0]

    @property
    def chains(self) -> int:
        return self.chain_start.shape[0] - 1

    @property
    def groups(self) -> int:
        return self.group_chain.shape[0] - 1

    @property
    def blocks(self) -> int:
        return self.block_start.shape[0] - 1

    @property
    def laterals(self) -> int:
        return self.lateral_stencil.shape[0]

    @property
    def has_friction(self) -> bool:
        return bool(np.any(self.friction_law[:, 3] > 0.0))

    @property
    def has_boundary(self) -> bool:
        """Moving planes, wrap springs or tied dofs: the boundary couplings are compiled in."""
        return bool(self.plane_nodes.size or np.any(self.wrap_stiffness > 0.0)
                    or np.any(self.node_tie >= 0))


def build(structure: Structure) -> StructureArrays:
    """The arrays of `structure` (module docstring); a ValueError for what the kernels do not
    take: nodes with other than 2 or 3 coordinates, dof ties other than a family's plane
    nodes (a spatial structure with moving planes, wraps or tied dofs: the relaxation's)."""
    dim = structure.rest_position.shape[1]
    if dim not in (2, 3):
        raise ValueError("the kernels take 2 (planar) or 3 (spatial) coordinates per node")
    start = np.asarray(structure.chain_start, np.int64)
    n = int(start[-1])
    node_chain = chain_of_node(structure)
    first, last = start[:-1], start[1:] - 1
    index = np.arange(n)
    previous = np.where(np.isin(index, first), -1, index - 1)
    following = np.where(np.isin(index, last), -1, index + 1)
    has_segment = following >= 0
    rest_length, stretch = np.zeros(n), np.zeros(n)
    segment = index[has_segment] - node_chain[has_segment]
    rest_length[has_segment] = structure.rest_length[segment]
    stretch[has_segment] = structure.stretch_stiffness[segment]
    tie_a = np.asarray(structure.tie_a, np.int64)
    tie_b = np.asarray(structure.tie_b, np.int64)
    T = tie_a.size
    incident = [tie_a, tie_b[tie_b != GROUND]]
    owners = np.concatenate(incident)
    which = np.concatenate([np.arange(T), np.flatnonzero(tie_b != GROUND)])
    order = np.lexsort((which, owners))
    node_ties = which[order]
    node_tie_start = np.searchsorted(owners[order], np.arange(n + 1))
    weight = np.zeros((n, dim))
    weight[:, -1] = -structure.mass * structure.gravity
    load_direction = np.zeros((n, dim))
    load_direction[structure.load_node, 0] = structure.load_factor
    load_family = np.full(n, -1)
    load_family[structure.load_node] = structure.chain_family
    free = ~np.asarray(structure.fixed).reshape(n, dim)
    if structure.physical_source.size:  # a retired tail: held, seen at its chain's end
        tail = retired_tails(structure)
        free &= ~tail.reshape(n, dim)
        structure = structure._replace(dof_tie=np.where(tail, -1, structure.dof_tie))
    boundary = _boundary(structure, node_chain, dim)
    grouping = _groups(structure, node_chain, boundary, dim)
    spatial = _spatial(structure, grouping["node_group"])
    return StructureArrays(
        rest_position=np.array(structure.rest_position, float), previous=previous,
        next=following, rest_length=rest_length, stretch_stiffness=stretch,
        bend_stiffness=np.array(structure.bend_stiffness, float),
        rest_angle=np.array(structure.rest_angle, float),
        free=free.astype(float), mass=np.array(structure.mass, float),
        weight=weight, load_direction=load_direction, load_family=load_family,
        node_chain=node_chain, node_tie_start=node_tie_start, node_ties=node_ties,
        tie_a=tie_a, tie_b=tie_b, tie_side=np.array(structure.tie_side, float),
        tie_offset=np.array(structure.tie_gap_offset, float),
        contact_law=np.array(structure.tie_contact_law, float).reshape(T, 5),
        friction_law=np.array(structure.tie_friction_law, float).reshape(T, 4),
        tie_plane=np.pad(np.array(structure.tie_plane, float).reshape(T, 2),
                         ((0, 0), (0, dim - 2))),
        chain_start=start, families=int(np.max(structure.chain_family, initial=0)) + 1,
        dim=dim, **boundary, **grouping, **spatial, **_node_terms(structure),
        **_sliding(structure, has_segment, segment))


def retired_tails(s: Structure) -> np.ndarray:
    """The tied dofs (n dim,) bool of a sliding structure's retired tails (docs/model.md
    11.13): every tied dof but a family's plane nodes' (a periodic cell's lengths)."""
    tied = np.asarray(s.dof_tie) >= 0
    dim = s.rest_position.shape[1]
    for family in (s.plane_nodes_a, s.plane_nodes_b):
        tied[dim * np.asarray(family, np.int64)] = False
    return tied


def _sliding(s: Structure, has_segment: np.ndarray, segment: np.ndarray) -> dict:
    """Where the crossings slide, the arrays of their material (docs/model.md 11.13) per node
    and per segment (i, next) as the kernels index segments; none otherwise."""
    if not s.physical_source.size:
        return {}
    n, dim = s.rest_position.shape
    if np.asarray(s.node_term_active).any():
        raise ValueError("the kernels take no node terms on crossings that slide")

    def per_segment(values, shape=()):
        out = np.full((n, *shape), -1 if values.dtype.kind == "i" else 0.0, values.dtype)
        out[has_segment] = values[segment]
        return out

    slots = np.asarray(s.tie_material, np.int64).reshape(-1, 2)
    node_slide = np.full(n * dim, -1, np.int64)
    node_slide[slots[:, 0]], node_slide[slots[:, 1]] = s.tie_a, s.tie_b
    return dict(physical_source=np.asarray(s.physical_source, np.int64).reshape(n, dim),
                node_slide=node_slide.reshape(n, dim), tie_slide=slots,
                segment_material=per_segment(np.asarray(s.segment_material, np.int64), (2,)),
                segment_material_end=per_segment(np.asarray(s.segment_material_end, float),
                                                 (2,)),
                segment_fraction=per_segment(np.asarray(s.segment_fraction, float)),
                segment_base=per_segment(np.asarray(s.segment_base, float)),
                stretch_modulus=per_segment(np.asarray(s.stretch_modulus, float)),
                bend_modulus=np.asarray(s.bend_modulus, float),
                lateral_bend_modulus=np.asarray(s.lateral_bend_modulus, float),
                **_moving_planes(s))


def _moving_planes(s: Structure) -> dict:
    """`physical_plane` and `physical_plane_weight` of a structure whose crossings slide."""
    n, dim = s.rest_position.shape
    family, weight = np.full(n * dim, -1, np.int64), np.zeros(n * dim)
    planes = moving_planes(s)
    if planes is not None:
        counts = (s.plane_nodes_a.size, s.plane_nodes_b.size)
        for c, side in zip(*np.nonzero(planes[0] >= 0)):
            family[planes[0][c, side]] = side
            weight[planes[0][c, side]] = planes[1][c, side] / counts[side]
    return dict(physical_plane=family.reshape(n, dim), physical_plane_weight=weight.reshape(n, dim))


def _node_terms(s: Structure) -> dict:
    """The node terms' arrays (`dynfab.kernels.node_terms`)."""
    parameters = np.asarray(s.node_parameters, float)
    return dict(node_parameters=parameters if parameters.size else np.zeros((1, 1)),
                node_term_first=nodes.firsts(s.node_term_active))


def _spatial(s: Structure, node_group: np.ndarray) -> dict:
    """The spatial terms' arrays (docs/model.md section 11): per node the lateral bending, per
    crossing its stencil and rotation law, the lateral contacts and each group's range of
    them (their A nodes' groups, in order)."""
    lateral = np.asarray(s.lateral_stencil, np.int64).reshape(-1, 4)
    owner = node_group[lateral[:, 2]] if lateral.size else np.zeros(0, np.int64)
    if np.any(np.diff(owner) < 0):
        raise ValueError("lateral contacts not in group order")
    groups = int(node_group.max(initial=0)) + 1
    stencil = np.asarray(s.tie_stencil, np.int64).reshape(-1, 6)
    stencil_start, stencil_codes = _incidence(stencil, node_group.size)
    lateral_start, lateral_codes = _incidence(lateral, node_group.size)
    return dict(node_stencil_start=stencil_start, node_stencil=stencil_codes,
                node_lateral_start=lateral_start, node_lateral=lateral_codes,
                lateral_bend_stiffness=np.array(s.lateral_bend_stiffness, float),
                lateral_rest_angle=np.array(s.lateral_rest_angle, float),
                tie_stencil=stencil,
                rotation_law=np.array(s.tie_rotation_law, float).reshape(-1, 3),
                lateral_stencil=lateral,
                # the unilateral law: (sign, w, k, A, s_a, s_core), without the branch
                lateral_law=np.array(s.lateral_law, float)[:, [0, 1, 2, 4, 5, 6]].reshape(-1, 6),
                group_lateral=np.searchsorted(owner, np.arange(groups + 1)))


def _boundary(s: Structure, node_chain: np.ndarray, dim: int = 2) -> dict:
    """The wrap springs, moving planes and tied dofs as per-node and per-tie data."""
    start = s.chain_start
    n = int(start[-1])
    first, last = start[:-1], start[1:] - 1
    wrap_k, wrap_angle = np.zeros(n), np.zeros(n)
    wrap_k[first], wrap_angle[first] = s.wrap_stiffness, s.wrap_rest_angle
    node_wrap = np.full(n, -1)
    wraps = s.wrap_stiffness > 0
    if np.any(last[wraps] - first[wraps] < 3):
        raise ValueError("a wrap spring on a chain of fewer than 4 nodes")
    for a, b in zip(first[wraps], last[wraps]):
        node_wrap[[b - 1, b, a, a + 1]] = a
    nx, ny = s.plane_nodes_a.size, s.plane_nodes_b.size
    plane_nodes = np.concatenate([s.plane_nodes_a, s.plane_nodes_b]).astype(np.int64)
    node_plane = np.full(n, -1)
    node_plane[s.plane_nodes_a], node_plane[s.plane_nodes_b] = 0, 1
    weight = np.zeros((s.tie_a.size, dim))
    if nx:
        weight[:, 0] = s.tie_plane_weight[:, 0] / nx
    if ny:
        weight[:, 1] = s.tie_plane_weight[:, 1] / ny
    node_tie = np.full(n, -1)
    tie = np.asarray(s.dof_tie).reshape(n, dim)
    if np.any(tie[:, 1:] >= 0):
        raise ValueError("tied z dofs: the kernels tie a family's plane nodes' in-plane dofs only")
    claimed = np.zeros(n, np.bool_)
    for family, nodes in enumerate((s.plane_nodes_a, s.plane_nodes_b)):
        tied = nodes[tie[nodes, 0] >= 0]
        if tied.size:
            if not (np.array_equal(tied, nodes[1:]) and np.all(tie[tied, 0] == dim * nodes[0])):
                raise ValueError("tied dofs other than a family's plane nodes")
            node_tie[nodes] = family
            claimed[nodes[1:]] = True
    if np.any((tie[:, 0] >= 0) & ~claimed):
        raise ValueError("tied dofs other than a family's plane nodes")
    share = np.ones(n)
    for family in (0, 1):
        members = node_tie == family
        if members.any():
            share[members] = 1.0 / members.sum()
    return dict(chain_last=last[node_chain], node_wrap=node_wrap, wrap_stiffness=wrap_k,
                wrap_rest_angle=wrap_angle, plane_nodes=plane_nodes,
                plane_offsets=np.array([0, nx, nx + ny]), node_plane=node_plane,
                node_tie=node_tie, share=share, tie_weight=weight)


def _groups(s: Structure, node_chain: np.ndarray, boundary: dict, dim: int = 2) -> dict:
    """Groups of chains and blocks of nodes (module docstring)."""
    Y = chain_count(s)
    root = np.arange(Y)

    def find(y):
        while root[y] != y:
            root[y] = root[root[y]]
            y = root[y]
        return y

    def join(a, b):
        root[find(a)] = find(b)

    for a, b in zip(s.tie_a, s.tie_b):
        if b != GROUND:
            join(node_chain[a], node_chain[b])
    tied = np.flatnonzero(np.asarray(s.dof_tie) >= 0)
    for d in tied:
        join(node_chain[d // dim], node_chain[s.dof_tie[d] // dim])
    planes = np.concatenate([s.plane_nodes_a, s.plane_nodes_b]).astype(np.int64)
    moved = np.flatnonzero(np.any(np.asarray(s.tie_plane_weight) != 0.0, axis=1))
    coupled = np.concatenate([node_chain[planes], node_chain[s.tie_a[moved]]])
    for y in coupled[1:]:
        join(coupled[0], y)
    if s.physical_source.size:  # crossings that slide: one patch, a yarn that left it too
        for y in range(1, Y):
            join(0, y)
    component = np.array([find(y) for y in range(Y)])
    # contiguous ranges: a group ends at chain y when no component seen so far continues past y
    reach = {}
    for y in range(Y):
        reach[component[y]] = y
    bounds, end = [0], -1
    for y in range(Y):
        end = max(end, reach[component[y]])
        if end == y:
            bounds.append(y + 1)
    group_chain = np.array(bounds)
    chain_group = np.repeat(np.arange(group_chain.size - 1), np.diff(group_chain))
    tie_group = chain_group[node_chain[s.tie_a]] if s.tie_a.size else np.zeros(0, np.int64)
    if np.any(np.diff(tie_group) < 0):  # ties not in group order: one group
        group_chain = np.array([0, Y])
        chain_group = np.zeros(Y, np.int64)
        tie_group = np.zeros(s.tie_a.size, np.int64)
    G = group_chain.size - 1
    start = np.asarray(s.chain_start, np.int64)
    group_node = start[group_chain]
    group_tie = np.searchsorted(tie_group, np.arange(G + 1))
    block_start, block_group, group_block = [], [], [0]
    for g in range(G):
        lo, hi = group_node[g], group_node[g + 1]
        cuts = list(range(lo, hi, BLOCK))
        block_start += cuts
        block_group += [g] * len(cuts)
        group_block.append(len(block_start))
    block_start.append(int(start[-1]))
    chains = np.diff(group_chain)
    exact = np.zeros(G, np.int64)
    wraps = np.asarray(s.wrap_stiffness) > 0.0
    for g in range(G):
        ties = slice(group_tie[g], group_tie[g + 1])
        exact[g] = (chains[g] == 1 and np.all(s.tie_b[ties] == GROUND)
                    and not wraps[group_chain[g]]
                    and not np.any(boundary["node_plane"][group_node[g]:group_node[g + 1]] >= 0)
                    and not np.any(boundary["node_tie"][group_node[g]:group_node[g + 1]] >= 0))
    return dict(group_chain=group_chain, group_node=group_node, group_tie=group_tie,
                group_block=np.array(group_block), group_exact=exact,
                block_start=np.array(block_start), node_group=chain_group[node_chain],
                tie_group=tie_group, chain_group=chain_group, block_group=np.array(block_group))
def _incidence(stencil: np.ndarray, n: int) -> tuple[np.ndarray, np.ndarray]:
    """Each node's places in the (E, K) `stencil` as a CSR list: (start (n + 1,), codes
    K e + slot in element order), for the gather order of elements spanning several nodes."""
    count, width = stencil.shape
    codes = np.arange(count * width, dtype=np.int64)
    nodes = stencil.reshape(-1)
    order = np.lexsort((codes, nodes))
    return np.searchsorted(nodes[order], np.arange(n + 1)), codes[order]


def struct(scalar, dim: int = 2):
    """The `StructureData` Warp struct (`_struct`), one per (scalar, dim) however called."""
    return _struct(scalar, int(dim))


@functools.cache
def _struct(scalar, dim: int):
    """The `StructureData` Warp struct for one scalar type and `dim` coordinates per node (the
    spatial terms' arrays empty in a planar structure)."""
    vec = vector(scalar, dim)

    class StructureData:
        """Everything a kernel knows of the structure; constant during a run."""

        rest_position: wp.array(dtype=vec)
        previous: wp.array(dtype=wp.int32)
        next: wp.array(dtype=wp.int32)
        rest_length: wp.array(dtype=scalar)
        stretch_stiffness: wp.array(dtype=scalar)
        bend_stiffness: wp.array(dtype=scalar)
        rest_angle: wp.array(dtype=scalar)
        free: wp.array(dtype=vec)
        mass: wp.array(dtype=scalar)
        weight: wp.array(dtype=vec)
        load_direction: wp.array(dtype=vec)
        load_family: wp.array(dtype=wp.int32)
        node_chain: wp.array(dtype=wp.int32)
        node_tie_start: wp.array(dtype=wp.int32)
        node_ties: wp.array(dtype=wp.int32)
        chain_last: wp.array(dtype=wp.int32)
        node_wrap: wp.array(dtype=wp.int32)
        wrap_stiffness: wp.array(dtype=scalar)
        wrap_rest_angle: wp.array(dtype=scalar)
        plane_nodes: wp.array(dtype=wp.int32)
        plane_offsets: wp.array(dtype=wp.int32)
        node_plane: wp.array(dtype=wp.int32)
        node_tie: wp.array(dtype=wp.int32)
        share: wp.array(dtype=scalar)
        tie_a: wp.array(dtype=wp.int32)
        tie_b: wp.array(dtype=wp.int32)
        tie_side: wp.array(dtype=scalar)
        tie_offset: wp.array(dtype=scalar)
        contact_law: wp.array2d(dtype=scalar)
        friction_law: wp.array2d(dtype=scalar)
        tie_plane: wp.array(dtype=vec)
        tie_weight: wp.array(dtype=vec)
        chain_start: wp.array(dtype=wp.int32)
        group_chain: wp.array(dtype=wp.int32)
        group_node: wp.array(dtype=wp.int32)
        group_tie: wp.array(dtype=wp.int32)
        group_block: wp.array(dtype=wp.int32)
        group_exact: wp.array(dtype=wp.int32)
        block_start: wp.array(dtype=wp.int32)
        node_group: wp.array(dtype=wp.int32)
        tie_group: wp.array(dtype=wp.int32)
        chain_group: wp.array(dtype=wp.int32)
        block_group: wp.array(dtype=wp.int32)
        node_parameters: wp.array2d(dtype=scalar)
        node_term_first: wp.array(dtype=wp.int32)
        lateral_bend_stiffness: wp.array(dtype=scalar)
        lateral_rest_angle: wp.array(dtype=scalar)
        tie_stencil: wp.array2d(dtype=wp.int32)
        rotation_law: wp.array2d(dtype=scalar)
        lateral_stencil: wp.array2d(dtype=wp.int32)
        lateral_law: wp.array2d(dtype=scalar)
        group_lateral: wp.array(dtype=wp.int32)
        node_stencil_start: wp.array(dtype=wp.int32)
        node_stencil: wp.array(dtype=wp.int32)
        node_lateral_start: wp.array(dtype=wp.int32)
        node_lateral: wp.array(dtype=wp.int32)
        physical_source: wp.array2d(dtype=wp.int32)
        node_slide: wp.array2d(dtype=wp.int32)
        tie_slide: wp.array2d(dtype=wp.int32)
        segment_material: wp.array2d(dtype=wp.int32)
        segment_material_end: wp.array2d(dtype=scalar)
        segment_fraction: wp.array(dtype=scalar)
        segment_base: wp.array(dtype=scalar)
        stretch_modulus: wp.array(dtype=scalar)
        bend_modulus: wp.array(dtype=scalar)
        lateral_bend_modulus: wp.array(dtype=scalar)
        physical_plane: wp.array2d(dtype=wp.int32)
        physical_plane_weight: wp.array2d(dtype=scalar)

    return wp.struct(StructureData)


def upload(arrays: StructureArrays, scalar, device: str, **replaced):
    """The StructureData of `arrays` on `device` in precision `scalar`, each field converted to
    the element type the struct declares for it; `replaced` fields (numpy arrays) instead of
    the arrays' own (the reactions' unmasked `free`)."""
    Data = struct(scalar, arrays.dim)
    data = Data()
    for name, field in Data.vars.items():
        values = np.asarray(replaced.get(name, getattr(arrays, name)))
        dtype = field.type.dtype  # a node vector, the scalar or wp.int32
        if wp.types.type_is_vector(dtype):
            values = values.reshape(-1, arrays.dim)
        values = values.astype(np.int32 if dtype is wp.int32 else numpy_dtype(scalar))
        setattr(data, name, wp.array(values, dtype=dtype, device=device))
    return data
