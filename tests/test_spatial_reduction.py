"""The spatial fabric reduces to the planar one (docs/model.md section 11): with every node's
in-plane lateral dof held (a warp's y, a weft's x) the spatial terms on global (x, y, z)
coordinates are the planar fabric's on each chain's (along, z): the stretch and the
elevation bending are section 2's, the contact the same law on z, and the crossing's slip in
the warp's frame (its chord along +x) is (X_j - x_a, y_b - Y_k), the planar slip with its first
component's sign turned (the Huber potential is isotropic), its rotation constant (pi / 2).

The check solves the pull-out of runs/fabric_pullout.toml to its peak, its crossings fixed (a
clamped patch with friction, fixed planes, displacement control) step by step with both term sets, each step from the
planar solver's previous state lifted to 3D (anchors too), and compares the equilibria: they
agree within the planar step's own error bound (`steps/error_estimate`, residual x est
||H^-1||), twice it for the two solutions' errors.
"""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np

from dynfab.model.builders import build_model
from dynfab.solvers.newton_sparse import SparseNewton
from dynfab.solvers.static import StaticSolver
from dynfab.model.structure import Structure, chain_of_node
from independent import pullout_scene


def lift(planar: Structure, pos2: np.ndarray) -> np.ndarray:
    """Chain-frame (along, z) positions to global (x, y, z): a warp at y = Y_k, a weft at
    x = X_j (docs/model.md section 10)."""
    chain = chain_of_node(planar)
    plane = planar.chain_plane[chain]
    warp = planar.chain_family[chain] == 0
    x = np.where(warp, pos2[:, 0], plane)
    y = np.where(warp, plane, pos2[:, 0])
    return np.column_stack([x, y, pos2[:, 1]])


def lower(planar: Structure, pos3: np.ndarray) -> np.ndarray:
    chain = chain_of_node(planar)
    warp = planar.chain_family[chain] == 0
    return np.column_stack([np.where(warp, pos3[:, 0], pos3[:, 1]), pos3[:, 2]])


def spatial_twin(planar: Structure) -> Structure:
    """The planar fabric's structure in 3D, each chain's lateral dof held."""
    n = planar.rest_position.shape[0]
    chain = chain_of_node(planar)
    warp = planar.chain_family[chain] == 0
    fixed2 = planar.fixed.reshape(n, 2)
    fixed = np.column_stack([np.where(warp, fixed2[:, 0], True),
                             np.where(warp, True, fixed2[:, 0]), fixed2[:, 1]])
    start = planar.chain_start
    stencil = []
    for node in (planar.tie_a, planar.tie_b):
        c = chain[node]
        stencil.append(np.stack([np.maximum(node - 1, start[c]), node,
                                 np.minimum(node + 1, start[c + 1] - 1)], axis=1))
    ties = planar.tie_a.size
    return planar._replace(
        rest_position=lift(planar, planar.rest_position), fixed=fixed.ravel(),
        dof_tie=np.full(3 * n, -1, np.int64), lateral_bend_stiffness=np.zeros(n),
        lateral_rest_angle=np.zeros(n), tie_stencil=np.concatenate(stencil, axis=1),
        tie_rotation_law=np.column_stack([np.full(ties, 1e-3), np.zeros(ties),
                                          np.full(ties, np.pi / 2)]))


def spatial_anchors(planar_anchors: np.ndarray) -> np.ndarray:
    """(xi_x, xi_y) of the planar slip to the spatial anchor (-xi_x, xi_y, pi / 2)."""
    return np.column_stack([-planar_anchors[:, 0], planar_anchors[:, 1],
                            np.full(planar_anchors.shape[0], np.pi / 2)])


def test_the_spatial_terms_with_the_lateral_dofs_held_solve_the_planar_pull_out():
    scene = pullout_scene()  # fixed crossings, to the peak
    model = build_model(scene)
    planar = model.structure
    assert planar.plane_nodes_a.size == 0 and not planar.wrap_stiffness.any()  # fixed planes
    twin = SimpleNamespace(structure=spatial_twin(planar), scene=scene)
    backend = SparseNewton(twin)
    solver = StaticSolver(model)
    state = model.initial_state()
    for index in range(5):
        start = model.start_of_step(state, model.step_load(index))
        state, record = solver.step(state, model.step_load(index))
        pos3 = lift(planar, start.positions)
        backend.equilibrium(pos3, np.zeros(planar.chain_start.size - 1),
                            spatial_anchors(start.anchors))
        bound = 2.0 * float(np.max(record["error_estimate"]))
        assert bound < 1e-7  # the pull-out's steps are certified to well below a micrometre
        difference = np.abs(lower(planar, pos3) - state.positions).max()
        assert difference <= bound, (index, difference, bound)
        lateral = np.abs(pos3 - lift(planar, state.positions)).max()
        assert lateral <= bound
