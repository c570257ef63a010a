"""A clamped patch of woven fabric as one flat node array, for node-parallel kernels
(docs/model.md section 10).

The geometry and the parameters are the static reference's: `build(structure)` takes the
fabric's `dynfab.structure.Structure` (`dynfab.builders.fabric`: the node order, the crossings
and their sides, the fixed dofs, the masses, the contact law with k_c and the stick
stiffness k_t) and adds what node-parallel kernels need.
Only the force and energy code is the Warp twin's own (`fabric_forces`).

Both yarn families are chains (docs/model.md section 10). Every node of every yarn is one entry of
one flat array, in the layout's order: warp k's nodes first (k = 1..n_wa, N+1 nodes
each), then weft j's (j = 1..n_we, M+1 nodes each). A node's two coordinates are
(s, z): s = x along a warp, s = y along a weft (yarns stay straight in plan view,
docs/model.md section 10). Each node knows its chain neighbours (`previous`, `next`, -1 past an
end), so a thread can gather its own stretch and bending forces without touching
another thread's output, and at most one crossing: in a plain weave the crossings of
one yarn sit at distinct nodes, so the per-node list of incident crossings has length
0 or 1 and is stored as one index (`node_crossing`, -1 for none).

Crossing c = k n_we + j (0-based warp k, weft j) joins the layout's warp and weft
nodes, the warp on side sigma; closure g = c - sigma (z_wa - z_we) with
c = sigma (z0_wa - z0_we) (the layout's gap offset).

The boundary is data, not a kernel variant (docs/model.md section 10):
- moving planes (planes "affine", the periodic cell): X_j = X0_j + w_j u_wa with u_wa the
  mean end displacement of the warps (`plane_nodes`, x-family first, split at
  `plane_offsets`), so crossing c's slip subtracts `crossing_plane_weight[c]` (w_j / n_wa,
  w_k / n_we) times the summed end displacements, and each of those end nodes feels the
  reaction -sum_c (w / n) f_c of the crossings' friction forces f_c (gathered over the
  crossings by that node's thread); fixed planes have no plane nodes and zero weights;
- the periodic wrap: the bending spring at each yarn's node 0 between segment N-1 and
  segment 0's image (`wrap_stiffness`, `wrap_rest_angle` at node 0, 0 elsewhere; the four
  nodes it joins know their yarn's node 0, `node_wrap`: one read per node decides);
- the tied cell length (periodic force control): the end nodes of a family (`node_tie` =
  the family) move as one dof, each carrying the family's summed end force and the summed
  mass (`gershgorin_masses`), its kinetic energy counted once (`energy_shares`).
"""

import functools
from dataclasses import dataclass

import numpy as np
import warp as wp

from dynfab.structure import Structure, chain_of_node, uniform
from dynfab.kernels.precision import VECTORS, numpy_dtype

