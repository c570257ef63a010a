"""One-pass kernels over a structure's ties or nodes, outside any time loop: the tie pass, the
force gather, the energy and the anchors' return map (docs/model.md sections 2-4, 10), for the
host (`structure_relaxation`: reactions, contact and friction forces, the return map after a
load step) and the tests (forces against the static reference's gradient, energy).
"""


import warp as wp

from dynfab.kernels import structure_arrays, structure_forces, structure_settings, structure_state
from dynfab.kernels import structure_variants

TIES, FORCES, NODE_ENERGY, TIE_ENERGY, RETURN_MAP = range(5)
"""Passes (`pass_kernel`'s `which`): a thread per tie, node, node, tie, tie."""


@structure_variants.variant("passes", "-")
def pass_kernel(scalar, friction: bool, boundary: bool):
    """Kernel run(data, state, which, out): TIES writes every tie's R, dR/dg, F_T and friction
    force into the state; FORCES state.force = -dV/dr on the free dofs (after TIES);
    NODE_ENERGY and TIE_ENERGY out[unit] = the energy the unit owns [J]; RETURN_MAP moves
    every anchor radially, out[t] = the energy dissipated [J]."""
    Data = structure_arrays.struct(scalar)
    State = structure_state.struct(scalar)
    forces = structure_forces.functions(scalar, friction, boundary)

    @wp.kernel(module="unique", module_options=structure_settings.MODULE_OPTIONS)
    def run(data: Data, state: State, which: int, out: wp.array(dtype=scalar)):
        u = wp.tid()
        if which == TIES:
            forces.tie_pass(u, state.position, data, state)
        elif which == FORCES:
            state.force[u] = forces.node_force(u, state.position, data, state)
        elif which == NODE_ENERGY:
            out[u] = forces.node_energy(u, state.position, data, state)
        elif which == TIE_ENERGY:
            out[u] = forces.tie_energy(u, state.position, data, state)
        elif which == RETURN_MAP:
            out[u] = forces.return_map(u, state.position, data, state)

    return run
