"""Relaxations and transients of the kernel layer for any structure
(`dynfab.kernels.structure_relaxation`) against the static solvers (docs/model.md sections 4-6,
10).

A load step relaxed from the same state as the static solver's step must reach its solution
within the bound their residual tolerances allow: linearising the residual r at the static
solution, x_dynamic - x_static = J^-1 (r(x_dynamic) - r(x_static)), so
|x_dynamic - x_static|_inf <= ||J^-1||_inf (r_dynamic + r_static), J the Jacobian of the residual
on the free dofs (the Hessian with F_T frozen plus, with friction, F_T's coupling through R:
both solvers converge where F_T follows Gralen's law), with the step's anchors
(`agreement_bound`). Cases: the paper's yarn (two chains tied to ground, N = 32, friction,
gravity), the periodic 2 x 2 cell and a clamped 3 x 3 patch with "affine" planes (friction),
each with the explicit (kinetic damping) and the semi-implicit method; the other dampings on
the cell; float32 on the yarn. Transients: the undamped energy of the prestressed paper yarn
released at zero load oscillates without drift at first order in dt; with friction the anchors
are return-mapped at every step and a resumed run repeats the uninterrupted one bit for bit.

Kernel variants: float64 with friction and the boundary couplings compiled in, as
tests/test_kernels_structure.py builds them (explicit kinetic and semi-implicit, grouped,
scatter order), plus the viscous and FIRE explicit kernels, the transient kernel and the
float32 explicit kinetic kernel.
"""

import math
from pathlib import Path

import numpy as np
import pytest

from dynfab.model.builders import build_structure
from dynfab.model.fabric import contact
from dynfab.kernels import status
from dynfab.model.yarn import initial_state
from dynfab.model.builders import build_model
from dynfab.scene import load_scene, with_key
from dynfab.solvers.static import StaticSolver
from test_kernels_structure import (fabric_scene, relaxation, static_solver, yarn_scene,
                                    yarn_scene_sweep)

RUNS = Path(__file__).resolve().parent.parent / "runs"
EPS = np.finfo(float).eps
TOLERANCE = 1e-10
"""Residual tolerance [N] of the relaxations: above the static residual's rounding floor on
these structures (about 1e-11 N at k_c = 1e5 N/m, tests/test_fabric_static.py)."""


def jacobian_norm(structure, positions, anchors) -> float:
    """||J^-1||_inf [m/N] at `positions` with the step's `anchors` (module docstring), by the
    static solver's Hessian and coupling on any structure (its unknowns: a tied family's dof
    counted once)."""
    static = static_solver(structure)
    limit = static.friction_limits(positions)
    J = static.hessian(positions, anchors, limit)
    if structure.has_friction:
        J = J + static.coupling(positions, anchors, limit)
    return float(np.abs(np.linalg.inv(J.toarray())).sum(axis=1).max())


def anchor_bound(structure, positions, bound: float) -> float:
    """The largest anchor difference [m] after the return map given positions within `bound`:
    a sliding tie's anchor is p - (F_T / k_t) s/|s| (p the node's coordinates from the planes):
    p moves by at most sqrt 2 bound (2-norm), (F_T / k_t) s/|s| by at most as much again plus
    dF_T / k_t, with dR <= 2 k_s bound and dF_T/dR <= alpha + (beta ell r_f / R_0)
    exp(-R / R_0) at the smallest R of a closed tie less that change."""
    law, friction = structure.tie_contact_law, structure.tie_friction_law
    R = np.zeros(structure.tie_a.size)
    contact.forces(positions, structure, R)
    dR = 2 * law[:, 0].max() * bound
    R_low = max(R[R > 0].min(initial=0.0) - dR, 0.0)
    onset = friction[:, 2].min()
    slope = friction[:, 0].max() + friction[:, 1].max() / onset * np.exp(-R_low / onset)
    return 2 * np.sqrt(2) * bound + slope * dR / friction[:, 3].min()


METHODS = ("explicit", "semi_implicit")


