"""As-woven geometry of the fabric and its model arrays (docs/model.md section 10).

Every yarn is a planar chain in its own vertical plane: warp k in y = Y_k with
nodes (x, z), weft j in x = X_j with nodes (y, z). All nodes sit in one array
`positions` (nodes, 2), column 0 the in-plane coordinate along the yarn, column 1 z;
warps first (warp k's nodes at yarn_start[k]..yarn_start[k+1]-1), then wefts. Dof
2 n is node n's in-plane coordinate, 2 n + 1 its z: each yarn's dofs are contiguous,
so the Hessian is one band per yarn plus the crossing couplings.

Crossing c = k n_we + j (0-based warp k, weft j) joins warp k's node
(2j+1) N / (2 n_we) and weft j's node (2k+1) M / (2 n_wa).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from dynfab import geometry
from dynfab.fabric.spec import FabricSpec
from dynfab.terms.friction import law_constants


class Fabric(NamedTuple):
    """Arrays of a fabric (docs/model.md section 10); passed whole to numba. Y yarns, C
    crossings."""

    rest_position: np.ndarray
    """As-woven (in-plane coordinate, z) of every node (nodes, 2) [m]."""
    yarn_start: np.ndarray
    """First node of each yarn, and the node count at the end (Y+1,), int64."""
    rest_length: np.ndarray
    """Segment rest lengths l0, yarn after yarn (nodes - Y,) [m]; yarn y's segments
    start at yarn_start[y] - y."""
    stretch_stiffness: np.ndarray
    """EA / l0 per segment (nodes - Y,) [N/m]."""
    bend_stiffness: np.ndarray
    """EI / lbar per node (nodes,) [N m]; 0 at each yarn's end nodes."""
    rest_angle: np.ndarray
    """As-woven turning angles phi0 per node (nodes,) [rad]."""
    mass: np.ndarray
    """Physical lumped masses rho_l lbar per node (nodes,) [kg]."""
    gravity: float
    """g [m/s^2]; 0 without gravity."""
    warp_node: np.ndarray
    """Warp node of each crossing (C,), int64 (global node index)."""
    weft_node: np.ndarray
    """Weft node of each crossing (C,), int64."""
    side: np.ndarray
    """sigma_jk, +1 where the warp lies above the weft (C,) [-]."""
    gap_offset: np.ndarray
    """sigma (z0_wa - z0_we) (C,) [m]: g = gap_offset - sigma (z_wa - z_we)."""
    plane_x: np.ndarray
    """X_j of each crossing (C,) [m] (planes fixed)."""
    plane_y: np.ndarray
    """Y_k of each crossing (C,) [m] (as woven)."""
    plane_weight_x: np.ndarray
    """w_j with X_j = plane_x + w_j u_wa (C,) [-], u_wa the mean end displacement of the
    warps (the nodes `plane_nodes_x`): (j - 1/2) / n_we when the planes move (periodic
    cell, or planes "affine"), else 0."""
    plane_weight_y: np.ndarray
    """The same for Y_k and the wefts (C,) [-]."""
    plane_nodes_x: np.ndarray
    """The warp end nodes whose mean displacement moves the planes X_j (n_wa,), int64;
    empty when the planes are fixed."""
    plane_nodes_y: np.ndarray
    """The weft end nodes moving Y_k (n_we,), int64; empty when fixed."""
    wrap_stiffness: np.ndarray
    """EI / lbar_0 of the bending spring at node 0 across the periodic wrap (Y,) [N m];
    0 on a clamped patch."""
    wrap_rest_angle: np.ndarray
    """As-woven turning angle across the wrap (Y,) [rad]."""
    tie: np.ndarray
    """Per dof (2 nodes,), int64: -1, or the dof it is tied to (periodic force control:
    every warp's x_N is the cell length L1, held in warp 0's x_N; likewise the wefts)."""
    contact_law: np.ndarray
    """(k_c [N/m], C_wa [m], a_wa [1/N], C_we [m], a_we [1/N]) (docs/model.md sections 3, 10)."""
    friction_alpha: float
    """Gralen alpha [-]; 0 without friction."""
    friction_constant: float
    """beta ell r_f [N]; 0 without friction."""
    friction_onset: float
    """R_0 [N]."""
    stick_stiffness: float
    """k_t [N/m]; 0 without friction."""
    has_friction: bool
    load_node: np.ndarray
    """Last node of each yarn (Y,), int64: where the yarn is loaded along itself."""
    load_factor: np.ndarray
    """Per-yarn load factor (Y,) [-]."""
    is_warp: np.ndarray
    """True for the warp yarns (Y,)."""
    fixed: np.ndarray
    """Fixed dofs (2 nodes,) bool (docs/model.md section 10, boundary "clamped")."""


