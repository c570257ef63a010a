"""A clamped patch of woven fabric as one flat node array, for node-parallel kernels (MODEL.md 10).

Both yarn families are chains (MODEL.md 10). Every node of every yarn is one entry of
one flat array: warp k's nodes first (k = 1..n_wa, N+1 nodes each), then weft j's
(j = 1..n_we, M+1 nodes each). A node's two coordinates are (s, z): s = x along a
warp, s = y along a weft (yarns stay straight in plan view, MODEL.md 10). Each node
knows its chain neighbours (`previous`, `next`, -1 past an end), so a thread can
gather its own stretch and bending forces without touching another thread's
output, and at most one crossing: in a plain weave the crossings of one yarn sit at
distinct nodes, so the per-node list of incident crossings has length 0 or 1 and is
stored as one index (`node_crossing`, -1 for none).

The geometry (MODEL.md 10): warp k in the plane y = Y_k, z = s_k A_wa sin(n_we pi x / L),
s_k = (-1)^(k-1); weft j in x = X_j, z = -(-1)^(j-1) A_we sin(n_wa pi y / L_we);
crossing (j, k) joins warp k's node (2j-1) N / (2 n_we) and weft j's node
(2k-1) M / (2 n_wa), the warp on side sigma_jk = s_k (-1)^(j-1). Closure
g = sigma ((z0_wa - z0_we) - (z_wa - z_we)) = c - sigma (z_wa - z_we) with
c = sigma (z0_wa - z0_we). Clamped boundary: every yarn's first node pinned, its last
node held in z and loaded along the yarn (force control).
"""

import functools
from dataclasses import dataclass

import numpy as np
import warp as wp

from dynfab import geometry
from dynfab.kernels.precision import VECTORS, numpy_dtype


@dataclass(frozen=True, kw_only=True)
class Family:
    """One yarn family's parameters (MODEL.md 2, 3, 10)."""

    EA: float
    """Extensional stiffness [N]."""
    EI: float
    """Bending stiffness [N m^2]."""
    amplitude: float
    """Crimp amplitude A [m]."""
    kawabata_C: float
    """Kawabata C [m]."""
    kawabata_K: float
    """Kawabata K [m/N]."""


@dataclass(frozen=True, kw_only=True)
class Friction:
    """Gralen's law with its onset, as isotropic stick-slip at every crossing (MODEL.md 4, 10)."""

    alpha: float
    """Gralen alpha [-]."""
    beta: float
    """Gralen beta [N/m^2]."""
    contact_length: float
    """ell [m]."""
    fiber_radius: float
    """r_f [m]."""
    onset_force: float = 1e-5
    """R_0 [N]."""
    stick_stiffness: float | None = None
    """k_t [N/m]; None: the smaller family's EA / segment length (MODEL.md 10)."""


@dataclass(frozen=True, kw_only=True)
class Patch:
    """A clamped n_wa x n_we patch from plain parameters (MODEL.md 10)."""

    warps: int
    """n_wa, the number of warp yarns (= crossings along a weft)."""
    wefts: int
    """n_we, the number of weft yarns (= crossings along a warp)."""
    length: float
    """L, projected warp length [m]."""
    weft_length: float
    """L_we, projected weft length [m]."""
    segments: int
    """N, segments per warp (a multiple of 2 n_we)."""
    weft_segments: int
    """M, segments per weft (a multiple of 2 n_wa)."""
    warp: Family
    weft: Family
    core_stiffness: float = 1e5
    """k_c [N/m], in series with both Kawabata laws (MODEL.md 10)."""
    friction: Friction | None = None
    """None: frictionless crossings."""


PAPER_WARP = Family(EA=13.72, EI=1.47e-7, amplitude=0.5e-3, kawabata_C=0.2e-3, kawabata_K=0.2)
"""The paper's yarn (MODEL.md 7), used for both families by the tests and the benchmark."""


def paper_patch(warps: int, wefts: int, segments_per_half_wave: int = 8, pitch: float = 6.25e-3,
                core_stiffness: float = 1e5) -> Patch:
    """A balanced patch of the paper's yarn: pitch L / n_we = L_we / n_wa (the paper's
    0.1 m / 16 by default), N = segments_per_half_wave x n_we, M likewise."""
    return Patch(warps=warps, wefts=wefts, length=pitch * wefts, weft_length=pitch * warps,
                 segments=segments_per_half_wave * wefts, weft_segments=segments_per_half_wave * warps,
                 warp=PAPER_WARP, weft=PAPER_WARP, core_stiffness=core_stiffness)


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
    """(n, 2) 1 for a free dof, 0 for a held one."""
    node_crossing: np.ndarray
    """(n,) the node's crossing, -1 for none."""
    node_side: np.ndarray
    """(n,) z-force per unit R on the node: +sigma on the warp node, -sigma on the weft node."""
    crossing_warp: np.ndarray
    """(C,) warp node of crossing (j, k), C = n_wa n_we, index (k-1) n_we + (j-1)."""
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
    """(n, 2) the unit end load along a warp (+1 on x_N of every warp) [-]."""
    weft_load_direction: np.ndarray
    """(n, 2) the same for the wefts (+1 on y_M of every weft) [-]."""

    @property
    def nodes(self) -> int:
        return self.rest_position.shape[0]

    @property
    def crossings(self) -> int:
        return self.crossing_warp.shape[0]