@dataclass
class PatchArrays:
    """The numpy arrays of a patch (float64; index arrays int32). n nodes, C crossings."""

    rest_position: np.ndarray
    """(n, 2) as-woven (s, z) [m]."""
    previous: np.ndarray
    """(n,) chain neighbour before the node, -1 at a first node."""
    next: np.ndarray
    """(n,) chain neighbour after the node, -1 at a last node."""
    rest_length: np.ndarray
    """(n,) l0 of the segment (node, next) [m]; 0 at a last node."""
    stretch_stiffness: np.ndarray
    """(n,) EA / l0 of the segment (node, next) [N/m]; 0 at a last node."""
    bend_stiffness: np.ndarray
    """(n,) EI / lbar [N m]; 0 at the end nodes."""
    rest_angle: np.ndarray
    """(n,) as-woven turning angle phi0 [rad]; 0 at the end nodes."""
    free: np.ndarray
    """(n, 2) 1 for a free dof, 0 for a held one (the layout's fixed dofs)."""
    node_crossing: np.ndarray
    """(n,) the node's crossing, -1 for none."""
    node_side: np.ndarray
    """(n,) z-force per unit R on the node: +sigma on the warp node, -sigma on the weft node."""
    crossing_warp: np.ndarray
    """(C,) warp node of crossing c = k n_we + j (0-based warp k, weft j)."""
    crossing_weft: np.ndarray
    """(C,) weft node of the crossing."""
    crossing_side: np.ndarray
    """(C,) sigma_jk [-]: +1 when the warp lies above."""
    crossing_offset: np.ndarray
    """(C,) c = sigma (z0_wa - z0_we) [m], so g = c - sigma (z_wa - z_we)."""
    contact_law: np.ndarray
    """(5,) k_c [N/m], C_wa [m], a_wa [1/N], C_we [m], a_we [1/N] (a_m = K_m / Lc_m)."""
    friction_law: np.ndarray
    """(4,) alpha [-], beta ell r_f [N], R_0 [N], k_t [N/m]; zeros without friction."""
    warp_nodes: np.ndarray
    """(n_wa, N+1) flat index of warp k's node i."""
    weft_nodes: np.ndarray
    """(n_we, M+1) flat index of weft j's node i."""
    load_direction: np.ndarray
    """(n, 2) the end load per unit warp value: each warp's load factor on its x_N [-]."""
    weft_load_direction: np.ndarray
    """(n, 2) the same for the wefts (their factors on y_M) [-]."""
    weight: np.ndarray
    """(n, 2) gravity's constant nodal force (0, -rho_l lbar g) [N] (docs/model.md section 2); zeros
    without gravity. Not part of the kernels: a driver adds it to the external force."""
    node_wrap: np.ndarray
    """(n,) node 0 of the node's yarn where the node is one of the four its periodic wrap
    spring joins (N-1, N, 0, 1), -1 elsewhere and on a clamped patch."""
    yarn_last: np.ndarray
    """(n,) the last node of the node's yarn."""
    wrap_stiffness: np.ndarray
    """(n,) EI / lbar_0 [N m] of the periodic wrap spring, at each yarn's node 0; 0 elsewhere
    and on a clamped patch."""
    wrap_rest_angle: np.ndarray
    """(n,) as-woven turning angle across the wrap [rad], at each yarn's node 0."""
    plane_nodes: np.ndarray
    """(n_x + n_y,) the end nodes whose in-plane displacements move the planes: those moving
    X_j (the warps' last nodes), then those moving Y_k; empty with fixed planes."""
    plane_offsets: np.ndarray
    """(3,) plane_nodes[plane_offsets[f]:plane_offsets[f+1]] are family f's (0: X_j, 1: Y_k)."""
    node_plane: np.ndarray
    """(n,) the family (0, 1) of planes the node moves, -1 for none."""
    node_tie: np.ndarray
    """(n,) the family whose end nodes move as one with this node (periodic force control:
    the cell length), -1 for none."""
    crossing_plane_weight: np.ndarray
    """(C, 2) (w_j / n_x, w_k / n_y) [-]: X_j = X0_j + w_j mean u = X0_j + weight_x sum u over
    the family's plane nodes (docs/model.md section 10); zeros with fixed planes."""

    @property
    def nodes(self) -> int:
        return self.rest_position.shape[0]

    @property
    def crossings(self) -> int:
        return self.crossing_warp.shape[0]