def warp_shape(spec: FabricSpec, k: int) -> np.ndarray:
    """Warp k (0-based) as woven: x_i = i L / N, z = s_k A_wa sin(n_we pi x / L), s_k = (-1)^k."""
    return geometry.as_woven_positions(spec.warp.length, spec.warp.segments, spec.wefts,
                                       spec.warp.amplitude, (-1.0) ** k)


def weft_shape(spec: FabricSpec, j: int) -> np.ndarray:
    """Weft j (0-based) as woven: y_i = i L_we / M, z = -(-1)^j A_we sin(n_wa pi y / L_we)."""
    return geometry.as_woven_positions(spec.weft.length, spec.weft.segments, spec.warps,
                                       spec.weft.amplitude, -((-1.0) ** j))


def build_fabric(spec: FabricSpec) -> Fabric:
    """The model arrays of `spec` (docs/model.md section 10)."""
    shapes = [warp_shape(spec, k) for k in range(spec.warps)]
    shapes += [weft_shape(spec, j) for j in range(spec.wefts)]
    families = [spec.warp] * spec.warps + [spec.weft] * spec.wefts
    start = np.concatenate([[0], np.cumsum([s.shape[0] for s in shapes])]).astype(np.int64)
    rest = np.concatenate(shapes)
    rest_length, stretch, bend, angle, mass = [], [], [], [], []
    for shape, family in zip(shapes, families):
        l0 = geometry.segment_lengths(shape)
        lbar = geometry.voronoi_lengths(l0)
        mass.append(family.linear_density * lbar)
        kb = family.EI / lbar
        kb[[0, -1]] = 0.0
        rest_length.append(l0)
        stretch.append(family.EA / l0)
        bend.append(kb)
        angle.append(geometry.turning_angles(shape))
    warp_node, weft_node, side = _crossings(spec, start)
    periodic = spec.boundary == "periodic"
    moving = periodic or spec.planes == "affine"
    wrap_k, wrap_angle = np.zeros(len(shapes)), np.zeros(len(shapes))
    if periodic:
        for y, (shape, family) in enumerate(zip(shapes, families)):
            wrap_k[y], wrap_angle[y] = _wrap_spring(shape, family)
    x_planes = (np.arange(spec.wefts) + 0.5) * spec.warp.length / spec.wefts
    y_planes = (np.arange(spec.warps) + 0.5) * spec.weft.length / spec.warps
    friction = spec.friction
    yarns = spec.warps + spec.wefts
    alpha, constant, onset = law_constants(friction)  # Gralen, docs/model.md section 4
    return Fabric(
        rest_position=rest, yarn_start=start,
        rest_length=np.concatenate(rest_length), stretch_stiffness=np.concatenate(stretch),
        bend_stiffness=np.concatenate(bend), rest_angle=np.concatenate(angle),
        mass=np.concatenate(mass), gravity=float(spec.gravity or 0.0),
        warp_node=warp_node, weft_node=weft_node, side=side,
        gap_offset=side * (rest[warp_node, 1] - rest[weft_node, 1]),
        plane_x=np.tile(x_planes, spec.warps), plane_y=np.repeat(y_planes, spec.wefts),
        plane_weight_x=np.tile(x_planes / spec.warp.length, spec.warps) * moving,
        plane_weight_y=np.repeat(y_planes / spec.weft.length, spec.wefts) * moving,
        plane_nodes_x=(start[1:spec.warps + 1] - 1) if moving else np.zeros(0, np.int64),
        plane_nodes_y=(start[spec.warps + 1:] - 1) if moving else np.zeros(0, np.int64),
        wrap_stiffness=wrap_k, wrap_rest_angle=wrap_angle,
        tie=ties(spec, start),
        contact_law=contact_law(spec),
        friction_alpha=alpha, friction_constant=constant, friction_onset=onset,
        stick_stiffness=stick_stiffness(spec),
        has_friction=friction is not None,
        load_node=start[1:] - 1,
        load_factor=load_factors(spec),
        is_warp=np.arange(yarns) < spec.warps,
        fixed=fixed_dofs(spec, start),
    )


def _wrap_spring(shape: np.ndarray, family) -> tuple[float, float]:
    """(EI / lbar_0, as-woven angle) of the bending spring at node 0 of a periodic yarn,
    between segment N-1's image (shifted back by the cell length) and segment 0."""
    l0 = geometry.segment_lengths(shape)
    a, b = shape[-1] - shape[-2], shape[1] - shape[0]
    angle = float(np.arctan2(a[0] * b[1] - a[1] * b[0], a @ b))
    return family.EI / (0.5 * (l0[0] + l0[-1])), angle


