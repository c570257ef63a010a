"""One-pass kernels over a structure's ties or nodes, outside any time loop: the tie pass, the
force gather, the energy and the anchors' return map (docs/model.md sections 2-4, 10), for the
host (`structure_relaxation`: reactions, contact and friction forces, the return map after a
load step) and the tests (forces against the static reference's gradient, energy).
"""


import warp as wp

from dynfab.kernels import structure_arrays, structure_forces, structure_settings, structure_state
from dynfab.kernels import structure_variants
from dynfab.kernels.precision import KINEMATICS

TIES, FORCES, NODE_ENERGY, TIE_ENERGY, RETURN_MAP, LATERAL_ENERGY = range(6)
"""Passes (`pass_kernel`'s `which`): a thread per tie, node, node, tie, tie, lateral contact."""
UNITS = {TIES: "ties", FORCES: "nodes", NODE_ENERGY: "nodes", TIE_ENERGY: "ties",
         RETURN_MAP: "ties", LATERAL_ENERGY: "laterals"}
"""What each pass's threads run over (`StructureArrays` counts)."""


@structure_variants.variant("passes", "-")
def pass_kernel(scalar, friction: bool, boundary: bool, kinematics: str = "planar"):
    """Kernel run(data, state, which, out): TIES writes every tie's R, dR/dg, F_T and friction
    force into the state; FORCES state.force = -dV/dr on the free dofs (after TIES),
    gathered at node u; NODE_ENERGY, TIE_ENERGY and LATERAL_ENERGY out[unit] = the energy the unit
    owns [J]; RETURN_MAP moves every anchor radially, out[t] = the energy dissipated [J]."""
    dim = KINEMATICS[kinematics]
    Data = structure_arrays.struct(scalar, dim)
    State = structure_state.struct(scalar, dim)
    forces = structure_forces.functions(scalar, friction, boundary, kinematics)

    @wp.kernel(module="unique", module_options=structure_settings.MODULE_OPTIONS)
    def run(data: Data, state: State, which: int, out: wp.array(dtype=scalar)):
        u = wp.tid()
        if which == TIES:
            forces.tie_pass(u, state.position, data, state)
        elif which == FORCES:
            state.force[u] = forces.node_force(u, state.position, data, state)
        elif which == LATERAL_ENERGY:
            out[u] = forces.lateral_energy(u, state.position, data)
        elif which == NODE_ENERGY:
            out[u] = forces.node_energy(u, state.position, data, state)
        elif which == TIE_ENERGY:
            out[u] = forces.tie_energy(u, state.position, data, state)
        elif which == RETURN_MAP:
            out[u] = forces.return_map(u, state.position, data, state)

    return run