def build(fabric: Structure) -> PatchArrays:
    """The arrays of a fabric's structure (docs/model.md section 10): a clamped patch with
    fixed or affine planes, or a periodic cell. Its ties join two nodes, with one contact
    law and one friction law for all (the kernels' laws are not per tie)."""
    if np.any(fabric.tie_b < 0):
        raise ValueError("the fabric kernels take ties between two nodes, not to ground")
    start = fabric.chain_start
    n = start[-1]
    yarn_of_node = chain_of_node(fabric)
    is_warp = fabric.chain_family == 0
    first, last = start[:-1], start[1:] - 1
    index = np.arange(n, dtype=np.int32)
    previous = np.where(np.isin(index, first), -1, index - 1).astype(np.int32)
    following = np.where(np.isin(index, last), -1, index + 1).astype(np.int32)
    has_segment = following >= 0
    rest_length, stretch = np.zeros(n), np.zeros(n)
    segment = index[has_segment] - yarn_of_node[has_segment]  # the layout's segment index
    rest_length[has_segment] = fabric.rest_length[segment]
    stretch[has_segment] = fabric.stretch_stiffness[segment]
    C = fabric.tie_a.size
    node_crossing = np.full(n, -1, dtype=np.int32)
    node_side = np.zeros(n)
    node_crossing[fabric.tie_a] = np.arange(C)
    node_crossing[fabric.tie_b] = np.arange(C)
    node_side[fabric.tie_a], node_side[fabric.tie_b] = fabric.tie_side, -fabric.tie_side
    load_wa, load_we = np.zeros((n, 2)), np.zeros((n, 2))
    load_wa[last[is_warp], 0] = fabric.load_factor[is_warp]
    load_we[last[~is_warp], 0] = fabric.load_factor[~is_warp]
    weight = np.zeros((n, 2))
    weight[:, 1] = -fabric.mass * fabric.gravity
    nodes_of = [np.arange(a, b, dtype=np.int32) for a, b in zip(first, last + 1)]
    warps = int(is_warp.sum())
    return PatchArrays(
        rest_position=fabric.rest_position.copy(), previous=previous, next=following,
        rest_length=rest_length, stretch_stiffness=stretch,
        bend_stiffness=fabric.bend_stiffness.copy(), rest_angle=fabric.rest_angle.copy(),
        free=(~fabric.fixed).reshape(n, 2).astype(float), node_crossing=node_crossing,
        node_side=node_side, crossing_warp=fabric.tie_a.astype(np.int32),
        crossing_weft=fabric.tie_b.astype(np.int32), crossing_side=fabric.tie_side.copy(),
        crossing_offset=fabric.tie_gap_offset.copy(),
        contact_law=uniform(fabric.tie_contact_law).copy(),
        friction_law=uniform(fabric.tie_friction_law).copy(),
        warp_nodes=np.array(nodes_of[:warps]), weft_nodes=np.array(nodes_of[warps:]),
        load_direction=load_wa, weft_load_direction=load_we, weight=weight,
        **boundary_arrays(fabric, yarn_of_node))


def boundary_arrays(fabric: Structure, yarn_of_node: np.ndarray) -> dict:
    """The moving planes, the periodic wrap springs and the tied end nodes as per-node and
    per-crossing data (module docstring)."""
    start = fabric.chain_start
    n = start[-1]
    first, last = start[:-1], start[1:] - 1
    wrap_k, wrap_angle = np.zeros(n), np.zeros(n)
    wrap_k[first], wrap_angle[first] = fabric.wrap_stiffness, fabric.wrap_rest_angle
    node_wrap = np.full(n, -1, np.int32)
    for a, b in zip(first[fabric.wrap_stiffness > 0], last[fabric.wrap_stiffness > 0]):
        node_wrap[[b - 1, b, a, a + 1]] = a
    nx, ny = fabric.plane_nodes_a.size, fabric.plane_nodes_b.size
    plane_nodes = np.concatenate([fabric.plane_nodes_a, fabric.plane_nodes_b]).astype(np.int32)
    node_plane = np.full(n, -1, np.int32)
    node_plane[fabric.plane_nodes_a], node_plane[fabric.plane_nodes_b] = 0, 1
    weight = np.zeros((fabric.tie_a.size, 2))
    if nx:
        weight[:, 0] = fabric.tie_plane_weight[:, 0] / nx
    if ny:
        weight[:, 1] = fabric.tie_plane_weight[:, 1] / ny
    if not np.isin(last[fabric.wrap_stiffness > 0], plane_nodes).all():
        raise ValueError("a wrap spring on a yarn whose end does not move the planes")
    node_tie = np.full(n, -1, np.int32)
    tie = fabric.dof_tie.reshape(n, 2)[:, 0]
    for family, nodes in enumerate((fabric.plane_nodes_a, fabric.plane_nodes_b)):
        tied = nodes[tie[nodes] >= 0]
        if tied.size:  # every node of the family tied to its first: the family moves as one
            if not (np.array_equal(tied, nodes[1:]) and (tie[tied] == 2 * nodes[0]).all()):
                raise ValueError("tied dofs other than a family's plane nodes")
            node_tie[nodes] = family
    return dict(node_wrap=node_wrap,
                yarn_last=last[yarn_of_node].astype(np.int32),
                wrap_stiffness=wrap_k, wrap_rest_angle=wrap_angle, plane_nodes=plane_nodes,
                plane_offsets=np.array([0, nx, nx + ny], np.int32), node_plane=node_plane,
                node_tie=node_tie, crossing_plane_weight=weight)


