"""What every quasi-static relaxation kernel does around its integrator (docs/model.md section 5).

`start` evaluates the forces at the load step's starting positions and chooses
the masses and the time step; `check` judges the residual after each step:
converged, diverged (non-finite, or grown beyond `status.DIVERGENCE_FACTOR`),
at the rounding floor, out of steps, or still running; the explicit kernel adds
`check_energy`, the divergence test by energy.

Energy test (explicit integrators). With f0 and x0 the force and positions at the
load step's start and V convex, V(x0) - V(x) <= f0 . (x - x0) (the tangent plane
lies below V); a stable, damped or undamped motion starting at rest cannot have
more kinetic energy than the potential energy it has released, so
KE <= max_k f0 . (x_k - x0) (the running maximum: the energy never grows).
Symplectic Euler's half-step kinetic energy exceeds the exact one by a bounded
factor (1 / (1 - (omega dt / 2)^2) for a mode at omega dt < 2: 5.3 at safety 0.9),
and the paper's bending and contact are nearly convex over a load step
(tests/test_dynamic_relaxation.py checks the ratio stays below 5.3 on the paper relaxations).
An unstable mode (omega dt > 2) multiplies its energy every step while the work
bound, linear in the amplitude, grows far less: the test trips when
KE > status.ENERGY_FACTOR x that bound. It catches the divergences that the residual
test misses: on fine meshes the unstable chain folds, its forces saturating long
before 1e6 x the step's start residual.

Rounding floor (docs/model.md section 5, as the static reference's, docs/model.md section 6): a
residual below ROUNDING_FLOOR_FACTOR eps max_i |K_ii| max_i |x_i| is within the rounding of
the force sum; a tolerance below it is met once the residual stops falling, i.e.
its best value has not improved during the last half of the load step's steps
(and at least FLOOR_MIN_STEPS steps were taken).
"""

import functools
from types import SimpleNamespace

import warp as wp

from dynfab.banded import BANDWIDTH
from dynfab.kernels import forces, motion as motion_module, settings as settings_module
from dynfab.kernels import stability, status, yarn_arrays
from dynfab.kernels.precision import epsilon

ROUNDING_FLOOR_FACTOR = 16.0
"""Rounding floor of the residual / (eps max_i |K_ii| max_i |x_i|) [-], as in `dynfab.static`."""
FLOOR_MIN_STEPS = 1000
"""Time steps before a stalled residual may be declared at the rounding floor."""
ENERGY_CHECK_INTERVAL = 16
"""The energy test runs every this many time steps (and at the step limit), so that its
O(N) pass over three arrays does not weigh on an explicit step; a divergence is caught at
most 15 steps later. The kinetic energy is taken as its largest value since the last
test."""


