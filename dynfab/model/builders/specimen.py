"""An in-plane shear specimen as a spatial structure (docs/model.md section 11).

The layout (`dynfab.model.specimen_layout`: the bias-extension rectangle or the picture frame, its
yarns, crossings, held nodes and lateral contacts) becomes chains of nodes in x, y, z (dim 3):

- each yarn a chain with its stretch springs (EA / l0) and its bending in two planes
  (EI / lbar out of the plane, EI_lateral / lbar in it; rest turnings of the as-woven
  yarn);
- each crossing a tie of six nodes (the two crossing nodes and their chain neighbours):
  the contact along e_z (Kawabata's compressions in series with the core stiffness, a_m =
  K_m / Lc_m over each family's half-wave at its spacing, docs/model.md section 10), its
  closure offset set so that the as-woven state carries the preload R_p (g_p solving the
  series law at R_p), Gralen's friction on the three-component slip with the torsion
  radius rho, and the rotation spring K about the as-woven angle between the yarns;
- each pair of neighbouring yarns of a family, at each yarn crossing both, a lateral
  contact of the family's width w and lateral stiffness;
- the held nodes fixed in x, y and z (their positions prescribed by the model at each
  step, `dynfab.model.fabric.specimen_model`).
"""

from __future__ import annotations

import numpy as np

from dynfab.model import geometry, specimen_layout
from dynfab.model.builders import woven_rest
from dynfab.model.builders.fabric import DEFAULT_LINEAR_DENSITY
from dynfab.model.builders.sliding import crossings_as_they_move
from dynfab.errors import UserError
from dynfab.scene import DEFAULT_CORE_STIFFNESS, TORSION_RADIUS_PER_WIDTH, Scene
from dynfab.model.structure import Structure
from dynfab.model.terms import contact as contact_law
from dynfab.model.terms import nodes as node_terms
from dynfab.model.terms.friction import law_constants
from dynfab.model.terms.spatial import compaction_law

def layout_of(scene: Scene) -> specimen_layout.Layout:
    """The specimen's layout from its scene."""
    s, warp, weft = scene.specimen, scene.warp, scene.weft
    common = (warp.spacing, weft.spacing, warp.amplitude, weft.amplitude,
              s.segments_per_spacing)
    if s.test == "bias_extension":
        return specimen_layout.bias_extension(s.width, s.height, *common,
                                              yarn_widths=(warp.width, weft.width))
    return specimen_layout.picture_frame(s.side, *common)


def _in_plane_angle(e: np.ndarray) -> np.ndarray:
    return np.arctan2(e[:, 1], e[:, 0])


def _wrap(angle: np.ndarray) -> np.ndarray:
    return (angle + np.pi) % (2.0 * np.pi) - np.pi


def _chain_springs(shape: np.ndarray, EA: float, EI: float, EI_lateral: float, density: float,
                   load: np.ndarray, spacing: float, free_end: str | None):
    """(l0, EA / l0, EI / lbar, theta0, EI_lat / lbar, psi0, masses) of one chain (m, 3) whose
    crossing nodes carry the z-forces `load` [N] of the woven-in contact, `spacing` [m] apart
    (`dynfab.model.builders.woven_rest`: without a preload the as-woven shape is stress-free);
    `free_end`: the family's name where an end of the chain is free (`check_free_end`)."""
    e = np.diff(shape, axis=0)
    l0 = np.linalg.norm(e, axis=1)
    in_plane = np.hypot(e[:, 0], e[:, 1])
    if np.any(in_plane <= 1e-12 * l0):
        raise UserError("a specimen yarn has a vertical segment: the spatial model needs every "
                        "segment to have an in-plane extent (docs/model.md section 11)")
    moment = np.zeros(shape.shape[0])
    if np.any(load):
        if free_end is not None:
            woven_rest.check_free_end(float(np.max(np.abs(load))), spacing, EI,
                                      float(np.max(np.abs(shape[:, 2]))), free_end)
        tension, moment = woven_rest.internal_forces(in_plane, e[:, 2], load, spacing)
        l0 = woven_rest.rest_lengths(l0, tension, EA)
    lbar = geometry.voronoi_lengths(l0)
    elevation = np.arctan2(e[:, 2], in_plane)
    theta0, psi0 = np.zeros(shape.shape[0]), np.zeros(shape.shape[0])
    theta0[1:-1] = np.diff(elevation)
    psi0[1:-1] = _wrap(np.diff(_in_plane_angle(e)))
    kb, kl = EI / lbar, EI_lateral / lbar
    kb[[0, -1]] = kl[[0, -1]] = 0.0
    theta0 = woven_rest.rest_turnings(theta0, moment, kb)
    return l0, EA / l0, kb, theta0, kl, psi0, density * lbar