GERSHGORIN_SAFETY = 0.9
"""dt / the stable time step of the Gershgorin masses [-]."""


def gershgorin_masses(arrays: PatchArrays, dt: float, safety: float = GERSHGORIN_SAFETY) -> np.ndarray:
    """Fictitious masses (n,) [kg] with m_i >= dt^2/4 sum_j |K_ij| / safety^2
    (docs/model.md section 5).

    Row-sum bounds at the as-woven state, per term touching node i: a stretch
    segment k (e e^T / l^2) has absolute row sums <= (1 + sqrt 2)/2 k in its diagonal
    and its off-diagonal block, so 2.5 k; a bending spring k_b dphi dphi^T at a node
    with segments a, b has |dphi_i|_1 |dphi|_1 <= 4 (1/|a| + 1/|b|)^2 (|dphi_p|_1 <=
    sqrt 2 (1/|a| + 1/|b|) per node, three nodes); a contact has dR/dg <= k_c on two
    z dofs, 2 k_c. The geometric (tension, moment) parts are small near the as-woven
    state and covered by the safety factor on dt.
    """
    n = arrays.nodes
    rows = np.zeros(n)
    has_next = arrays.next >= 0
    segment = 2.5 * arrays.stretch_stiffness
    rows[has_next] += segment[has_next]
    rows[arrays.next[has_next]] += segment[has_next]
    inner = np.flatnonzero((arrays.previous >= 0) & (arrays.next >= 0))
    inv = 1.0 / arrays.rest_length[arrays.previous[inner]] + 1.0 / arrays.rest_length[inner]
    bend = 4.0 * arrays.bend_stiffness[inner] * inv ** 2
    for touched in (arrays.previous[inner], inner, arrays.next[inner]):
        np.add.at(rows, touched, bend)
    rows[arrays.node_crossing >= 0] += 2.0 * arrays.contact_law[0] + arrays.friction_law[3]
    rows += boundary_rows(arrays)
    masses = dt ** 2 / 4.0 * rows / safety ** 2
    for family in (0, 1):  # a tied family's end nodes: one dof, the sum of their masses
        tied = arrays.node_tie == family
        if tied.any():
            masses[tied] = masses[tied].sum()
    return masses


def boundary_rows(arrays: PatchArrays) -> np.ndarray:
    """Absolute row sums (n,) [N/m] the moving planes and the wrap springs add.

    Moving planes: crossing c's Huber block h (|h| <= k_t) acts through the slip's Jacobian
    J, whose row for X_j holds 1 on x_a and -w_x on each of the family's n_x end nodes
    (weight w_x = w_j / n_x each), likewise for Y_k; J^T h J then adds k_t (w_x n_x +
    w_y n_y) to the crossing nodes' rows beyond the k_t counted (nothing with fixed
    planes), and w_x k_t (2 + w_x n_x + w_y n_y) per crossing to an X end node's row (w_y
    likewise for Y). The wrap spring:
    the angle's gradient maps to (r_{N-1}, r_N, r_0, r_1) as (g_0, g_1 + g_2, -g_2, g_2), so
    |M^T g|_1 <= 4 sqrt 2 S and each node's part <= sqrt 2 S (S = 1/|a| + 1/|b|): 8 k S^2
    on each of the four nodes."""
    rows = np.zeros(arrays.nodes)
    k_t = arrays.friction_law[3]
    weight = arrays.crossing_plane_weight
    offsets = arrays.plane_offsets
    counts = np.diff(offsets)
    spread = 2.0 + weight[:, 0] * counts[0] + weight[:, 1] * counts[1]
    rows[arrays.crossing_warp] += k_t * (spread - 2.0)
    rows[arrays.crossing_weft] += k_t * (spread - 2.0)
    for family in (0, 1):
        nodes = arrays.plane_nodes[offsets[family]:offsets[family + 1]]
        rows[nodes] += k_t * (weight[:, family] * spread).sum()
    for first in np.flatnonzero(arrays.wrap_stiffness > 0.0):
        last = arrays.yarn_last[first]
        S = 1.0 / arrays.rest_length[last - 1] + 1.0 / arrays.rest_length[first]
        rows[[last - 1, last, first, first + 1]] += 8.0 * arrays.wrap_stiffness[first] * S ** 2
    return rows


