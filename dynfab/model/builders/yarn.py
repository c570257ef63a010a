"""The paper's yarn as a structure: warp chains tied to ground by the weft springs
(docs/model.md sections 1-4).

Each simulated warp yarn (one of `geometry.yarns` adjacent yarns, or one entry of a
[sweep], each with its own parameters) is one chain moving in its (x, z) plane; crossing
j of yarn k is a tie of node n_j to ground whose contact law is the weft spring k_we
(paper eq. 4) in series with Kawabata's compressions of both yarns (and the core
stiffness k_c where the scene gives one), and whose friction is Gralen's law on the slip
of x_{n_j} from its anchor (the weft stays put: the plane the slip is measured from is 0,
the anchors are positions). Node 0 is pinned; node N has z held and is loaded along x.
"""

from __future__ import annotations

import numpy as np

from dynfab.model import geometry
from dynfab.scene import Scene, expand_sweep, yarn_count
from dynfab.model.structure import GROUND, Structure
from dynfab.model.terms import nodes as node_terms
from dynfab.model.terms.friction import law_constants


def width_per_yarn(scene: Scene) -> float | None:
    """The fabric width per warp yarn L_we / N_wa [m] (force per unit width is P / this); None
    for a rod, which has no weft."""
    if scene.weft is None:
        return None
    return scene.weft.length / scene.weft.count


def yarn_structure(scene: Scene) -> Structure:
    """The structure of a one-yarn scene: one chain per simulated yarn, ties to ground."""
    if scene.sweep:
        chains = [_chain(s, phase=1.0) for s in expand_sweep(scene)]
    else:
        chains = [_chain(scene, phase=(-1.0) ** k) for k in range(yarn_count(scene))]
    return node_terms.attach(scene, _assemble(scene, chains))


def _chain(scene: Scene, phase: float) -> dict:
    """Arrays of one yarn of phase s_k = +-1 and its ties (docs/model.md sections 1-4)."""
    geo, warp = scene.geometry, scene.warp
    rest = geometry.as_woven_positions(geo.length, geo.segments, geo.crossings, geo.amplitude,
                                       phase)
    rest_length = geometry.segment_lengths(rest)
    lbar = geometry.voronoi_lengths(rest_length)
    bend = warp.EI / lbar
    bend[[0, -1]] = 0.0
    nodes = geometry.crossing_nodes(geo.segments, geo.crossings).astype(np.int64)
    sides = geometry.crossing_sides(geo.crossings, phase)
    friction = scene.friction
    stick = 0.0
    if friction is not None:
        stick = friction.stick_stiffness or warp.EA / (geo.length / geo.segments)
    law = [*law_constants(friction), float(stick)]  # Gralen, docs/model.md section 4
    return dict(
        rest_position=rest, rest_length=rest_length, stretch_stiffness=warp.EA / rest_length,
        bend_stiffness=bend,
        rest_angle=(np.zeros(geo.segments + 1) if geo.reference == "prestressed"
                    else geometry.turning_angles(rest)),
        mass=warp.linear_density * lbar,
        gravity=np.full(rest.shape[0], float(scene.gravity.g) if scene.gravity else 0.0),
        crossing_node=nodes, side=sides, gap_offset=_gap_offset(scene, rest, nodes, sides),
        contact_law=np.tile(contact_law(scene), (nodes.size, 1)),
        friction_law=np.tile(law, (nodes.size, 1)))