def _chain(positions: np.ndarray, family: Family) -> dict:
    """Per-node arrays of one chain (MODEL.md 2): l0, EA/l0, EI/lbar, phi0."""
    rest_length = geometry.segment_lengths(positions)
    lbar = geometry.voronoi_lengths(rest_length)
    bend = family.EI / lbar
    bend[[0, -1]] = 0.0
    return {"rest_length": np.append(rest_length, 0.0),
            "stretch_stiffness": np.append(family.EA / rest_length, 0.0),
            "bend_stiffness": bend, "rest_angle": geometry.turning_angles(positions)}


def build(patch: Patch) -> PatchArrays:
    """The arrays of a clamped patch (MODEL.md 10), force control on every yarn's last node."""
    n_wa, n_we, N, M = patch.warps, patch.wefts, patch.segments, patch.weft_segments
    if N % (2 * n_we) or M % (2 * n_wa):
        raise ValueError("segments must be a multiple of 2 n_we, weft_segments of 2 n_wa")
    chains, start = [], 0
    warp_nodes = np.arange(n_wa * (N + 1), dtype=np.int32).reshape(n_wa, N + 1)
    weft_nodes = (n_wa * (N + 1) + np.arange(n_we * (M + 1), dtype=np.int32)).reshape(n_we, M + 1)
    for k in range(n_wa):
        chains.append((geometry.as_woven_positions(patch.length, N, n_we, patch.warp.amplitude,
                                                   (-1.0) ** k), patch.warp))
    for j in range(n_we):
        chains.append((geometry.as_woven_positions(patch.weft_length, M, n_wa, patch.weft.amplitude,
                                                   -(-1.0) ** j), patch.weft))
    fields = {name: [] for name in ("rest_length", "stretch_stiffness", "bend_stiffness", "rest_angle")}
    previous, following, positions = [], [], []
    for chain, family in chains:
        count = chain.shape[0]
        index = start + np.arange(count, dtype=np.int32)
        previous.append(np.where(np.arange(count) > 0, index - 1, -1))
        following.append(np.where(np.arange(count) < count - 1, index + 1, -1))
        positions.append(chain)
        for name, values in _chain(chain, family).items():
            fields[name].append(values)
        start += count
    rest = np.concatenate(positions)
    n = rest.shape[0]
    free = np.ones((n, 2))
    load_wa, load_we = np.zeros((n, 2)), np.zeros((n, 2))
    for nodes, load in ((warp_nodes, load_wa), (weft_nodes, load_we)):
        free[nodes[:, 0]] = 0.0        # first node pinned (s and z)
        free[nodes[:, -1], 1] = 0.0    # last node held in z, free along the yarn
        load[nodes[:, -1], 0] = 1.0
    warp_crossing = geometry.crossing_nodes(N, n_we)   # index j-1
    weft_crossing = geometry.crossing_nodes(M, n_wa)   # index k-1
    k, j = np.meshgrid(np.arange(n_wa), np.arange(n_we), indexing="ij")
    crossing_warp = warp_nodes[k, warp_crossing[j]].ravel()
    crossing_weft = weft_nodes[j, weft_crossing[k]].ravel()
    sigma = ((-1.0) ** k * (-1.0) ** j).ravel()
    offset = sigma * (rest[crossing_warp, 1] - rest[crossing_weft, 1])
    node_crossing = np.full(n, -1, dtype=np.int32)
    node_side = np.zeros(n)
    node_crossing[crossing_warp] = np.arange(sigma.size)
    node_crossing[crossing_weft] = np.arange(sigma.size)
    node_side[crossing_warp], node_side[crossing_weft] = sigma, -sigma
    return PatchArrays(
        rest_position=rest, previous=np.concatenate(previous).astype(np.int32),
        next=np.concatenate(following).astype(np.int32),
        **{name: np.concatenate(values) for name, values in fields.items()},
        free=free, node_crossing=node_crossing, node_side=node_side,
        crossing_warp=crossing_warp.astype(np.int32), crossing_weft=crossing_weft.astype(np.int32),
        crossing_side=sigma, crossing_offset=offset, contact_law=contact_law(patch),
        friction_law=friction_law(patch),
        warp_nodes=warp_nodes, weft_nodes=weft_nodes, load_direction=load_wa,
        weft_load_direction=load_we)


def contact_law(patch: Patch) -> np.ndarray:
    """(k_c, C_wa, a_wa, C_we, a_we), a_m = K_m / Lc_m with each family's half-wave (MODEL.md 3, 10)."""
    lc_wa = geometry.half_wave_arc_length(patch.length / patch.wefts, patch.warp.amplitude)
    lc_we = geometry.half_wave_arc_length(patch.weft_length / patch.warps, patch.weft.amplitude)
    return np.array([patch.core_stiffness, patch.warp.kawabata_C, patch.warp.kawabata_K / lc_wa,
                     patch.weft.kawabata_C, patch.weft.kawabata_K / lc_we])


def friction_law(patch: Patch) -> np.ndarray:
    """(alpha, beta ell r_f, R_0, k_t) (MODEL.md 4, 10); zeros without friction."""
    friction = patch.friction
    if friction is None:
        return np.zeros(4)
    stick = friction.stick_stiffness or min(patch.warp.EA / (patch.length / patch.segments),
                                            patch.weft.EA / (patch.weft_length / patch.weft_segments))
    return np.array([friction.alpha, friction.beta * friction.contact_length * friction.fiber_radius,
                     friction.onset_force, stick])


GERSHGORIN_SAFETY = 0.9
"""dt / the stable time step of the Gershgorin masses [-]."""


def gershgorin_masses(arrays: PatchArrays, dt: float, safety: float = GERSHGORIN_SAFETY) -> np.ndarray:
    """Fictitious masses (n,) [kg] with m_i >= dt^2/4 sum_j |K_ij| / safety^2 (MODEL.md 5).

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