def energy_shares(arrays: PatchArrays) -> np.ndarray:
    """(n,) the share of a node's 1/2 m v^2 (and of its terms in FIRE's sums) in the totals:
    1, and 1 / n for each of a tied family's n end nodes, which move as one dof of their
    summed mass (`gershgorin_masses`), so that dof is counted once."""
    share = np.ones(arrays.nodes)
    for family in (0, 1):
        tied = arrays.node_tie == family
        share[tied] = 1.0 / tied.sum() if tied.any() else 1.0
    return share


@functools.cache
def struct(scalar):
    """The `FabricArrays` struct type for one scalar type."""
    vec = VECTORS[scalar]

    @wp.struct
    class FabricArrays:
        """Everything a fabric kernel needs to know about the patch; constant during a run."""

        rest_position: wp.array(dtype=vec)
        previous: wp.array(dtype=wp.int32)
        next: wp.array(dtype=wp.int32)
        rest_length: wp.array(dtype=scalar)
        stretch_stiffness: wp.array(dtype=scalar)
        bend_stiffness: wp.array(dtype=scalar)
        rest_angle: wp.array(dtype=scalar)
        free: wp.array(dtype=vec)
        node_crossing: wp.array(dtype=wp.int32)
        node_side: wp.array(dtype=scalar)
        crossing_warp: wp.array(dtype=wp.int32)
        crossing_weft: wp.array(dtype=wp.int32)
        crossing_side: wp.array(dtype=scalar)
        crossing_offset: wp.array(dtype=scalar)
        contact_law: wp.array(dtype=scalar)
        friction_law: wp.array(dtype=scalar)
        node_wrap: wp.array(dtype=wp.int32)
        yarn_last: wp.array(dtype=wp.int32)
        wrap_stiffness: wp.array(dtype=scalar)
        wrap_rest_angle: wp.array(dtype=scalar)
        plane_nodes: wp.array(dtype=wp.int32)
        plane_offsets: wp.array(dtype=wp.int32)
        node_plane: wp.array(dtype=wp.int32)
        node_tie: wp.array(dtype=wp.int32)
        crossing_plane_weight: wp.array(dtype=vec)

    return FabricArrays


VECTOR_FIELDS = ("rest_position", "free", "crossing_plane_weight")
INDEX_FIELDS = ("previous", "next", "node_crossing", "crossing_warp", "crossing_weft",
                "node_wrap", "yarn_last", "plane_nodes", "plane_offsets", "node_plane", "node_tie")
SCALAR_FIELDS = ("rest_length", "stretch_stiffness", "bend_stiffness", "rest_angle", "node_side",
                 "crossing_side", "crossing_offset", "contact_law", "friction_law",
                 "wrap_stiffness", "wrap_rest_angle")


def upload(arrays: PatchArrays, scalar, device: str):
    """The FabricArrays struct of `arrays` on `device`, in precision `scalar`."""
    dtype, vec = numpy_dtype(scalar), VECTORS[scalar]
    fabric = struct(scalar)()
    for name in VECTOR_FIELDS:
        setattr(fabric, name, wp.array(getattr(arrays, name).astype(dtype), dtype=vec, device=device))
    for name in INDEX_FIELDS:
        setattr(fabric, name, wp.array(getattr(arrays, name).astype(np.int32), dtype=wp.int32,
                                       device=device))
    for name in SCALAR_FIELDS:
        setattr(fabric, name, wp.array(getattr(arrays, name).astype(dtype), dtype=scalar, device=device))
    return fabric