@pytest.mark.parametrize("method", METHODS)
def test_the_paper_yarn_reaches_the_static_state(method):
    """Two paper yarns (phases +-1, N = 32, friction, gravity) pulled from the as-woven state by
    0.1 N: positions within `agreement_bound`, far below the step's motion; the return-mapped
    anchors within `anchor_bound` of the static solver's."""
    scene = yarn_scene()
    model = build_model(scene)
    start = initial_state(model)
    state, record = StaticSolver(model).step(start, 0.1)
    s = build_structure(scene)
    kernels = relaxation(s, method=method, damping="kinetic")
    anchors = start.anchors  # the structure's (T, 2), a ground tie's second column 0
    positions, outcome = kernels.relax(s.rest_position, kernels.chain_loads([0.1]), anchors,
                                       tolerance=TOLERANCE, max_steps=500_000)
    assert list(outcome.status) == [status.CONVERGED] * 2
    expected = state.positions.reshape(-1, 2)
    bound = jacobian_norm(s, expected, anchors) * (outcome.residual.max()
                                                   + np.max(record["residual"]))
    assert np.abs(positions - expected).max() <= bound
    assert np.abs(expected - s.rest_position).max() > 1e3 * bound
    mapped, lost = kernels.return_map(positions, anchors)
    slid = np.abs(state.anchors - start.anchors).max()
    gap = np.abs(mapped[:, 0] - state.anchors[:, 0]).max()
    assert slid > 1e3 * anchor_bound(s, expected, bound) and gap <= anchor_bound(s, expected, bound)
    assert np.array_equal(mapped[:, 1], np.zeros(s.tie_a.size))  # ground ties slip along x alone
    assert lost.sum() > 0.0


FABRICS = {"periodic": lambda: fabric_scene(2, "periodic"),
           "affine": lambda: fabric_scene(3, "clamped", "affine", gravity=True)}


def fabric_step(name):
    """(structure, start state, the static step's state and record, loads per chain)."""
    scene = with_key(FABRICS[name](), "static.tolerance", TOLERANCE / 10)
    model = build_model(scene)
    static = StaticSolver(model)
    start = static.initial_state()
    values = model.load_values[0]
    state, record = static.step(start.copy(), values)
    return model.structure, start, state, record, model.yarn_loads(*values)


@pytest.mark.parametrize("method", METHODS)
@pytest.mark.parametrize("name", sorted(FABRICS))
def test_a_fabric_reaches_the_static_state(name, method):
    """The fabric's first load step from the as-woven state, each method against
    `StaticSolver.step`: positions within `agreement_bound`, the same closed and sliding
    ties, the return-mapped anchors within `anchor_bound`."""
    s, start, state, record, P = fabric_step(name)
    kernels = relaxation(s, method=method, damping="kinetic")
    positions, outcome = kernels.relax(start.positions, P, start.anchors, tolerance=TOLERANCE,
                                       max_steps=500_000)
    assert list(outcome.status) == [status.CONVERGED]
    bound = jacobian_norm(s, state.positions, start.anchors) * (outcome.residual[0]
                                                                 + record["residual"])
    assert np.abs(positions - state.positions).max() <= bound
    assert np.abs(state.positions - start.positions).max() > 1e3 * bound
    R, _, _ = kernels.tie_forces(positions, start.anchors)
    assert np.array_equal(R > 0, record["contact_force"].ravel() > 0)
    mapped, _ = kernels.return_map(positions, start.anchors)
    sliding = np.any(mapped != start.anchors, axis=1)
    assert np.array_equal(sliding, record["sliding"].ravel())
    if sliding.any():
        assert np.abs(mapped - state.anchors).max() <= anchor_bound(s, state.positions, bound)


@pytest.mark.parametrize("damping, coefficient", [("viscous", None), ("viscous", 0.1),
                                                  ("fire", None)])
def test_the_other_dampings_reach_the_static_state(damping, coefficient):
    """Viscous damping (adaptive c, and a given c) and FIRE on the periodic cell: the first step
    within `agreement_bound` of the static solver's."""
    s, start, state, record, P = fabric_step("periodic")
    kernels = relaxation(s, damping=damping, damping_coefficient=coefficient)
    positions, outcome = kernels.relax(start.positions, P, start.anchors, tolerance=TOLERANCE,
                                       max_steps=500_000)
    assert list(outcome.status) == [status.CONVERGED]
    bound = jacobian_norm(s, state.positions, start.anchors) * (outcome.residual[0]
                                                                 + record["residual"])
    assert np.abs(positions - state.positions).max() <= bound


