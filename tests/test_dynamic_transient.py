"""The dynamic solver's transient runs in physical time (docs/model.md sections 4-5).

Energy: undamped symplectic Euler has, at whole steps, an O(dt) energy error that
oscillates without drift (docs/model.md section 5) on a scene without contact switching or
friction kinks. Friction: the anchors are return-mapped at every time step, so
no frame carries a friction force above Gralen's limit.
"""

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from dynfab.model import assembly
from dynfab.solvers.dynamic import DynamicSolver
from dynfab.model.yarn import initial_state
from dynfab.model.builders import build_model
from dynfab.scene import load_scene, validate_scene, with_key

RUNS = Path(__file__).resolve().parent.parent / "runs"
EPS = np.finfo(np.float64).eps


def run_frames(scene):
    """Every frame of a transient run of `scene` from the as-woven state, and the solver."""
    model = build_model(scene)
    solver = DynamicSolver(model)
    return list(solver.transient(initial_state(model))), solver


def total_energy(frame) -> float:
    """Kinetic plus every potential term [J] of the (single) yarn."""
    return sum(value[0] for name, value in frame.items() if name.startswith("energy/"))


def energy_errors(scene, dt, steps):
    """|E(t) - E(0)| [J] at 1000 frames of `steps` undamped steps of `dt` [s]."""
    scene = with_key(scene, "dynamic.dt", dt)
    scene = with_key(with_key(scene, "dynamic.duration", steps * dt), "dynamic.output_interval",
                     steps * dt / 1000)
    frames, solver = run_frames(scene)
    assert solver.relaxation.group_values("steps")[0] == steps
    assert min(frame["contact_force"].min() for frame in frames) > 0.0  # no contact switching
    energy = np.array([total_energy(frame) for frame in frames])
    return np.abs(energy - energy[0])


def test_undamped_energy_error_is_bounded_and_first_order():
    """relax.toml undamped: the prestressed paper yarn released at zero load, contacts closed
    throughout."""
    scene = with_key(load_scene(RUNS / "relax.toml"), "dynamic.damping_coefficient", 0.0)
    model = build_model(scene)
    dt = 0.5 * DynamicSolver(model).predicted_stable_dt(initial_state(model))[0]
    coarse = energy_errors(scene, dt, 100_000)
    fine = energy_errors(scene, dt / 2, 200_000)
    for errors in (coarse, fine):
        # No drift: the second half's largest error is not above the first half's
        # (10 % slack: 500 frames sample the oscillation of the error).
        assert errors[500:].max() <= 1.1 * errors[:501].max()
    # First order: the error is dt g(t) + O(dt^2); its RMS over the frames averages the
    # oscillation (the maximum of sampled peaks is noisier), so log2 of the ratio is 1
    # up to the O(dt^2) part, a few % at half the stable dt.
    rms = [np.sqrt(np.mean(errors ** 2)) for errors in (coarse, fine)]
    order = np.log2(rms[0] / rms[1])
    assert 0.9 <= order <= 1.1, f"energy error order {order:.2f}, expected 1"


@pytest.fixture(scope="module")
def friction_run():
    """Fig. 5 (friction on and off), ramped to u = 2 mm over 5 ms, a frame every 0.5 ms."""
    scene = with_key(load_scene(RUNS / "paper_fig5.toml"), "load.values", [0.001, 0.002])
    scene = validate_scene(replace(scene, dynamic=replace(scene.dynamic, mode="transient",
                                                          duration=5e-3, output_interval=5e-4)))
    return build_model(scene), *run_frames(scene)


def test_frames_follow_the_load_ramp(friction_run):
    model, frames, _ = friction_run
    assert np.allclose([frame["time"] for frame in frames], np.arange(11) * 5e-4, rtol=0, atol=1e-15)
    ramp = np.interp([frame["time"] for frame in frames], [0.0, 2.5e-3, 5e-3], [0.0, 1e-3, 2e-3])
    end = np.array([frame["positions"][:, -1, 0] - model.stacked("rest_position")[:, -1, 0]
                    for frame in frames])
    # x_N = x0_N + u(t) is set exactly, up to the rounding of x0_N + u (x ~ 0.1 m).
    assert np.abs(end - ramp[:, None]).max() <= 4 * EPS * 0.1
    for name in ("velocities", "contact_force", "anchors", "energy/kinetic", "energy/stick"):
        assert name in frames[0]


def test_anchors_are_return_mapped_every_step(friction_run):
    model, frames, solver = friction_run
    yarn = model.yarns[0]
    for frame in frames:
        positions, anchors = frame["positions"][0], frame["anchors"][0]
        contact_force, limit, tangent = (np.zeros(model.crossings) for _ in range(3))
        assembly.contact_state(positions, yarn, contact_force, limit, tangent)
        friction_force = yarn.stick_stiffness * np.abs(positions[yarn.crossing_node, 0] - anchors)
        # |k_t (x - xi)| <= F_T after each return map, up to the rounding of x - xi (x ~ 0.1 m).
        assert (friction_force <= limit + 4 * EPS * yarn.stick_stiffness * 0.1).all()
    dissipated = solver.relaxation.group_values("dissipated")  # per tie, since t = 0
    yarn_of_tie = np.searchsorted(model.structure.chain_start, model.structure.tie_a,
                                  side="right") - 1
    assert dissipated[yarn_of_tie == 0].sum() > 0.0
    assert dissipated[yarn_of_tie == 1].sum() == 0.0  # entry 1 has no friction (alpha = beta = 0)