@functools.cache
def functions(scalar, terms: tuple) -> SimpleNamespace:
    """`evaluate`, `start` and `check` for one term selection (`Configuration.terms`) and scalar type."""
    YarnArrays = yarn_arrays.struct(scalar)
    Motion = motion_module.struct(scalar)
    Settings = settings_module.struct(scalar)
    force_ops = forces.functions(scalar, terms)
    stability_ops = stability.functions(scalar, terms)
    force_control = "load" in terms
    floor_scale = ROUNDING_FLOOR_FACTOR * epsilon(scalar)

    @wp.func
    def evaluate(y: int, yarn: YarnArrays, motion: Motion, settings: Settings):
        """motion.force [N] (and R, dR/dg, F_T) at motion.position, and its residual [N] in
        motion.residual; counts the evaluation."""
        motion.residual[y] = force_ops.evaluate(y, motion.position, yarn, motion.anchors,
                                                settings.end_load, motion.force, motion.contact_force,
                                                motion.contact_tangent, motion.friction_limit)
        motion.force_evaluations[y] = motion.force_evaluations[y] + 1

    @wp.func
    def rounding_floor(y: int, motion: Motion) -> scalar:
        """ROUNDING_FLOOR_FACTOR eps max_i |K_ii| max_i |x_i| [N], K in motion.band."""
        largest_diagonal = scalar(0.0)
        largest_coordinate = scalar(0.0)
        for i in range(motion.position.shape[1]):
            for c in range(2):
                largest_diagonal = wp.max(largest_diagonal, wp.abs(motion.band[y, 2 * i + c, BANDWIDTH]))
                largest_coordinate = wp.max(largest_coordinate, wp.abs(motion.position[y, i][c]))
        return scalar(floor_scale) * largest_diagonal * largest_coordinate

    @wp.func
    def force_scale(y: int, yarn: YarnArrays, motion: Motion, settings: Settings) -> scalar:
        """The load step's force scale [N] at its start: the largest of |P| (force control),
        the contact forces R_j and the segment tensions |EA (l - l0) / l0|."""
        scale = scalar(0.0)
        if wp.static(force_control):
            scale = wp.abs(settings.end_load)
        for j in range(motion.contact_force.shape[1]):
            scale = wp.max(scale, wp.abs(motion.contact_force[y, j]))
        for i in range(yarn.rest_length.shape[1]):
            length = wp.length(motion.position[y, i + 1] - motion.position[y, i])
            scale = wp.max(scale, wp.abs(yarn.stretch_stiffness[y, i]
                                         * (length - yarn.rest_length[y, i])))
        return scale

    @wp.func
    def step_tolerance(y: int, yarn: YarnArrays, motion: Motion, settings: Settings) -> scalar:
        """The residual to reach [N]: as given, or by default (relative_tolerance > 0)
        min(tolerance, max(relative_tolerance x force scale, rounding floor))
        (docs/model.md section 5)."""
        tolerance = settings.tolerance
        if settings.relative_tolerance > scalar(0.0):
            relative = settings.relative_tolerance * force_scale(y, yarn, motion, settings)
            tolerance = wp.min(tolerance, wp.max(relative, motion.rounding_floor[y]))
        return tolerance

    @wp.func
    def start(y: int, yarn: YarnArrays, motion: Motion, settings: Settings):
        """Forces, masses, time step and residual at the load step's start (velocities are 0)."""
        evaluate(y, yarn, motion, settings)
        stability_ops.choose_masses(y, yarn, motion, settings)
        residual = motion.residual[y]
        motion.start_residual[y] = residual
        motion.best_residual[y] = residual
        motion.steps_since_best[y] = 0
        motion.kinetic_energy[y] = scalar(0.0)
        motion.rounding_floor[y] = rounding_floor(y, motion)
        motion.tolerance[y] = step_tolerance(y, yarn, motion, settings)
        motion.work_bound[y] = scalar(0.0)
        motion.kinetic_peak[y] = scalar(0.0)
        motion.energy_ratio[y] = scalar(0.0)
        for i in range(motion.position.shape[1]):
            motion.start_position[y, i] = motion.position[y, i]
            motion.start_force[y, i] = motion.force[y, i]
        if residual <= motion.tolerance[y]:
            motion.status[y] = status.CONVERGED

    @wp.func
    def at_rounding_floor(y: int, motion: Motion) -> bool:
        """The best residual is within the rounding floor and has not fallen for half the steps."""
        return (motion.best_residual[y] <= motion.rounding_floor[y]
                and motion.steps[y] >= FLOOR_MIN_STEPS
                and 2 * motion.steps_since_best[y] > motion.steps[y])

    @wp.func
    def check(y: int, motion: Motion, settings: Settings) -> int:
        """Count the step just taken and set motion.status [-] from the new residual [N]
        (motion.residual, from the evaluation at the step's new positions)."""
        motion.steps[y] = motion.steps[y] + 1
        residual = motion.residual[y]
        if residual < motion.best_residual[y]:
            motion.best_residual[y] = residual
            motion.steps_since_best[y] = 0
        else:
            motion.steps_since_best[y] = motion.steps_since_best[y] + 1
        code = status.RUNNING
        if not (wp.isfinite(residual) and wp.isfinite(motion.kinetic_energy[y])):
            code = status.NON_FINITE
        elif residual <= motion.tolerance[y]:
            code = status.CONVERGED
        elif residual > scalar(status.DIVERGENCE_FACTOR) * wp.max(motion.start_residual[y],
                                                                  motion.tolerance[y]):
            code = status.DIVERGED
        elif at_rounding_floor(y, motion):
            code = status.ROUNDING_FLOOR
        elif motion.steps[y] >= settings.max_steps:
            code = status.MAX_STEPS
        motion.status[y] = code
        return code

    @wp.func
    def check_progress(y: int, motion: Motion, code: int, min_steps: int) -> int:
        """`code`, or status.NO_PROGRESS if the best residual has not fallen during the last
        half of at least `min_steps` steps (and is above the rounding floor)."""
        if code != status.RUNNING:
            return code
        if (motion.steps[y] >= min_steps and 2 * motion.steps_since_best[y] > motion.steps[y]
                and motion.best_residual[y] > motion.rounding_floor[y]):
            motion.status[y] = status.NO_PROGRESS
            return status.NO_PROGRESS
        return code

    @wp.func
    def check_energy(y: int, motion: Motion, code: int) -> int:
        """`code`, or status.DIVERGED if the kinetic energy [J] exceeds ENERGY_FACTOR x
        the largest f0 . (x - x0) [J] of the load step so far, every ENERGY_CHECK_INTERVAL
        steps with the largest kinetic energy since the last test (kinetic damping's resets
        would otherwise alias with the interval; an explicit integrator only:
        its velocities are those of the motion). Also keeps motion.work_bound and
        motion.energy_ratio."""
        if code != status.RUNNING and code != status.MAX_STEPS:
            return code
        energy = wp.max(motion.kinetic_peak[y], motion.kinetic_energy[y])
        if code == status.RUNNING and motion.steps[y] % ENERGY_CHECK_INTERVAL != 0:
            motion.kinetic_peak[y] = energy
            return code
        motion.kinetic_peak[y] = scalar(0.0)
        work = scalar(0.0)
        for i in range(motion.position.shape[1]):
            work += wp.dot(motion.start_force[y, i],
                           motion.position[y, i] - motion.start_position[y, i])
        bound = wp.max(motion.work_bound[y], work)
        motion.work_bound[y] = bound
        if energy > scalar(0.0):
            if energy > scalar(status.ENERGY_FACTOR) * bound:
                motion.energy_ratio[y] = wp.max(motion.energy_ratio[y], energy / wp.max(
                    bound, scalar(1.0e-30)))
                motion.kinetic_peak[y] = energy  # kept for the message
                motion.status[y] = status.DIVERGED
                return status.DIVERGED
            motion.energy_ratio[y] = wp.max(motion.energy_ratio[y], energy / bound)
        return code

    return SimpleNamespace(evaluate=evaluate, start=start, check=check, check_energy=check_energy,
                           check_progress=check_progress)