def _contact_law(scene: Scene) -> np.ndarray:
    """(k_c, C_wa, a_wa, C_we, a_we) with a_m = K_m / Lc_m, Lc_m the half-wave arc length of
    family m at its spacing (docs/model.md section 10)."""
    warp, weft = scene.warp, scene.weft
    core = scene.contact.core_stiffness if scene.contact is not None else None
    lc_warp = geometry.half_wave_arc_length(weft.spacing, warp.amplitude)
    lc_weft = geometry.half_wave_arc_length(warp.spacing, weft.amplitude)
    return np.array([DEFAULT_CORE_STIFFNESS if core is None else core, warp.kawabata_C,
                     warp.kawabata_K / lc_warp, weft.kawabata_C, weft.kawabata_K / lc_weft])


def _friction_law(scene: Scene) -> np.ndarray:
    """(alpha, beta ell r_f, R_0, k_t): k_t as given, else the smaller family's EA over its
    segment length; zeros without friction (alpha = beta = 0 written out)."""
    friction = scene.friction
    if friction is None:
        return np.zeros(4)
    stick = friction.stick_stiffness
    if stick is None:
        n = scene.specimen.segments_per_spacing
        stick = min(scene.warp.EA * n / scene.weft.spacing, scene.weft.EA * n / scene.warp.spacing)
    return np.array([*law_constants(friction), float(stick)])


def _compaction(scene: Scene, family: int, core: np.ndarray) -> np.ndarray:
    """(A [N], s_a [m], s_core [m]) of Gutowski's lateral compaction between two yarns of
    `family` (docs/model.md 11.5, (11.5)-(11.6)); zeros without `fibre_modulus`.

    A = 3 pi E_f / beta^4 x t x l: the law's stiffness A_s over the side face of a yarn of
    thickness t = 2 A (its crimp amplitude: a balanced weave's centreline runs +-t / 2) along
    the length l a lateral contact stands for (the crossing family's spacing); s_a = V0 w /
    V_a, the centreline distance at which the yarns' fibres reach their packing limit; s_core
    where the law's stiffness reaches the yarns' core (`lateral_stiffness`, `core`: that
    family's, one value), found by bisection in (s_a, w]."""
    yarn, across = (scene.warp, scene.weft) if family == 0 else (scene.weft, scene.warp)
    if getattr(yarn, "fibre_modulus", None) is None:
        return np.zeros(3)
    A = (3.0 * np.pi * yarn.fibre_modulus / yarn.fibre_waviness ** 4
         * 2.0 * yarn.amplitude * across.spacing)
    w = yarn.width
    packed = yarn.fibre_volume_fraction * w / yarn.packing_limit
    k = float(core[0]) if core.size else 0.0

    def stiffness(d):
        return compaction_law(d, w, k, A, packed, packed)[2]

    low, high = packed, w
    if stiffness(high) >= k:
        return np.array([A, packed, w])
    for _ in range(200):
        middle = 0.5 * (low + high)
        low, high = (middle, high) if stiffness(middle) > k else (low, middle)
    return np.array([A, packed, high])


def torsion_radius(scene: Scene) -> float:
    """rho [m]: crossing.torsion_radius, as the validated scene resolves it (default
    `dynfab.scene.TORSION_RADIUS_PER_WIDTH` times the smaller yarn width)."""
    given = scene.crossing.torsion_radius if scene.crossing is not None else None
    if given is not None:
        return float(given)
    return TORSION_RADIUS_PER_WIDTH * min(scene.warp.width, scene.weft.width)


def _stencils(layout, start: np.ndarray, reach: int) -> np.ndarray:
    """(a_prev, a, a_next, b_prev, b, b_next) of each crossing (C, 6): each crossing node and
    the nodes `reach` along its chain either way (the neighbouring crossings' nodes), or the
    chain's end nodes where it ends first (`specimen_layout.chord_neighbours`)."""
    out = []
    for column in (0, 1):
        node = layout.crossing_nodes[:, column]
        before, after = specimen_layout.chord_neighbours(start, node, reach)
        out.append(np.stack([before, node, after], axis=1))
    return np.concatenate(out, axis=1).astype(np.int64)


def _rest_rotation(rest: np.ndarray, stencil: np.ndarray) -> np.ndarray:
    """phi at rest: the in-plane angle from the warp's chord to the weft's (C,) [rad]."""
    warp = rest[stencil[:, 2]] - rest[stencil[:, 0]]
    weft = rest[stencil[:, 5]] - rest[stencil[:, 3]]
    return _wrap(_in_plane_angle(weft) - _in_plane_angle(warp))


