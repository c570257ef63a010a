"""A clamped patch of woven fabric as one flat node array, for node-parallel kernels
(docs/model.md section 10).

The geometry and the parameters are the static reference's: `build(spec)` takes a
`dynfab.fabric.spec.FabricSpec` and lays it out through `dynfab.fabric.layout` (the
node order, the crossings and their sides, the fixed dofs, the masses, the contact
law with k_c and the stick stiffness k_t), then adds what node-parallel kernels need.
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
c = sigma (z0_wa - z0_we) (the layout's gap offset). The kernels keep the planes
X_j, Y_k fixed at the crossing nodes' as-woven in-plane coordinates and have no wrap
springs or tied dofs: `build` refuses the periodic cell and moving ("affine") planes.
"""

import functools
from dataclasses import dataclass, replace

import numpy as np
import warp as wp

from dynfab.fabric import layout
from dynfab.fabric.spec import FabricSpec, Family, Friction
from dynfab.kernels.precision import VECTORS, numpy_dtype

PAPER_YARN = Family(length=0.1, segments=128, amplitude=0.5e-3, EA=13.72, EI=1.47e-7,
                    kawabata_C=0.2e-3, kawabata_K=0.2)
"""The paper's yarn (docs/model.md section 7), used for both families by the tests and the benchmark
(length and segments are set per patch by `paper_patch`)."""
PAPER_FRICTION = Friction(alpha=0.2, beta=1e3, contact_length=2e-3, fiber_radius=1e-3)
"""The paper's Gralen parameters (docs/model.md section 7), R_0 = 1e-5 N."""


def paper_patch(warps: int, wefts: int, segments_per_half_wave: int = 8, pitch: float = 6.25e-3,
                core_stiffness: float = 1e5, **more) -> FabricSpec:
    """A balanced clamped patch of the paper's yarn: pitch L / n_we = L_we / n_wa (the paper's
    0.1 m / 16 by default), N = segments_per_half_wave x n_we, M likewise; `more`: other
    FabricSpec fields (friction, control, load path...)."""
    return FabricSpec(
        warp=replace(PAPER_YARN, length=pitch * wefts, segments=segments_per_half_wave * wefts),
        weft=replace(PAPER_YARN, length=pitch * warps, segments=segments_per_half_wave * warps),
        warps=warps, wefts=wefts, core_stiffness=core_stiffness, **more)


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

    @property
    def nodes(self) -> int:
        return self.rest_position.shape[0]

    @property
    def crossings(self) -> int:
        return self.crossing_warp.shape[0]


def build(spec: FabricSpec) -> PatchArrays:
    """The arrays of the clamped patch `spec` (docs/model.md section 10), from
    `dynfab.fabric.layout`."""
    if spec.boundary != "clamped" or spec.planes != "fixed":
        raise ValueError("the fabric kernels model the clamped patch with fixed planes only")
    fabric = layout.build_fabric(spec)
    start = fabric.yarn_start
    n, yarns = start[-1], start.size - 1
    yarn_of_node = np.repeat(np.arange(yarns), np.diff(start))
    first, last = start[:-1], start[1:] - 1
    index = np.arange(n, dtype=np.int32)
    previous = np.where(np.isin(index, first), -1, index - 1).astype(np.int32)
    following = np.where(np.isin(index, last), -1, index + 1).astype(np.int32)
    has_segment = following >= 0
    rest_length, stretch = np.zeros(n), np.zeros(n)
    segment = index[has_segment] - yarn_of_node[has_segment]  # the layout's segment index
    rest_length[has_segment] = fabric.rest_length[segment]
    stretch[has_segment] = fabric.stretch_stiffness[segment]
    C = fabric.warp_node.size
    node_crossing = np.full(n, -1, dtype=np.int32)
    node_side = np.zeros(n)
    node_crossing[fabric.warp_node] = np.arange(C)
    node_crossing[fabric.weft_node] = np.arange(C)
    node_side[fabric.warp_node], node_side[fabric.weft_node] = fabric.side, -fabric.side
    load_wa, load_we = np.zeros((n, 2)), np.zeros((n, 2))
    load_wa[last[fabric.is_warp], 0] = fabric.load_factor[fabric.is_warp]
    load_we[last[~fabric.is_warp], 0] = fabric.load_factor[~fabric.is_warp]
    weight = np.zeros((n, 2))
    weight[:, 1] = -fabric.mass * fabric.gravity
    nodes_of = [np.arange(a, b, dtype=np.int32) for a, b in zip(first, last + 1)]
    return PatchArrays(
        rest_position=fabric.rest_position.copy(), previous=previous, next=following,
        rest_length=rest_length, stretch_stiffness=stretch,
        bend_stiffness=fabric.bend_stiffness.copy(), rest_angle=fabric.rest_angle.copy(),
        free=(~fabric.fixed).reshape(n, 2).astype(float), node_crossing=node_crossing,
        node_side=node_side, crossing_warp=fabric.warp_node.astype(np.int32),
        crossing_weft=fabric.weft_node.astype(np.int32), crossing_side=fabric.side.copy(),
        crossing_offset=fabric.gap_offset.copy(), contact_law=fabric.contact_law.copy(),
        friction_law=friction_law(spec),
        warp_nodes=np.array(nodes_of[:spec.warps]), weft_nodes=np.array(nodes_of[spec.warps:]),
        load_direction=load_wa, weft_load_direction=load_we, weight=weight)


def friction_law(spec: FabricSpec) -> np.ndarray:
    """(alpha, beta ell r_f, R_0, k_t) (docs/model.md sections 4, 10), k_t from
    `layout.stick_stiffness`; zeros without friction."""
    friction = spec.friction
    if friction is None:
        return np.zeros(4)
    return np.array([friction.alpha, friction.beta * friction.contact_length * friction.fiber_radius,
                     friction.onset_force, layout.stick_stiffness(spec)])


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
    return dt ** 2 / 4.0 * rows / safety ** 2


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

    return FabricArrays


VECTOR_FIELDS = ("rest_position", "free")
INDEX_FIELDS = ("previous", "next", "node_crossing", "crossing_warp", "crossing_weft")
SCALAR_FIELDS = ("rest_length", "stretch_stiffness", "bend_stiffness", "rest_angle", "node_side",
                 "crossing_side", "crossing_offset", "contact_law", "friction_law")


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

