"""The woven fabric as a structure: warps and wefts alike as chains, tied at every crossing
(docs/model.md section 10).

Every yarn is a chain in its own vertical plane: warp k in y = Y_k with nodes (x, z), weft j
in x = X_j with nodes (y, z). The warps come first (warp k's nodes at chain_start[k] ..),
then the wefts; each yarn's dofs are contiguous, so the Hessian is one band per yarn plus
the crossing couplings.

Crossing c = k n_we + j (0-based warp k, weft j) is the tie of warp k's node
(2j+1) N / (2 n_we) (node a) and weft j's node (2k+1) M / (2 n_wa) (node b), the warp on
side sigma_jk = (-1)^(k + j), the closure g = sigma ((z0_a - z0_b) - (z_a - z_b)); its
slips are x_a - X_j and y_b - Y_k from their anchors.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from dynfab.model import geometry
from dynfab.model.builders import woven_rest
from dynfab.model.builders.sliding import crossings_as_they_move
from dynfab.model.builders.woven_rest import woven_closure
from dynfab.scene import DEFAULT_CORE_STIFFNESS, Scene
from dynfab.model.structure import Structure
from dynfab.model.terms import nodes as node_terms
from dynfab.model.terms.friction import law_constants

DEFAULT_LINEAR_DENSITY = 3e-5
"""rho_l [kg/m] of the wefts without weft.linear_density (as the warps' default)."""


class Family(NamedTuple):
    """One yarn family of a fabric scene (docs/model.md section 10), SI units."""

    length: float
    """Yarn length along its in-plane axis [m] (L for the warps, L_we for the wefts)."""
    segments: int
    amplitude: float
    EA: float
    EI: float
    kawabata_C: float
    kawabata_K: float
    linear_density: float
    count: int
    """Yarns of the family."""


def families(scene: Scene) -> tuple[Family, Family]:
    """(warps, wefts) of a validated fabric scene."""
    g, warp, weft = scene.geometry, scene.warp, scene.weft
    return (Family(g.length, g.segments, g.amplitude, warp.EA, warp.EI, warp.kawabata_C,
                   warp.kawabata_K, warp.linear_density, weft.count),
            Family(weft.length, weft.segments, weft.amplitude, weft.EA, weft.EI, weft.kawabata_C,
                   weft.kawabata_K, weft.linear_density or DEFAULT_LINEAR_DENSITY, g.crossings))


def warp_shape(warp: Family, wefts: int, k: int) -> np.ndarray:
    """Warp k (0-based) as woven: x_i = i L / N, z = s_k A_wa sin(n_we pi x / L), s_k = (-1)^k."""
    return geometry.as_woven_positions(warp.length, warp.segments, wefts, warp.amplitude,
                                       (-1.0) ** k)


def weft_shape(weft: Family, warps: int, j: int) -> np.ndarray:
    """Weft j (0-based) as woven: y_i = i L_we / M, z = -(-1)^j A_we sin(n_wa pi y / L_we)."""
    return geometry.as_woven_positions(weft.length, weft.segments, warps, weft.amplitude,
                                       -((-1.0) ** j))


def fabric_structure(scene: Scene) -> Structure:
    """The structure of a validated fabric scene (docs/model.md section 10)."""
    warp, weft = families(scene)
    shapes = [warp_shape(warp, weft.count, k) for k in range(warp.count)]
    shapes += [weft_shape(weft, warp.count, j) for j in range(weft.count)]
    members = [warp] * warp.count + [weft] * weft.count
    start = np.concatenate([[0], np.cumsum([s.shape[0] for s in shapes])]).astype(np.int64)
    rest = np.concatenate(shapes)
    tie_a, tie_b, side = _crossings(warp, weft, start)
    preload = scene.crossing.preload if scene.crossing is not None else 0.0
    load = woven_rest.crossing_loads(rest.shape[0], tie_a, tie_b, side, preload)
    spacings = [warp.length / weft.count] * warp.count + [weft.length / warp.count] * weft.count
    g = scene.geometry
    periodic = g.boundary == "periodic"
    moving = periodic or g.planes == "affine"
    yarns = len(shapes)
    wrap_k, wrap_angle = np.zeros(yarns), np.zeros(yarns)
    fixed = _fixed_dofs(scene, start)
    free = woven_rest.free_ends(fixed, start, 2)
    rest_length, stretch, bend, angle, mass = [], [], [], [], []
    for y, (shape, family) in enumerate(zip(shapes, members)):
        if preload > 0.0 and free[y].any():
            woven_rest.check_free_end(preload, spacings[y], family.EI, family.amplitude,
                                      "warp" if y < warp.count else "weft")
        l0, phi0, moment = _rest_shape(shape, family, load[start[y]:start[y + 1]], spacings[y])
        lbar = geometry.voronoi_lengths(l0)
        mass.append(family.linear_density * lbar)
        kb = family.EI / lbar
        kb[[0, -1]] = 0.0
        rest_length.append(l0)
        stretch.append(family.EA / l0)
        bend.append(kb)
        angle.append(woven_rest.rest_turnings(phi0, moment, kb))
        if periodic:
            wrap_k[y], wrap_angle[y] = _wrap_spring(shape, family, l0, moment[0])
    ties = tie_a.size
    x_planes = (np.arange(weft.count) + 0.5) * warp.length / weft.count
    y_planes = (np.arange(warp.count) + 0.5) * weft.length / warp.count
    friction_law = np.tile(_friction_law(scene, warp, weft), (ties, 1))
    law = _contact_law(scene, warp, weft)
    made = crossings_as_they_move(scene)
    return made(node_terms.attach(scene, Structure(
        rest_position=rest, mass=np.concatenate(mass),
        gravity=np.full(rest.shape[0], float(scene.gravity.g) if scene.gravity else 0.0),
        chain_start=start, chain_family=(np.arange(yarns) >= warp.count).astype(np.int64),
        chain_plane=np.concatenate([y_planes, x_planes]),
        rest_length=np.concatenate(rest_length), stretch_stiffness=np.concatenate(stretch),
        bend_stiffness=np.concatenate(bend), rest_angle=np.concatenate(angle),
        wrap_stiffness=wrap_k, wrap_rest_angle=wrap_angle,
        load_node=start[1:] - 1, load_factor=_load_factors(scene, warp, weft),
        tie_a=tie_a, tie_b=tie_b, tie_side=side,
        tie_gap_offset=side * (rest[tie_a, 1] - rest[tie_b, 1]) + woven_closure(preload, law),
        tie_contact_law=np.tile(law, (ties, 1)),
        tie_friction_law=friction_law,
        tie_plane=np.stack([np.tile(x_planes, warp.count), np.repeat(y_planes, weft.count)],
                           axis=1),
        tie_plane_weight=np.stack([np.tile(x_planes / warp.length, warp.count),
                                   np.repeat(y_planes / weft.length, weft.count)], axis=1) * moving,
        plane_nodes_a=(start[1:warp.count + 1] - 1) if moving else np.zeros(0, np.int64),
        plane_nodes_b=(start[warp.count + 1:] - 1) if moving else np.zeros(0, np.int64),
        has_friction=bool(np.any(friction_law[:, 3] > 0.0)),
        fixed=fixed, dof_tie=_dof_ties(scene, start, warp.count))))


def _rest_shape(shape: np.ndarray, family: Family, load: np.ndarray, spacing: float):
    """(rest lengths l0, woven turnings phi, moments M) of one yarn (N+1, 2) whose crossing
    nodes carry the z-forces `load` [N] of the woven-in contact (`dynfab.model.builders.woven_rest`;
    without a preload l0 the woven lengths and M zero, the as-woven state stress-free)."""
    length = geometry.segment_lengths(shape)
    turning = geometry.turning_angles(shape)
    if not np.any(load):
        return length, turning, np.zeros(shape.shape[0])
    e = np.diff(shape, axis=0)
    tension, moment = woven_rest.internal_forces(e[:, 0], e[:, 1], load, spacing)
    return woven_rest.rest_lengths(length, tension, family.EA), turning, moment


def _wrap_spring(shape: np.ndarray, family: Family, l0: np.ndarray,
                 moment: float) -> tuple[float, float]:
    """(EI / lbar_0, rest angle) of the bending spring at node 0 of a periodic yarn, between
    segment N-1's image (shifted back by the cell length) and segment 0: the as-woven angle
    less the woven-in moment over the stiffness (`woven_rest.rest_turnings`)."""
    a, b = shape[-1] - shape[-2], shape[1] - shape[0]
    angle = float(np.arctan2(a[0] * b[1] - a[1] * b[0], a @ b))
    stiffness = family.EI / (0.5 * (l0[0] + l0[-1]))
    return stiffness, angle - moment / stiffness


def _crossings(warp: Family, weft: Family, start: np.ndarray):
    """(warp node, weft node, sigma) of crossing c = k n_we + j (docs/model.md section 10).

    sigma_jk = s_k (-1)^(j-1) in 1-based indices, (-1)^(k + j) in 0-based ones.
    """
    k, j = np.divmod(np.arange(warp.count * weft.count), weft.count)
    warp_node = start[k] + (2 * j + 1) * warp.segments // (2 * weft.count)
    weft_node = start[warp.count + j] + (2 * k + 1) * weft.segments // (2 * warp.count)
    side = np.where((k + j) % 2 == 0, 1.0, -1.0)
    return warp_node.astype(np.int64), weft_node.astype(np.int64), side


def _contact_law(scene: Scene, warp: Family, weft: Family) -> np.ndarray:
    """(k_c, C_wa, a_wa, C_we, a_we), a_m = K_m / Lc_m with each family's half-wave Lc."""
    core = scene.contact.core_stiffness if scene.contact is not None else None
    lc_warp = geometry.half_wave_arc_length(warp.length / weft.count, warp.amplitude)
    lc_weft = geometry.half_wave_arc_length(weft.length / warp.count, weft.amplitude)
    return np.array([DEFAULT_CORE_STIFFNESS if core is None else core, warp.kawabata_C,
                     warp.kawabata_K / lc_warp, weft.kawabata_C, weft.kawabata_K / lc_weft])


def _friction_law(scene: Scene, warp: Family, weft: Family) -> np.ndarray:
    """(alpha, beta ell r_f, R_0, k_t) (docs/model.md sections 4, 10): k_t as given, else the
    smaller family's EA / segment length; zeros without friction."""
    friction = scene.friction
    if friction is None:
        return np.zeros(4)
    stick = friction.stick_stiffness
    if stick is None:
        stick = min(warp.EA * warp.segments / warp.length, weft.EA * weft.segments / weft.length)
    return np.array([*law_constants(friction), float(stick)])


def _load_factors(scene: Scene, warp: Family, weft: Family) -> np.ndarray:
    """Per-yarn load factors (Y,): the given ones (default 1). A pull-out loads its warp
    with factor 1, holds the other warps at their as-woven ends (factor 0) and loads the
    wefts with their factors (default 1), so `weft_values` can tension the wefts first and
    press the crossings (docs/model.md, decisions: what presses a pulled-out warp)."""
    load = scene.load
    weft_factors = np.ones(weft.count) if load.weft_factors is None else load.weft_factors
    if scene.pullout is not None:
        factors = np.zeros(warp.count + weft.count)
        factors[scene.pullout.warp - 1] = 1.0
        factors[warp.count:] = weft_factors
        return factors
    warp_factors = np.ones(warp.count) if load.warp_factors is None else load.warp_factors
    return np.concatenate([warp_factors, weft_factors]).astype(float)


def _fixed_dofs(scene: Scene, start: np.ndarray) -> np.ndarray:
    """Clamped patch: each yarn's first node pinned, its last node's z held, and under
    displacement control its last node's in-plane coordinate prescribed; a pull-out frees
    its warp's first node (docs/model.md section 10). The periodic cell alike: node 0 held
    at its as-woven position, node N (node 0's image) at z = z_0 and at the cell length,
    prescribed (displacement control) or tied across the family (force control)."""
    fixed = np.zeros(2 * start[-1], dtype=np.bool_)
    first, last = start[:-1], start[1:] - 1
    fixed[2 * first] = fixed[2 * first + 1] = True
    fixed[2 * last + 1] = True
    if scene.load.control == "displacement":
        fixed[2 * last] = True
    if scene.pullout is not None:
        pulled = first[scene.pullout.warp - 1]
        fixed[2 * pulled] = fixed[2 * pulled + 1] = False
    return fixed


def _dof_ties(scene: Scene, start: np.ndarray, warps: int) -> np.ndarray:
    """Periodic cell under force control: x_N of every warp tied to warp 0's (the cell
    length L1), y_M of every weft to weft 0's (L2); -1 elsewhere (docs/model.md section 10)."""
    tie = np.full(2 * start[-1], -1, np.int64)
    if scene.geometry.boundary == "periodic" and scene.load.control == "force":
        last = start[1:] - 1
        tie[2 * last[1:warps]] = 2 * last[0]
        tie[2 * last[warps + 1:]] = 2 * last[warps]
    return tie