def _family_value(scene: Scene, key: str, family: np.ndarray, default) -> np.ndarray:
    """A per-family key for each row of `family` (0 warp, 1 weft), its default where unset."""
    values = [getattr(t, key, None) for t in (scene.warp, scene.weft)]
    values = [default(t) if v is None else v for v, t in zip(values, (scene.warp, scene.weft))]
    return np.where(family == 0, values[0], values[1]).astype(float)


def specimen_structure(scene: Scene, layout=None) -> Structure:
    """The spatial structure of a validated specimen scene (module docstring)."""
    layout = layout_of(scene) if layout is None else layout
    rest, start = layout.positions, layout.chain_start
    tie_a, tie_b = layout.crossing_nodes[:, 0], layout.crossing_nodes[:, 1]
    side = layout.crossing_side.astype(float)
    preload = scene.crossing.preload if scene.crossing is not None else 0.0
    load = woven_rest.crossing_loads(rest.shape[0], tie_a, tie_b, side, preload)
    fixed = np.repeat(layout.held, 3)
    free = woven_rest.free_ends(fixed, start, 3)
    parts = []
    for y in range(start.size - 1):
        # along a warp the crossings are the wefts', weft.spacing apart, and the other way
        yarn, across = ((scene.warp, scene.weft) if layout.chain_family[y] == 0
                        else (scene.weft, scene.warp))
        density = yarn.linear_density or DEFAULT_LINEAR_DENSITY
        nodes = slice(start[y], start[y + 1])
        family = "warp" if layout.chain_family[y] == 0 else "weft"
        parts.append(_chain_springs(rest[nodes], yarn.EA, yarn.EI, yarn.EI_lateral or yarn.EI,
                                    density, load[nodes], across.spacing,
                                    family if free[y].any() else None))
    l0, stretch, kb, theta0, kl, psi0, mass = (np.concatenate(p) for p in zip(*parts))
    law = _contact_law(scene)
    g_p = woven_rest.woven_closure(preload, law)
    stencil = _stencils(layout, start, scene.specimen.segments_per_spacing)
    ties = tie_a.size
    friction = np.tile(_friction_law(scene), (ties, 1))
    shear_k = (scene.crossing.shear_stiffness or 0.0) if scene.crossing is not None else 0.0
    rotation = np.column_stack([np.full(ties, torsion_radius(scene)), np.full(ties, shear_k),
                                _rest_rotation(rest, stencil)])
    node_chain = np.repeat(np.arange(start.size - 1), np.diff(start))
    lateral_family = layout.chain_family[node_chain[layout.lateral[:, 2]]]
    core = law[0]
    width = _family_value(scene, "width", lateral_family, lambda t: np.nan)
    stiffness = _family_value(scene, "lateral_stiffness", lateral_family, lambda t: core)
    compaction = np.array([_compaction(scene, f, stiffness[lateral_family == f])
                           for f in (0, 1)])
    lateral_law = np.column_stack([
        layout.lateral_sign, width, stiffness,
        np.full(lateral_family.size, float(contact_law.NATURAL)),
        compaction[lateral_family]])
    n, chains = rest.shape[0], start.size - 1
    return crossings_as_they_move(scene)(node_terms.attach(scene, Structure(
        rest_position=rest, mass=mass, gravity=np.zeros(n),
        chain_start=start.astype(np.int64), chain_family=layout.chain_family.astype(np.int64),
        chain_plane=np.zeros(chains), rest_length=l0, stretch_stiffness=stretch,
        bend_stiffness=kb, rest_angle=theta0,
        wrap_stiffness=np.zeros(chains), wrap_rest_angle=np.zeros(chains),
        load_node=(start[1:] - 1).astype(np.int64), load_factor=np.zeros(chains),
        tie_a=tie_a.astype(np.int64), tie_b=tie_b.astype(np.int64), tie_side=side,
        tie_gap_offset=side * (rest[tie_a, 2] - rest[tie_b, 2]) + g_p,
        tie_contact_law=np.tile(law, (ties, 1)), tie_friction_law=friction,
        tie_plane=np.zeros((ties, 2)), tie_plane_weight=np.zeros((ties, 2)),
        plane_nodes_a=np.zeros(0, np.int64), plane_nodes_b=np.zeros(0, np.int64),
        has_friction=bool(np.any(friction[:, 3] > 0.0) and np.any(friction[:, :2] > 0.0)),
        fixed=fixed, dof_tie=np.full(3 * n, -1, np.int64),
        lateral_bend_stiffness=kl, lateral_rest_angle=psi0,
        tie_stencil=stencil, tie_rotation_law=rotation,
        lateral_stencil=layout.lateral.astype(np.int64), lateral_law=lateral_law)))
