"""Which term set a structure's coordinates call for (docs/model.md sections 10 and 11).

Planar kinematics (dim 2: each chain in its vertical plane) takes the planar fabric's terms
(`dynfab.model.fabric.assembly`); spatial kinematics (dim 3: x, y, z) the spatial ones
(`dynfab.model.fabric.spatial`: bending in two planes, the three-component crossing friction and
rotation spring, the lateral contacts). Both offer the same functions (TERMS, CONTACT,
total_energy, gradient, sparse_hessian, energy_vector, rounding_scale, pattern_of,
coupling_rows, crossing_slips), so the static solver's sparse backend and its certificate
take either.
"""

from __future__ import annotations

from dynfab.model.fabric import assembly, spatial
from dynfab.model.structure import Structure, dim


def terms_of(structure: Structure):
    """The term set (module) of `structure`: spatial where its nodes have three coordinates."""
    return spatial if dim(structure) == 3 else assembly
