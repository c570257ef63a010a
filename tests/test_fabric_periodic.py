"""The periodic fabric cell (docs/model.md section 10) against what it must reduce to.

- Every crossing of the cell lies on a mirror plane, so slips stay zero: friction on and
  off give the same results, to solver tolerance.
- A cell of two repeats in each direction (4 x 4 yarns) is the 2 x 2 cell tiled: the same
  strains, the same contact forces repeated, the same crimp, to solver tolerance.
"""

import numpy as np
import pytest

from dynfab.model.fabric.model import FabricModel
from dynfab.solvers.static import StaticSolver
from independent import fabric_scene, record_inverse_norm

SPACING_WARP, SPACING_WEFT = 0.1 / 16, 0.005
"""Crossing spacings [m] along the warps (L / n_we) and along the wefts (L_we / n_wa)."""
PER_CROSSING = 8
FRICTION = dict(alpha=0.2, beta=1e3, contact_length=2e-3, fiber_radius=1e-3)
PATHS = {"force": ((0.1, 0.3, 0.6), (0.05, 0.1, 0.4)),
         "displacement": ((1e-4, 2e-4, 4e-4), (0.0, 5e-5, 1e-4))}
"""(warp, weft) load paths per yarn [N] or per cell repeat of two crossings [m]."""


def cell(warps, wefts, control, friction):
    """The solver of a periodic cell of `warps` x `wefts` yarns (the tests pass each step's
    loads to `step`)."""
    warp = dict(length=wefts * SPACING_WARP, segments=PER_CROSSING * wefts, amplitude=0.5e-3,
                EA=13.72, EI=1.47e-7, kawabata_C=0.2e-3, kawabata_K=0.2)
    weft = dict(length=warps * SPACING_WEFT, segments=PER_CROSSING * warps, amplitude=0.4e-3,
                EA=10.0, EI=2e-7, kawabata_C=0.15e-3, kawabata_K=0.3)
    warp_values, weft_values = PATHS[control]
    tables = {} if friction is None else {"friction": friction}
    return StaticSolver(FabricModel.from_scene(fabric_scene(
        warp, weft, warps, wefts, geometry=dict(boundary="periodic"),
        load=dict(control=control, values=list(warp_values), weft_values=list(weft_values)),
        **tables)))


def position_tolerance(solver, record, other_residual):
    """4 ||H^-1||_inf max(r1 + r2, tolerance) [m] on the unknowns (as in test_fabric_static),
    ||H^-1||_inf the step's record's (`record_inverse_norm`: its error_estimate over its
    residual)."""
    return 4 * record_inverse_norm(record) * max(record["residual"] + other_residual,
                                                  solver.tolerance)


@pytest.mark.parametrize("control", ["force", "displacement"])
def test_friction_on_and_off_agree_on_the_cell(control):
    without = cell(2, 4, control, None)
    with_friction = cell(2, 4, control, FRICTION)
    s0, s1 = without.initial_state(), with_friction.initial_state()
    for a, b in zip(*PATHS[control]):
        s0, r0 = without.step(s0, (a, b))
        s1, r1 = with_friction.step(s1, (a, b))
        tol = position_tolerance(with_friction, r1, r0["residual"])
        assert np.abs(s0.positions - s1.positions).max() <= tol
        assert r1["friction_limit"].min() > 0  # every crossing closed, friction active
        # the slips stay zero: k_t |s| below the rounding of the forces (k_t x tol)
        assert np.abs(s1.anchors).max() <= tol
        assert r1["strain"][0] > 0


@pytest.mark.parametrize("control", ["force", "displacement"])
def test_two_repeats_are_the_cell_tiled(control):
    # the same load per yarn (force control), or the same stretch: twice the end
    # displacement over twice the length (displacement control)
    small, large = cell(2, 2, control, None), cell(4, 4, control, None)
    scale = 1.0 if control == "force" else 2.0
    s_small, s_large = small.initial_state(), large.initial_state()
    for a, b in zip(*PATHS[control]):
        s_small, r_small = small.step(s_small, (a, b))
        s_large, r_large = large.step(s_large, (scale * a, scale * b))
        tol = position_tolerance(large, r_large, r_small["residual"])
        # strains: end displacements (each within tol) over lengths; R: k_c per closure
        spacing = min(SPACING_WARP, SPACING_WEFT)
        assert np.abs(r_small["strain"] - r_large["strain"]).max() <= tol / spacing
        tiled = np.tile(r_small["contact_force"], (2, 2))
        k_c = small.model.structure.tie_contact_law[0, 0]
        assert np.abs(tiled - r_large["contact_force"]).max() <= k_c * tol
        assert r_small["contact_force"].max() > 0
        # warp 0 of the large cell, first repeat, is warp 0 of the small one
        n = small.model.structure.chain_start[1]
        assert np.abs(s_large.positions[:n] - s_small.positions[:n]).max() <= tol
