"""A balanced fabric is symmetric under (x, y, z) -> (y, x, -z) (docs/model.md section 10).

Warps and wefts alike (same count, length, segments, amplitude, material, equal k_t), no
gravity, on the clamped patch and on the periodic cell: the map takes warp k onto weft k (as-woven shapes included: warp k's
z = s_k A sin, weft k's z = -s_k A sin) and crossing (k, j) onto (j, k). So under equal
biaxial loads warp k and weft k respond alike (z mirrored, contact forces a symmetric
matrix), and swapping the loads swaps the results, to solver tolerance.
"""

import numpy as np
import pytest

from dynfab.model.fabric.model import FabricModel
from dynfab.solvers.static import StaticSolver
from independent import fabric_scene, record_inverse_norm

COUNT = 4
YARN = dict(length=0.04, segments=16, amplitude=0.5e-3, EA=13.72, EI=1.47e-7, kawabata_C=0.2e-3,
            kawabata_K=0.2)
FRICTION = dict(alpha=0.2, beta=1e3, contact_length=2e-3, fiber_radius=1e-3)
PATHS = {"force": ((0.1, 0.3, 0.6), (0.05, 0.1, 0.4)),
         "displacement": ((2e-4, 5e-4, 8e-4), (1e-4, 3e-4, 2e-4))}


def solve(control, warp_values, weft_values, friction, boundary="clamped", planes="fixed"):
    """(solver, [(state, record)] per step) of the balanced fabric."""
    tables = {} if friction is None else {"friction": friction}
    solver = StaticSolver(FabricModel.from_scene(fabric_scene(
        YARN, YARN, COUNT, COUNT, geometry=dict(boundary=boundary, planes=planes),
        load=dict(control=control, values=list(warp_values), weft_values=list(weft_values)),
        **tables)))
    state, steps = solver.initial_state(), []
    for a, b in zip(warp_values, weft_values):
        state, record = solver.step(state, (a, b))
        steps.append((state, record))
    return solver, steps


def families(solver, state):
    """(warps, wefts): node positions (COUNT, nodes, 2), z of the wefts mirrored."""
    f, pos = solver.model.structure, state.positions
    warps = np.stack([pos[f.chain_start[k]:f.chain_start[k + 1]] for k in range(COUNT)])
    wefts = np.stack([pos[f.chain_start[COUNT + j]:f.chain_start[COUNT + j + 1]]
                      for j in range(COUNT)]) * np.array([1.0, -1.0])
    return warps, wefts


def tolerance(solver, record, other):
    """4 ||H^-1||_inf max(r1 + r2, tolerance) [m]: two states with residuals r1, r2 (the F_T
    frozen Hessian's norm as the step's record gives it, `record_inverse_norm`: its
    error_estimate over its residual; factor 4 for the friction limit's coupling, as in
    test_fabric_static)."""
    return 4 * record_inverse_norm(record) * max(record["residual"] + other["residual"],
                                                  solver.tolerance)


@pytest.mark.parametrize("control", ["force", "displacement"])
@pytest.mark.parametrize("friction", [None, FRICTION], ids=["frictionless", "friction"])
def test_equal_loads_give_equal_families(control, friction):
    values = PATHS[control][0]
    solver, steps = solve(control, values, values, friction)
    for state, record in steps:
        warps, wefts = families(solver, state)
        tol = tolerance(solver, record, record)
        assert np.abs(warps - wefts).max() <= tol
        R = record["contact_force"]
        assert R.max() > 0
        k_c = solver.model.structure.tie_contact_law[0, 0]
        assert np.abs(R - R.T).max() <= k_c * tol  # dR <= k_c dz
        assert record["strain"][0] == pytest.approx(record["strain"][1], rel=0,
                                                    abs=tol / YARN["length"])


@pytest.mark.parametrize("control", ["force", "displacement"])
@pytest.mark.parametrize("friction, boundary, planes",
                         [(None, "clamped", "fixed"), (FRICTION, "clamped", "fixed"),
                          (None, "periodic", "cell"), (FRICTION, "clamped", "affine")],
                         ids=["frictionless", "friction", "periodic", "affine"])
def test_swapped_loads_swap_the_results(control, friction, boundary, planes):
    first, second = PATHS[control]
    solver_a, steps_a = solve(control, first, second, friction, boundary, planes)
    solver_b, steps_b = solve(control, second, first, friction, boundary, planes)
    for (state_a, record_a), (state_b, record_b) in zip(steps_a, steps_b):
        warps_a, wefts_a = families(solver_a, state_a)
        warps_b, wefts_b = families(solver_b, state_b)
        tol = tolerance(solver_a, record_a, record_b)
        assert np.abs(warps_a - wefts_b).max() <= tol
        assert np.abs(wefts_a - warps_b).max() <= tol
        assert np.abs(warps_a - wefts_a).max() > 1e3 * tol  # the loads differ: so do families
        R_a, R_b = record_a["contact_force"], record_b["contact_force"]
        assert np.abs(R_a - R_b.T).max() <= solver_a.model.structure.tie_contact_law[0, 0] * tol
        if friction is not None:
            assert np.array_equal(record_a["sliding"], record_b["sliding"].T)
