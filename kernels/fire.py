"""FIRE 2.0 (Guenole et al. 2020, Comput. Mater. Sci. 175, 109584) with symplectic Euler
(docs/model.md section 5).

Per step, with power P = f . v:

- P > 0 for more than N_delay steps in a row: dt = min(f_inc dt, dt_max), alpha *= f_alpha;
- P <= 0: (after the first N_delay steps of the load step) dt = f_dec dt if that
  stays above dt_min, alpha = alpha_start; x -= dt/2 v (back to the mid-step,
  FIRE 2.0's correction) and v = 0; more than N_neg_max such steps in a row: stalled;
- then v += dt M^-1 f, v = (1 - alpha) v + alpha |v| f / |f| (the mixing), x += dt v.

dt starts at most at DT_START and grows to at most DT_MAX times the Gershgorin
stable time step (`motion.stable_dt`), dt_min is DT_MIN times it. The mixing
turns the velocity toward f, which the stiff axial modes dominate, so FIRE is
unstable well below the plain integrator's bound; DT_START and DT_MAX come from the
time steps the benchmark step takes against dt_max (docs/results.md, "FIRE's largest
time step").
"""

import functools
from types import SimpleNamespace

import warp as wp

from dynfab.kernels import motion as motion_module
from dynfab.kernels.precision import VECTORS

DELAY_STEPS = 20
"""N_delay: positive-power steps before dt may grow; no dt decrease in the first N_delay steps."""
MAX_NEGATIVE_STEPS = 2000
"""N_neg_max: non-positive-power steps in a row after which FIRE has stalled."""
DT_GROWTH = 1.1
"""f_inc [-]."""
DT_SHRINK = 0.5
"""f_dec [-]."""
ALPHA_START = 0.25
"""alpha_start [-]."""
ALPHA_SHRINK = 0.99
"""f_alpha [-]."""
DT_START = 0.5
"""Largest starting dt / stable_dt [-]."""
DT_MAX = 0.6
"""dt_max / stable_dt [-]."""
DT_MIN = 0.02
"""dt_min / stable_dt [-]."""


@functools.cache
def functions(scalar) -> SimpleNamespace:
    """The FIRE step `wp.func`s for one scalar type."""
    vec = VECTORS[scalar]
    Motion = motion_module.struct(scalar)

    @wp.func
    def start(y: int, motion: Motion):
        """FIRE's state at the start of a load step: alpha_start, dt at most DT_START x the bound."""
        motion.dt[y] = wp.min(motion.dt[y], scalar(DT_START) * motion.stable_dt[y])
        motion.fire_alpha[y] = scalar(ALPHA_START)
        motion.fire_positive_steps[y] = 0
        motion.fire_negative_steps[y] = 0

    @wp.func
    def power(y: int, motion: Motion) -> scalar:
        """P = f . v [W]."""
        total = scalar(0.0)
        for i in range(motion.mass.shape[1]):
            total += wp.dot(motion.force[y, i], motion.velocity[y, i])
        return total

    @wp.func
    def adapt(y: int, motion: Motion) -> bool:
        """FIRE 2.0's dt and alpha update and velocity reset; False once stalled."""
        dt = motion.dt[y]
        if power(y, motion) > scalar(0.0):
            motion.fire_positive_steps[y] = motion.fire_positive_steps[y] + 1
            motion.fire_negative_steps[y] = 0
            if motion.fire_positive_steps[y] > DELAY_STEPS:
                dt = wp.min(dt * scalar(DT_GROWTH), scalar(DT_MAX) * motion.stable_dt[y])
                motion.fire_alpha[y] = motion.fire_alpha[y] * scalar(ALPHA_SHRINK)
        else:
            motion.fire_positive_steps[y] = 0
            motion.fire_negative_steps[y] = motion.fire_negative_steps[y] + 1
            if motion.fire_negative_steps[y] > MAX_NEGATIVE_STEPS:
                return False
            if motion.steps[y] >= DELAY_STEPS:
                if dt * scalar(DT_SHRINK) >= scalar(DT_MIN) * motion.stable_dt[y]:
                    dt = dt * scalar(DT_SHRINK)
                motion.fire_alpha[y] = scalar(ALPHA_START)
            for i in range(motion.mass.shape[1]):
                back = (scalar(0.5) * dt) * motion.velocity[y, i]
                motion.position[y, i] = motion.position[y, i] - back
                motion.velocity[y, i] = vec(scalar(0.0), scalar(0.0))
        motion.dt[y] = dt
        return True

    @wp.func
    def step(y: int, motion: Motion) -> bool:
        """One FIRE 2.0 step of yarn y; False once stalled."""
        if not adapt(y, motion):
            return False
        dt = motion.dt[y]
        speed2 = scalar(0.0)
        force2 = scalar(0.0)
        for i in range(motion.mass.shape[1]):
            v = motion.velocity[y, i] + (dt / motion.mass[y, i]) * motion.force[y, i]
            motion.velocity[y, i] = v
            speed2 += wp.dot(v, v)
            force2 += wp.dot(motion.force[y, i], motion.force[y, i])
        alpha = motion.fire_alpha[y]
        mixing = scalar(0.0)
        if force2 > scalar(0.0):
            mixing = alpha * wp.sqrt(speed2 / force2)
        energy = scalar(0.0)
        for i in range(motion.mass.shape[1]):
            v = (scalar(1.0) - alpha) * motion.velocity[y, i] + mixing * motion.force[y, i]
            motion.velocity[y, i] = v
            motion.position[y, i] = motion.position[y, i] + dt * v
            energy += scalar(0.5) * motion.mass[y, i] * wp.dot(v, v)
        motion.kinetic_energy[y] = energy
        return True

    return SimpleNamespace(start=start, step=step)
