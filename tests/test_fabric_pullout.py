"""A yarn pull-out from the clamped patch (docs/model.md section 10).

Warp 2 of a 3 x 4 patch has its first node free and its last node displaced; every other
yarn is clamped at both ends. Its internal forces (stretch, bending) cancel in a sum over
its nodes, and contact acts in z only, so its x-equilibrium says: the pull-out force
equals the sum of the friction forces on its crossings, to the residual summed over its
nodes. Friction bounds it: at most sum_j F_T,j. Once every crossing slides the warp moves
as a rigid translation (the crossings ride on their nodes, the planes are fixed), so the
force stays constant from step to step.

Gravity is on: without it (or a pretension) nothing presses the pulled warp onto the
wefts. The as-woven contacts carry no force, and a rigid translation of a warp leaves
every closure unchanged (the crossings ride on their nodes), so the warp would slide out
at zero force, a rigid-body mode of a singular Hessian, the state then depending on the
solver's path (measured: zero force or a stretched, sticking warp, by the number of
frozen-F_T solves).
"""

import numpy as np

from dynfab.model.fabric.model import FabricModel
from dynfab.solvers.static import StaticSolver
from independent import fabric_scene, record_inverse_norm

WARP = dict(length=0.04, segments=24, amplitude=0.5e-3, EA=13.72, EI=1.47e-7, kawabata_C=0.2e-3,
            kawabata_K=0.2)
WEFT = dict(length=0.03, segments=18, amplitude=0.4e-3, EA=10.0, EI=2e-7, kawabata_C=0.15e-3,
            kawabata_K=0.3)
FRICTION = dict(alpha=0.2, beta=1e3, contact_length=2e-3, fiber_radius=1e-3, onset_force=1e-5)
K_C = 1e5
"""The core stiffness [N/m] (a fabric's default)."""
PULLED = 2
WARPS, WEFTS = 3, 4


def test_pullout_force_is_the_friction_on_the_pulled_warp():
    values = tuple(np.linspace(2e-5, 6e-4, 12))
    solver = StaticSolver(FabricModel.from_scene(fabric_scene(
        WARP, WEFT, WARPS, WEFTS, friction=FRICTION, contact=dict(core_stiffness=K_C),
        gravity=dict(g=9.81), pullout=dict(warp=PULLED),
        load=dict(control="displacement", values=list(values)))))
    f = solver.model.structure
    k = PULLED - 1
    nodes = f.chain_start[k + 1] - f.chain_start[k]
    state, forces = solver.initial_state(), []
    for value in values:
        state, record = solver.step(state, (value, 0.0))
        pull = record["end_force"][k]
        friction_x = record["friction_force"].reshape(WARPS, WEFTS, 2)[k, :, 0]
        limits = record["friction_limit"][k]
        # the residual bounds every free force component: nodes x residual for the sum
        tolerance = nodes * max(record["residual"], solver.tolerance)
        assert abs(pull + friction_x.sum()) <= tolerance
        assert pull <= limits.sum() + tolerance
        forces.append((pull, record["sliding"][k].all(), record["residual"]))
    assert all(all_slide for _, all_slide, _ in forces[-5:])
    assert forces[-1][0] > 0  # it slides, against friction: its free end has moved
    assert state.positions[f.chain_start[k], 0] > f.rest_position[f.chain_start[k], 0] + 1e-4
    # The plateau: each pull within nodes x r of its friction sum; each F_T,j within
    # dF_T/dR x k_c x |dz| of the next step's, |dz| <= ||H^-1|| r (dF_T/dR <= alpha +
    # beta ell r_f / R_0, the contact tangent <= k_c; ||H^-1|| the last step's record's,
    # `record_inverse_norm`).
    residual = max(max(r for _, _, r in forces[-5:]), solver.tolerance)
    inverse = record_inverse_norm(record)
    slope = FRICTION["alpha"] + (FRICTION["beta"] * FRICTION["contact_length"]
                                 * FRICTION["fiber_radius"] / FRICTION["onset_force"])
    bound = 2 * (nodes * residual + WEFTS * slope * K_C * inverse * residual)
    assert np.ptp([p for p, _, _ in forces[-5:]]) <= bound
