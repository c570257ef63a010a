"""What a structure's coordinates call for, on the host (docs/model.md sections 10 and 11): its
term set, its friction anchors as woven, and the dynamic solver's stiffest rows.

Planar kinematics (dim 2: each chain in its vertical plane) takes the planar fabric's terms
(`dynfab.model.fabric.assembly`); spatial kinematics (dim 3: x, y, z) the spatial ones
(`dynfab.model.fabric.spatial`: bending in two planes, the three-component crossing friction and
rotation spring, the lateral contacts). Both offer the same functions (TERMS, CONTACT,
total_energy, gradient, sparse_hessian, energy_vector, rounding_scale, pattern_of,
coupling_rows, crossing_slips), so the static solver's sparse backend and its certificate
take either. This is the one place on the host that asks which kinematics a structure has.
"""

from __future__ import annotations

import numpy as np

from dynfab.model.builders.sliding import woven_dofs
from dynfab.model.fabric import assembly, sliding, spatial
from dynfab.model.structure import Structure, chain_of_node, dim
from dynfab.model.structure import sliding as slides
from dynfab.model.terms.spatial import crossing_coordinates


def terms_of(structure: Structure):
    """The term set of `structure`: spatial where its nodes have three coordinates, else
    planar; on the dofs of crossings that slide where they do (`dynfab.model.fabric.sliding`,
    docs/model.md 11.13)."""
    if slides(structure):
        return sliding.SPATIAL if dim(structure) == 3 else sliding.PLANAR
    return spatial if dim(structure) == 3 else assembly


def woven_state(structure: Structure) -> np.ndarray:
    """The dofs as woven (n, dim): the rest positions, or where the crossings slide each one's
    material coordinates in its slots (`dynfab.model.builders.sliding.woven_dofs`)."""
    if slides(structure):
        return woven_dofs(structure)
    return np.array(structure.rest_position, float)


def physical_positions(structure: Structure, dofs) -> np.ndarray:
    """The positions (n, dim) [m] the dofs stand for: themselves, or where the crossings slide
    each crossing's nodes where it is (`dynfab.model.fabric.sliding.physical`)."""
    if slides(structure):
        return sliding.physical(dofs, structure)
    return np.asarray(dofs, float)


def woven_plan(structure: Structure) -> np.ndarray:
    """(x, y) [m] of each node as woven, seen from above: planar, a warp node at (its in-plane
    coordinate, Y_k) and a weft node at (X_j, its in-plane coordinate) (docs/model.md section
    10); spatial, the node's own (x, y) (section 11)."""
    pos = np.asarray(structure.rest_position, float)
    if dim(structure) == 3:
        return pos[:, :2]
    chain = chain_of_node(structure)
    along, line = pos[:, 0], structure.chain_plane[chain]
    warp = structure.chain_family[chain, None] == 0
    return np.where(warp, np.stack([along, line], 1), np.stack([line, along], 1))


def woven_anchors(structure: Structure) -> np.ndarray:
    """Each tie's friction anchor at zero slip as woven: planar (T, 2) [m], from the planes (a
    ground tie's first component its node's x, its second 0; docs/model.md section 10);
    spatial (T, 3) [m, m, rad], each crossing's coordinates q as woven (section 11.4); where
    the crossings slide the first two are the slides of the material through the crossing,
    0 as woven (11.13)."""
    pos = np.asarray(structure.rest_position, float)
    if dim(structure) == 3:
        anchors = np.zeros((structure.tie_a.size, 3))
        for t, stencil in enumerate(np.asarray(structure.tie_stencil).reshape(-1, 6)):
            crossing_coordinates(pos[stencil], anchors[t])
    if slides(structure):  # no slide as woven
        if dim(structure) == 3:
            anchors[:, :2] = 0.0
            return anchors
        return np.zeros((structure.tie_a.size, 2))
    if dim(structure) == 3:
        return anchors
    plane = np.asarray(structure.tie_plane, float).reshape(-1, 2)
    anchors = np.zeros((structure.tie_a.size, 2))
    anchors[:, 0] = pos[structure.tie_a, 0] - plane[:, 0]
    node_b = structure.tie_b >= 0
    anchors[node_b, 1] = pos[structure.tie_b[node_b], 0] - plane[node_b, 1]
    return anchors


def stiffest_rows(structure: Structure, pos, anchors) -> tuple[np.ndarray, np.ndarray] | None:
    """Per node, the stiffest tangent's Gershgorin row sum and largest diagonal [N/m] where the
    host computes them (spatial: `dynfab.model.fabric.spatial.stiffest_rows`, from the exact
    Hessian; crossings that slide: `dynfab.model.fabric.sliding.stiffest_rows`, the step's
    anchors with their stretches); None where the kernels do (planar: from their band,
    `structure_tangent`)."""
    if slides(structure):
        return sliding.stiffest_rows(structure, pos, anchors)
    if dim(structure) != 3:
        return None
    return spatial.stiffest_rows(structure, np.asarray(pos, float).reshape(-1, 3),
                                 np.asarray(anchors, float).reshape(-1, 3))