def _assemble(scene: Scene, chains: list[dict]) -> Structure:
    """One structure of the chains: nodes chain after chain, ties in chain order."""
    sizes = [c["rest_position"].shape[0] for c in chains]
    start = np.concatenate([[0], np.cumsum(sizes)]).astype(np.int64)
    joined = {name: np.concatenate([c[name] for c in chains])
              for name in ("rest_position", "rest_length", "stretch_stiffness", "bend_stiffness",
                           "rest_angle", "mass", "gravity", "side", "gap_offset", "contact_law",
                           "friction_law")}
    tie_a = np.concatenate([first + c["crossing_node"] for first, c in zip(start, chains)])
    ties, yarns = tie_a.size, len(chains)
    friction_law = joined["friction_law"].reshape(ties, 4)
    return Structure(
        rest_position=joined["rest_position"], mass=joined["mass"], gravity=joined["gravity"],
        chain_start=start, chain_family=np.zeros(yarns, np.int64),
        chain_plane=(np.arange(yarns) + 0.5) * plane_spacing(scene),
        rest_length=joined["rest_length"], stretch_stiffness=joined["stretch_stiffness"],
        bend_stiffness=joined["bend_stiffness"], rest_angle=joined["rest_angle"],
        wrap_stiffness=np.zeros(yarns), wrap_rest_angle=np.zeros(yarns),
        load_node=start[1:] - 1, load_factor=np.ones(yarns),
        tie_a=tie_a.astype(np.int64), tie_b=np.full(ties, GROUND, np.int64),
        tie_side=joined["side"], tie_gap_offset=joined["gap_offset"],
        tie_contact_law=joined["contact_law"].reshape(ties, 5), tie_friction_law=friction_law,
        tie_plane=np.zeros((ties, 2)), tie_plane_weight=np.zeros((ties, 2)),
        plane_nodes_a=np.zeros(0, np.int64), plane_nodes_b=np.zeros(0, np.int64),
        has_friction=bool(np.any(friction_law[:, 3] > 0.0)),
        fixed=_fixed_dofs(start, scene.load.control), dof_tie=np.full(2 * start[-1], -1, np.int64))


def plane_spacing(scene: Scene) -> float:
    """The distance between the planes of neighbouring yarns [m]: the fabric width per warp
    yarn L_we / N_wa; the yarns of a [sweep] are not neighbours in a fabric, and a rod has no
    width: L / 10 for them (L the projected length)."""
    if scene.sweep or scene.weft is None:
        return scene.geometry.length / 10
    return scene.weft.length / scene.weft.count


def _fixed_dofs(start: np.ndarray, control: str) -> np.ndarray:
    """Node 0 pinned, z_N held, x_N held under displacement control (docs/model.md section 1)."""
    fixed = np.zeros(2 * start[-1], dtype=np.bool_)
    first, last = start[:-1], start[1:] - 1
    fixed[2 * first] = fixed[2 * first + 1] = fixed[2 * last + 1] = True
    fixed[2 * last] = control == "displacement"
    return fixed


def _gap_offset(scene: Scene, rest: np.ndarray, nodes: np.ndarray, sides: np.ndarray) -> np.ndarray:
    """c_j in g_j = c_j - s_j z_{n_j} (docs/model.md section 3).

    as_woven: g_j = s_j (z0 - z), so c_j = s_j z0_{n_j} and every contact starts at g = 0;
    prestressed: g_j = A_wa + A_we - s_j z, the weft pre-deflected by its own amplitude.
    """
    if scene.geometry.crossings == 0:
        return np.zeros(0)
    if scene.geometry.reference == "prestressed":
        return np.full(nodes.size, scene.geometry.amplitude + scene.weft.amplitude)
    return sides * rest[nodes, 1]


def contact_law(scene: Scene) -> np.ndarray:
    """(k_s, C_wa, a_wa, C_we, a_we), a_m = K_m / Lc_m (docs/model.md section 3, paper eqs. 4,
    6-7).

    k_s = 1 / (1/k_we + 1/k_c): the weft spring in series with the core stiffness
    `contact.core_stiffness` when the scene gives one (else k_we). One more linear spring
    in series adds R/k_c to the law's left side and R^2/(2 k_c) to the energy, exactly
    what k_s does, so both solvers take it with no term of its own.
    """
    geo, weft = scene.geometry, scene.weft
    if geo.crossings == 0:
        return np.zeros(5)
    k_we = geometry.weft_stiffness(weft.EI, weft.length, weft.count, weft.tension)
    core = scene.contact.core_stiffness if scene.contact is not None else None
    if core is not None:
        k_we = 1.0 / (1.0 / k_we + 1.0 / core)
    lc_warp = geometry.half_wave_arc_length(geo.length / geo.crossings, geo.amplitude)
    lc_weft = geometry.half_wave_arc_length(weft.length / weft.count, weft.amplitude)
    return np.array([k_we, scene.warp.kawabata_C, scene.warp.kawabata_K / lc_warp,
                     weft.kawabata_C, weft.kawabata_K / lc_weft])