def ties(spec: FabricSpec, start: np.ndarray) -> np.ndarray:
    """Periodic cell under force control: x_N of every warp tied to warp 0's (the cell
    length L1), y_M of every weft to weft 0's (L2); -1 elsewhere (docs/model.md section 10)."""
    tie = np.full(2 * start[-1], -1, np.int64)
    if spec.boundary == "periodic" and spec.control == "force":
        last = start[1:] - 1
        tie[2 * last[1:spec.warps]] = 2 * last[0]
        tie[2 * last[spec.warps + 1:]] = 2 * last[spec.warps]
    return tie


def _crossings(spec: FabricSpec, start: np.ndarray):
    """(warp node, weft node, sigma) of crossing c = k n_we + j (docs/model.md section 10).

    sigma_jk = s_k (-1)^(j-1) in 1-based indices, (-1)^(k + j) in 0-based ones.
    """
    k, j = np.divmod(np.arange(spec.warps * spec.wefts), spec.wefts)
    warp_node = start[k] + (2 * j + 1) * spec.warp.segments // (2 * spec.wefts)
    weft_node = start[spec.warps + j] + (2 * k + 1) * spec.weft.segments // (2 * spec.warps)
    side = np.where((k + j) % 2 == 0, 1.0, -1.0)
    return warp_node.astype(np.int64), weft_node.astype(np.int64), side


def contact_law(spec: FabricSpec) -> np.ndarray:
    """(k_c, C_wa, a_wa, C_we, a_we), a_m = K_m / Lc_m with each family's half-wave Lc."""
    lc_warp = geometry.half_wave_arc_length(spec.warp.length / spec.wefts, spec.warp.amplitude)
    lc_weft = geometry.half_wave_arc_length(spec.weft.length / spec.warps, spec.weft.amplitude)
    return np.array([spec.core_stiffness, spec.warp.kawabata_C, spec.warp.kawabata_K / lc_warp,
                     spec.weft.kawabata_C, spec.weft.kawabata_K / lc_weft])


def stick_stiffness(spec: FabricSpec) -> float:
    """k_t [N/m]: the given one, else the smaller family's EA / segment length
    (docs/model.md section 10)."""
    if spec.friction is None:
        return 0.0
    if spec.friction.stick_stiffness is not None:
        return float(spec.friction.stick_stiffness)
    return min(spec.warp.EA * spec.warp.segments / spec.warp.length,
               spec.weft.EA * spec.weft.segments / spec.weft.length)


def load_factors(spec: FabricSpec) -> np.ndarray:
    """Per-yarn load factors (Y,): the given ones (default 1). A pull-out loads its warp
    with factor 1, holds the other warps at their as-woven ends (factor 0) and loads the
    wefts with their factors (default 1), so `weft_values` can tension the wefts first and
    press the crossings (docs/model.md, decisions: what presses a pulled-out warp)."""
    if spec.pullout is not None:
        factors = np.zeros(spec.warps + spec.wefts)
        factors[spec.pullout - 1] = 1.0
        factors[spec.warps:] = spec.weft_factors or np.ones(spec.wefts)
        return factors
    return np.concatenate([spec.warp_factors or np.ones(spec.warps),
                           spec.weft_factors or np.ones(spec.wefts)]).astype(float)


def fixed_dofs(spec: FabricSpec, start: np.ndarray) -> np.ndarray:
    """Clamped patch: each yarn's first node pinned, its last node's z held, and under
    displacement control its last node's in-plane coordinate prescribed; a held family
    has every dof fixed; a pull-out frees its warp's first node (docs/model.md section 10). The
    periodic cell alike: node 0 held at its
    as-woven position, node N (node 0's image) at z = z_0 and at the cell length,
    prescribed (displacement control) or tied across the family (force control)."""
    fixed = np.zeros(2 * start[-1], dtype=np.bool_)
    first, last = start[:-1], start[1:] - 1
    fixed[2 * first] = fixed[2 * first + 1] = True
    fixed[2 * last + 1] = True
    if spec.control == "displacement":
        fixed[2 * last] = True
    if spec.pullout is not None:  # the pulled warp's first node free
        fixed[2 * first[spec.pullout - 1]] = fixed[2 * first[spec.pullout - 1] + 1] = False
    if spec.hold != "none":
        yarns = range(spec.warps) if spec.hold == "warp" else range(spec.warps, len(first))
        for y in yarns:
            fixed[2 * start[y]:2 * start[y + 1]] = True
    return fixed

