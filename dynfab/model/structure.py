"""The one data model of every scene: chains, ties and held degrees of freedom
(docs/model.md, "The structure").

A `Structure` is what the solvers see of a scene, whatever the model that made it
(`dynfab.model.builders`: the paper's yarn against weft springs, docs/model.md sections 1-9; the
woven fabric, section 10):

- **Chains**: Y ordered runs of nodes, chain y holding nodes chain_start[y] ..
  chain_start[y+1]-1, with a stretch spring per segment and a bending spring per inner
  node (docs/model.md section 2); on a periodic cell a further bending spring across the
  wrap at node 0 (section 10). Each chain belongs to a family (0: warps, 1: wefts), whose
  load value a load step gives; its last node is loaded along the chain by that value
  times the chain's load factor.
- **Ties**: T stencils of nodes with a law. Tie t joins node tie_a[t] to node tie_b[t],
  or to ground where tie_b[t] = -1 (the paper's weft, a spring fixed in space): the
  contact law of docs/model.md section 3 on the closure
  g = gap_offset - side (z_a - z_b) (z_b = 0 for ground), and Gralen's stick-slip
  friction of section 4 on the slip of each node along its own chain, measured from
  the plane of the chain it crosses (the tie's `tie_plane`, moving with the mean end
  displacement of the `plane_nodes` where the planes follow the patch) and from the
  anchor. Every tie has its own law parameters (rows of `tie_contact_law`,
  `tie_friction_law`): a one-yarn [sweep], an unbalanced fabric and a uniform patch are
  the same data.
- **Boundary**: held dofs (`fixed`), tied dofs (`dof_tie`: a dof that moves as another,
  the periodic cell's lengths), loads as the load factor of each chain's last node.

Nodes carry `dim` coordinates, the last one z (out of the fabric's plane). Planar
kinematics (dim = 2): every chain moves in its own vertical plane, coordinate 0 along the
chain (docs/model.md section 10). Spatial kinematics (dim = 3): global (x, y, z), the
fabric's plane x-y; the ties are then stencils of six nodes and neighbouring yarns meet in
lateral contacts (docs/model.md section 11, the fields after `dof_tie`). Nothing here
depends on dim but the terms that read the coordinates. Dof d = dim * node + coordinate.

A Structure is a NamedTuple of arrays and scalars, so numba functions take it whole;
nothing in it changes during a run (what changes is a `dynfab.model.yarn.State`).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

GROUND = -1
"""`tie_b` of a tie to ground."""


class Structure(NamedTuple):
    """Chains, ties and boundary of a scene (module docstring). n nodes, Y chains, T ties."""

    # --- nodes
    rest_position: np.ndarray
    """Node positions of the stress-free (as-woven) state (n, dim) [m], in each chain's
    frame: coordinate 0 along the chain, the last z."""
    mass: np.ndarray
    """Physical lumped masses rho_l lbar (n,) [kg] (docs/model.md section 5)."""
    gravity: np.ndarray
    """g acting on each node along -z (n,) [m/s^2]; 0 where the scene has no gravity."""
    # --- chains
    chain_start: np.ndarray
    """First node of each chain, and the node count at the end (Y+1,), int64."""
    chain_family: np.ndarray
    """Family of each chain (Y,), int64: 0 the warps (or the paper's yarns), running along x,
    1 the wefts, running along y."""
    chain_plane: np.ndarray
    """The as-woven plane of each chain (Y,) [m]: y = Y_k of a warp, x = X_j of a weft."""
    rest_length: np.ndarray
    """Segment rest lengths l0, chain after chain (n - Y,) [m]; chain y's segments start at
    chain_start[y] - y."""
    stretch_stiffness: np.ndarray
    """EA / l0 per segment (n - Y,) [N/m]."""
    bend_stiffness: np.ndarray
    """EI / lbar per node (n,) [N m]; 0 at each chain's end nodes."""
    rest_angle: np.ndarray
    """Rest turning angle phi0 per node (n,) [rad]."""
    wrap_stiffness: np.ndarray
    """EI / lbar_0 of the bending spring across a periodic chain's wrap at node 0 (Y,) [N m];
    0 where the chain does not wrap (docs/model.md section 10)."""
    wrap_rest_angle: np.ndarray
    """Rest turning angle across the wrap (Y,) [rad]."""
    load_node: np.ndarray
    """Last node of each chain (Y,), int64: where the chain is loaded along itself."""
    load_factor: np.ndarray
    """Load of each chain per unit of its family's load value (Y,) [-]."""
    # --- ties
    tie_a: np.ndarray
    """First node of each tie (T,), int64: the warp node of a crossing."""
    tie_b: np.ndarray
    """Second node of each tie (T,), int64: the weft node, or GROUND."""
    tie_side: np.ndarray
    """sigma, +1 where node a lies above node b (or above the ground's weft) (T,) [-]."""
    tie_gap_offset: np.ndarray
    """c of the closure g = c - sigma (z_a - z_b) (T,) [m] (docs/model.md sections 3, 10)."""
    tie_contact_law: np.ndarray
    """(k_s [N/m], C_a [m], a_a [1/N], C_b [m], a_b [1/N]) of each tie's series law (T, 5)
    (docs/model.md section 3)."""
    tie_friction_law: np.ndarray
    """(alpha [-], beta ell r_f [N], R_0 [N], k_t [N/m]) of each tie's friction (T, 4)
    (docs/model.md section 4); zeros without friction."""
    tie_plane: np.ndarray
    """As-woven planes the slips are measured from (T, 2) [m]: node a's from the plane of
    node b's chain (X_j), node b's from node a's (Y_k); zeros for ground ties, whose
    anchors are positions."""
    tie_plane_weight: np.ndarray
    """(w_a, w_b) (T, 2) [-]: the planes move by w times the mean end displacement of
    `plane_nodes_a` (`plane_nodes_b`); zeros where they stay as woven."""
    plane_nodes_a: np.ndarray
    """End nodes whose mean displacement along their chains moves the planes of the a
    slips (int64); empty where the planes stay as woven."""
    plane_nodes_b: np.ndarray
    """The same for the planes of the b slips."""
    has_friction: bool
    """Some tie has friction (k_t > 0)."""
    # --- boundary
    fixed: np.ndarray
    """Held dofs (n dim,) bool."""
    dof_tie: np.ndarray
    """Per dof (n dim,) int64: -1, or the dof it moves as (periodic force control: every
    warp's end holds the cell length L1 in warp 0's end)."""
    # --- spatial kinematics only (dim 3, docs/model.md section 11); empty in the plane
    lateral_bend_stiffness: np.ndarray = np.zeros(0)
    """EI_lateral / lbar per node (n,) [N m]: the in-plane (lateral) bending spring; 0 at
    each chain's end nodes."""
    lateral_rest_angle: np.ndarray = np.zeros(0)
    """Rest in-plane turning psi0 per node (n,) [rad]."""
    tie_stencil: np.ndarray = np.zeros((0, 6), np.int64)
    """(a_prev, a, a_next, b_prev, b, b_next) of each tie (T, 6), int64: its two nodes and
    their chain neighbours (a node itself at its chain's end), whose chords set the
    crossing's local frame and rotation."""
    tie_rotation_law: np.ndarray = np.zeros((0, 3))
    """(rho [m], K [N m/rad], phi_rest [rad]) of each tie (T, 3): the torsion radius that
    scales the rotation in the friction slip, the elastic rotation (shear) spring and its
    rest angle from the warp to the weft."""
    lateral_stencil: np.ndarray = np.zeros((0, 4), np.int64)
    """(A_prev, A_next, A, B) of each lateral contact (L, 4), int64: node B of yarn k+1
    against the line through node A of its neighbour yarn k along A's chord."""
    lateral_law: np.ndarray = np.zeros((0, 7))
    """(sign [-], w [m], k [N/m], branch, A [N], s_a [m], s_core [m]) of each lateral contact
    (L, 7): the orientation that makes the distance positive, the yarns' width, the
    stiffness (the law without compaction, the core with it), NATURAL (the unilateral law,
    `dynfab.model.terms.contact`; the static solver's Newton solves see a copy with each contact
    held OPEN or CLOSED, its active set), and Gutowski's compaction (A 0 without it): its
    constant, the distance at the packing limit and the one below which the core takes over
    (docs/model.md 11.5)."""
    # --- node terms (`dynfab.model.terms.nodes`): empty where the scene has none
    node_parameters: np.ndarray = np.zeros((0, 0))
    """The parameters of every node term the scene has, side by side in registry order
    (n, sum of their parameter counts); see `dynfab.model.terms.nodes`."""
    node_term_active: np.ndarray = np.zeros(0, np.bool_)
    """Which registry node terms the scene has (K,) bool, in registry order."""
    # --- crossings that slide (docs/model.md 11.13, `dynfab.model.builders.sliding`): empty
    # where every crossing is a fixed pair of nodes
    physical_source: np.ndarray = np.zeros(0, np.int64)
    """Per physical coordinate (n dim,), int64: the dof that holds it, or -1 where it is held at
    its as-woven value (a planar sliding crossing's node, on the plane it crosses). The
    positions the elements see are these (`dynfab.model.fabric.sliding.physical`); the dofs
    of the solvers are the physical coordinates but for each sliding tie's two slip dofs,
    which hold its material slides instead."""
    tie_material: np.ndarray = np.zeros((0, 2), np.int64)
    """(dof of delta_a, dof of delta_b) of each tie (T, 2), int64: the dofs that hold its two
    slides [m], delta = u - U, u the material coordinate (the as-woven arc length from its
    chain's first node of the yarn point at the crossing) and U its value as woven, on node
    a's chain and on node b's (its slip dofs as a fixed crossing)."""
    segment_material: np.ndarray = np.zeros((0, 2), np.int64)
    """(left, right) material coordinates' dofs of each segment's bay (n - Y, 2), int64: the
    bay, the piece of chain between two consecutive crossings or a crossing and the chain's
    end, whose material the crossings let through; -1 at a chain's end."""
    segment_material_end: np.ndarray = np.zeros((0, 2))
    """The slide [m] of each segment's bay end where `segment_material` is -1 (a chain's end,
    a material point: 0, or where a departure retired a tail, its crossing's slide then),
    else 0 (n - Y, 2)."""
    segment_fraction: np.ndarray = np.zeros(0)
    """Each segment's share f of its bay's material (n - Y,) [-]."""
    segment_base: np.ndarray = np.zeros(0)
    """Each segment's rest length where its bay's ends have not slid (n - Y,) [m]: its rest
    length is this plus f times the difference of the slides of its bay's two ends."""
    stretch_modulus: np.ndarray = np.zeros(0)
    """EA of each segment (n - Y,) [N]: a sliding crossing changes its rest length."""
    bend_modulus: np.ndarray = np.zeros(0)
    """EI of each node's bending spring (n,) [N m^2] (0 at each chain's end nodes)."""
    lateral_bend_modulus: np.ndarray = np.zeros(0)
    """EI_lateral of each node's in-plane bending spring (n,) [N m^2] (spatial kinematics;
    empty in the plane)."""


def sliding(structure: Structure) -> bool:
    """Whether the structure's crossings slide along its chains (docs/model.md 11.13)."""
    return structure.physical_source.size > 0


def dim(structure: Structure) -> int:
    """Coordinates per node."""
    return structure.rest_position.shape[1]


def chain_count(structure: Structure) -> int:
    return structure.chain_start.size - 1


def chain_nodes(structure: Structure, y: int) -> slice:
    """The nodes of chain y."""
    return slice(int(structure.chain_start[y]), int(structure.chain_start[y + 1]))


def chain_segments(structure: Structure, y: int) -> slice:
    """The segments of chain y in `rest_length`, `stretch_stiffness`."""
    return slice(int(structure.chain_start[y]) - y, int(structure.chain_start[y + 1]) - y - 1)


def chain_of_node(structure: Structure) -> np.ndarray:
    """The chain of every node (n,), int64."""
    return np.repeat(np.arange(chain_count(structure)), np.diff(structure.chain_start))


def grounded(structure: Structure) -> bool:
    """Every tie is to ground and no dof moves as another chain's: the chains are independent,
    each with a banded Hessian (the static solver's banded path, docs/model.md section 6)."""
    if np.any(structure.tie_b != GROUND) or structure.plane_nodes_a.size \
            or structure.plane_nodes_b.size or np.any(structure.wrap_stiffness > 0.0):
        return False
    tied = np.flatnonzero(structure.dof_tie >= 0)
    if tied.size == 0:
        return True
    node_chain = chain_of_node(structure)
    d = dim(structure)
    return bool(np.all(node_chain[tied // d] == node_chain[structure.dof_tie[tied] // d]))


def chain_ties(structure: Structure, y: int) -> np.ndarray:
    """The ties whose node a lies on chain y, in order of that node (int64)."""
    nodes = chain_nodes(structure, y)
    own = np.flatnonzero((structure.tie_a >= nodes.start) & (structure.tie_a < nodes.stop))
    return own[np.argsort(structure.tie_a[own], kind="stable")]


def tie_layout(structure: Structure, y: int) -> tuple[np.ndarray, np.ndarray]:
    """(ties of chain y (`chain_ties`), their node a within the chain) (int64)."""
    ties = chain_ties(structure, y)
    return ties, structure.tie_a[ties] - structure.chain_start[y]


def uniform(rows: np.ndarray) -> np.ndarray:
    """The one row every row of `rows` (k, ...) equals; a ValueError if they differ."""
    if rows.shape[0] and not np.all(rows == rows[:1]):
        raise ValueError("the ties of a chain differ in their laws")
    return rows[0] if rows.shape[0] else np.zeros(rows.shape[1:])