def test_float32_reaches_the_static_state_within_its_rounding():
    """The paper yarn in float32 (explicit, kinetic damping) to float32's default 1e-4 N: it
    converges or stops at its rounding floor (status SUCCESS), and its positions lie within
    ||J^-1|| (r + r_static) of the static state, r the residual at those positions evaluated in
    float64, plus float32's rounding of a coordinate (4 eps_32 |x|)."""
    scene = yarn_scene()
    model = build_model(scene)
    start = initial_state(model)
    state, record = StaticSolver(model).step(start, 0.1)
    s = build_structure(scene)
    anchors = start.anchors  # the structure's (T, 2), a ground tie's second column 0
    kernels = relaxation(s, damping="kinetic", precision="float32")
    positions, outcome = kernels.relax(s.rest_position, kernels.chain_loads([0.1]), anchors,
                                       tolerance=1e-4, max_steps=500_000)
    assert outcome.succeeded, outcome
    double = relaxation(s)
    residual = np.abs(double.forces(positions, double.chain_loads([0.1]), anchors)).max()
    expected = state.positions.reshape(-1, 2)
    rounding = 4 * np.finfo(np.float32).eps * np.abs(expected).max()
    bound = jacobian_norm(s, expected, anchors) * (residual + np.max(record["residual"]))
    assert np.abs(positions - expected).max() <= bound + rounding
    assert residual < 1e-2  # float32's floor on this yarn, not a runaway


def total_energy(kernels, frame, loads=None) -> float:
    """Kinetic plus potential energy [J] of a frame (every group)."""
    nodes, ties = kernels.energies(frame["positions"], loads, frame["anchors"])
    return math.fsum(nodes) + math.fsum(ties) + float(np.sum(frame["kinetic_energy"]))


