"""What every quasi-static relaxation kernel does around its integrator (MODEL.md 5).

`start` evaluates the forces at the load step's starting positions and chooses
the masses and the time step; `check` judges the residual after each step:
converged, diverged (non-finite, or grown beyond `status.DIVERGENCE_FACTOR`),
at the rounding floor, out of steps, or still running.

Rounding floor (MODEL.md 5, as the static reference's, MODEL.md 6): a residual
below ROUNDING_FLOOR_FACTOR eps max_i |K_ii| max_i |x_i| is within the rounding of
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


@functools.cache
def functions(scalar, has_friction: bool, has_gravity: bool, force_control: bool) -> SimpleNamespace:
    """`evaluate`, `start` and `check` for one term selection and scalar type."""
    YarnArrays = yarn_arrays.struct(scalar)
    Motion = motion_module.struct(scalar)
    Settings = settings_module.struct(scalar)
    terms = (scalar, has_friction, has_gravity, force_control)
    force_ops = forces.functions(*terms)
    stability_ops = stability.functions(*terms)
    floor_scale = ROUNDING_FLOOR_FACTOR * epsilon(scalar)

    @wp.func
    def evaluate(y: int, yarn: YarnArrays, motion: Motion, settings: Settings):
        """motion.force [N] (and R, dR/dg, F_T) at motion.position; counts the evaluation."""
        force_ops.evaluate(y, motion.position, yarn, motion.anchors, settings.end_load, motion.force,
                           motion.contact_force, motion.contact_tangent, motion.friction_limit)
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
    def start(y: int, yarn: YarnArrays, motion: Motion, settings: Settings):
        """Forces, masses, time step and residual at the load step's start (velocities are 0)."""
        evaluate(y, yarn, motion, settings)
        stability_ops.choose_masses(y, yarn, motion, settings)
        residual = force_ops.residual(y, motion.force)
        motion.residual[y] = residual
        motion.start_residual[y] = residual
        motion.best_residual[y] = residual
        motion.steps_since_best[y] = 0
        motion.kinetic_energy[y] = scalar(0.0)
        motion.rounding_floor[y] = rounding_floor(y, motion)
        for i in range(motion.position.shape[1]):
            motion.start_position[y, i] = motion.position[y, i]
        if residual <= settings.tolerance:
            motion.status[y] = status.CONVERGED

    @wp.func
    def at_rounding_floor(y: int, motion: Motion) -> bool:
        """The best residual is within the rounding floor and has not fallen for half the steps."""
        return (motion.best_residual[y] <= motion.rounding_floor[y]
                and motion.steps[y] >= FLOOR_MIN_STEPS
                and 2 * motion.steps_since_best[y] > motion.steps[y])

    @wp.func
    def check(y: int, motion: Motion, settings: Settings) -> int:
        """Count the step just taken and set motion.status [-] from the new residual [N]."""
        motion.steps[y] = motion.steps[y] + 1
        residual = force_ops.residual(y, motion.force)
        motion.residual[y] = residual
        if residual < motion.best_residual[y]:
            motion.best_residual[y] = residual
            motion.steps_since_best[y] = 0
        else:
            motion.steps_since_best[y] = motion.steps_since_best[y] + 1
        code = status.RUNNING
        if not (wp.isfinite(residual) and wp.isfinite(motion.kinetic_energy[y])):
            code = status.NON_FINITE
        elif residual <= settings.tolerance:
            code = status.CONVERGED
        elif residual > scalar(status.DIVERGENCE_FACTOR) * wp.max(motion.start_residual[y],
                                                                  settings.tolerance):
            code = status.DIVERGED
        elif at_rounding_floor(y, motion):
            code = status.ROUNDING_FLOOR
        elif motion.steps[y] >= settings.max_steps:
            code = status.MAX_STEPS
        motion.status[y] = code
        return code

    return SimpleNamespace(evaluate=evaluate, start=start, check=check)
