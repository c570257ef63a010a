"""Kinetic damping (Barnes): zero the velocities at each peak of kinetic energy (MODEL.md 5).

One symplectic Euler step v += dt M^-1 f(x); x += dt v, unless the kinetic
energy of the new half-step velocities is below the last one: the peak has
just been passed. Then, with the usual back-step correction, the positions go
back to the estimated peak, half a step before the current ones,
x* = x - dt/2 v^{n-1/2} (= x^{n+1} - 3/2 dt v^{n+1/2} + dt^2/2 M^-1 f^n), and v = 0.
"""

import functools
from types import SimpleNamespace

import warp as wp

from dynfab.kernels import motion as motion_module
from dynfab.kernels.precision import VECTORS


@functools.cache
def functions(scalar) -> SimpleNamespace:
    """The kinetic-damping step `wp.func` for one scalar type."""
    vec = VECTORS[scalar]
    Motion = motion_module.struct(scalar)

    @wp.func
    def trial_kinetic_energy(y: int, motion: Motion, dt: scalar) -> scalar:
        """1/2 sum_i m_i |v_i + dt f_i / m_i|^2 [J]: the kinetic energy a full step would reach."""
        energy = scalar(0.0)
        for i in range(motion.mass.shape[1]):
            m = motion.mass[y, i]
            v = motion.velocity[y, i] + (dt / m) * motion.force[y, i]
            energy += scalar(0.5) * m * wp.dot(v, v)
        return energy

    @wp.func
    def step(y: int, motion: Motion):
        """Advance yarn y by one time step, or reset it at a kinetic energy peak."""
        dt = motion.dt[y]
        energy = trial_kinetic_energy(y, motion, dt)
        if energy < motion.kinetic_energy[y]:
            for i in range(motion.mass.shape[1]):
                back = (scalar(0.5) * dt) * motion.velocity[y, i]
                motion.position[y, i] = motion.position[y, i] - back
                motion.velocity[y, i] = vec(scalar(0.0), scalar(0.0))
            motion.kinetic_energy[y] = scalar(0.0)
        else:
            for i in range(motion.mass.shape[1]):
                v = motion.velocity[y, i] + (dt / motion.mass[y, i]) * motion.force[y, i]
                motion.velocity[y, i] = v
                motion.position[y, i] = motion.position[y, i] + dt * v
            motion.kinetic_energy[y] = energy

    return SimpleNamespace(step=step)