def energy_errors(structure, dt: float, steps: int) -> np.ndarray:
    """|E(t) - E(0)| [J] at 1000 frames of `steps` undamped steps of `dt` [s] from rest."""
    kernels = relaxation(structure, masses="physical", damping="viscous",
                         damping_coefficient=0.0, dt=dt, chunk=steps // 1000)
    frames = list(kernels.transient(structure.rest_position, None, [[0.0]],
                                    duration=steps * dt, output_interval=steps * dt / 1000))
    assert kernels.group_values("steps")[0] == steps
    assert min(frame["contact_force"].min() for frame in frames) > 0.0  # no contact switching
    energy = np.array([total_energy(kernels, frame) for frame in frames])
    return np.abs(energy - energy[0])


def test_undamped_energy_error_is_bounded_and_first_order():
    """runs/relax.toml undamped (the prestressed paper yarn released at zero load, contacts
    closed throughout): symplectic Euler's energy at whole steps has an O(dt) error that
    oscillates without drift (docs/model.md section 5): the second half's largest error is not
    above the first half's (10 % slack: 500 frames sample the oscillation), and halving dt
    halves the error's RMS (log2 of the ratio within 0.1 of 1: the O(dt^2) part)."""
    s = build_structure(load_scene(RUNS / "relax.toml"))
    probe = relaxation(s, masses="physical", damping="viscous", damping_coefficient=0.0)
    probe.start(s.rest_position)
    dt = 0.5 * float(probe.group_values("stable_dt")[0])
    coarse = energy_errors(s, dt, 100_000)
    fine = energy_errors(s, dt / 2, 200_000)
    for errors in (coarse, fine):
        assert errors[500:].max() <= 1.1 * errors[:501].max()
    rms = [np.sqrt(np.mean(errors ** 2)) for errors in (coarse, fine)]
    assert 0.9 <= np.log2(rms[0] / rms[1]) <= 1.1


def friction_transient(resume_at=None):
    """The paper yarn (two chains, N = 32, friction) pulled by its end to 2 mm over 5 ms
    (displacement control), a frame every 0.5 ms: (kernels, frames)."""
    scene = yarn_scene()
    scene = with_key(with_key(scene, "load.control", "displacement"), "load.values",
                     [1e-3, 2e-3])
    s = build_structure(scene)
    kernels = relaxation(s, masses="physical", damping="viscous", damping_coefficient=0.0)
    anchors = kernels.as_woven_anchors()
    run = kernels.transient(s.rest_position, anchors, [[1e-3, 2e-3]], duration=5e-3,
                            output_interval=5e-4, resume_from=resume_at)
    return kernels, s, list(run)


def test_transient_friction_follows_the_ramp_and_return_maps_every_step():
    """Under displacement control the ends follow the ramp exactly (x_N = x0_N + u(t), to the
    rounding of x0_N + u); after every time step's return map no tie carries more than its
    limit (k_t |s| <= F_T, to the rounding of the slip); friction dissipates; a run resumed
    from a frame repeats the uninterrupted one bit for bit."""
    kernels, s, frames = friction_transient()
    times = np.array([frame["time"] for frame in frames])
    assert np.allclose(times, np.arange(11) * 5e-4, rtol=0, atol=1e-15)
    ramp = np.interp(times, [0.0, 2.5e-3, 5e-3], [0.0, 1e-3, 2e-3])
    last = s.chain_start[1:] - 1
    for frame, u in zip(frames, ramp):
        end = frame["positions"][last, 0] - s.rest_position[last, 0]
        assert np.abs(end - u).max() <= 4 * EPS * 0.1
        R, friction, limit = kernels.tie_forces(frame["positions"], frame["anchors"])
        stick = s.tie_friction_law[:, 3]
        x = frame["positions"][s.tie_a, 0]
        slip = np.abs(x - frame["anchors"][:, 0])
        assert np.all(stick * slip <= limit + 4 * EPS * stick * 0.1)
    assert frames[-1]["dissipated"].sum() > 0.0
    _, _, resumed = friction_transient(resume_at=frames[4])
    assert resumed[0]["time"] == frames[5]["time"]
    for name in ("positions", "velocities", "anchors", "force"):
        assert np.array_equal(resumed[-1][name], frames[-1][name])


def test_displacement_control_reactions_are_the_static_ones():
    """The affine 3 x 3 patch under displacement control (the ends prescribed, the planes moving
    with them): the relaxed positions within `agreement_bound` of the static step's, and each
    end's reaction, minus the in-plane internal force on its held dof (`internal_force`: no
    external load, every dof unmasked), within the bound times the sum of |H| over that dof's
    row (the reaction's change to first order in the positions: the Hessian's row, F_T frozen;
    no tie on an end node)."""
    from dynfab.model.fabric import assembly

    scene = with_key(fabric_scene(3, "clamped", "affine", load=(2e-4, 5e-5),
                                  control="displacement"), "static.tolerance", TOLERANCE / 10)
    model = build_model(scene)
    static = StaticSolver(model)
    start = static.initial_state()
    state, record = static.step(start.copy(), model.load_values[0])
    s = model.structure
    begun = model.start_of_step(start, model.load_values[0])
    positions, anchors, P = begun.positions, begun.anchors, begun.chain_loads
    kernels = relaxation(s, damping="kinetic")
    relaxed, outcome = kernels.relax(positions, P, anchors, tolerance=TOLERANCE,
                                     max_steps=500_000)
    assert list(outcome.status) == [status.CONVERGED]
    bound = jacobian_norm(s, state.positions, anchors) * (outcome.residual[0] + record["residual"])
    assert np.abs(relaxed - state.positions).max() <= bound
    reaction = -kernels.internal_force(relaxed, anchors)[s.load_node, 0]
    values = np.zeros(static.backend.pattern.size)
    limit = static.backend.friction_limits(state.positions)
    assembly.hessian_values(state.positions, s, anchors, limit, values)
    H = static.backend.pattern.full_matrix(values)
    rows = np.abs(H[2 * s.load_node]).sum(axis=1)
    assert np.all(np.abs(reaction - record["end_force"]) <= rows * bound)
    assert np.abs(record["end_force"]).max() > 1e3 * (rows * bound).max()


def test_a_non_finite_node_stops_its_group_as_non_finite():
    """The residual a group is judged by is its largest |force component|; one NaN node in the
    middle of a chain (its force and its neighbours' NaN, the components compared after them
    finite) makes it NaN, so the group stops as non-finite at once instead of converging on
    its finite components; the other groups run on."""
    s = build_structure(yarn_scene_sweep())
    kernels = relaxation(s, damping="kinetic")
    positions = s.rest_position.copy()
    positions[(s.chain_start[0] + s.chain_start[1]) // 3, 1] = np.nan
    _, outcome = kernels.relax(positions, kernels.chain_loads([0.1]), None, tolerance=1e-9,
                               max_steps=10)
    assert list(outcome.status) == [status.NON_FINITE, status.MAX_STEPS, status.MAX_STEPS]
    assert np.isnan(outcome.residual[0]) and np.isfinite(outcome.residual[1:]).all()
