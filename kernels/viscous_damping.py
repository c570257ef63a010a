"""Viscous damping -c M v, given or adaptive (Underwood's adaptive dynamic relaxation;
docs/model.md section 5).

One step of symplectic Euler with the damping force centred in time,

    v^{n+1/2} = ((1 - c dt/2) v^{n-1/2} + dt M^-1 f^n) / (1 + c dt/2),   x^{n+1} = x^n + dt v^{n+1/2}.

Adaptive c (a negative `settings.damping_coefficient`): twice the lowest
circular frequency estimated by Underwood's Rayleigh quotient,

    c^n = 2 sqrt(u^T K^n u / u^T M u),   K^n_ii = -(f^n_i - f^{n-1}_i) / (dt v^{n-1/2}_i),

u the displacement since the start of the load step (dominated by the
lowest mode as the relaxation proceeds) and K^n the diagonal stiffness
estimated from the last step. A negative quotient gives c = 0; c is capped at
2/dt, where the velocity factor (1 - c dt/2) would turn negative.
"""

import functools
from types import SimpleNamespace

import warp as wp

from dynfab.kernels import motion as motion_module, settings as settings_module


@functools.cache
def functions(scalar) -> SimpleNamespace:
    """The viscous-damping step `wp.func` for one scalar type."""
    Motion = motion_module.struct(scalar)
    Settings = settings_module.struct(scalar)

    @wp.func
    def adaptive_coefficient(y: int, motion: Motion, dt: scalar) -> scalar:
        """c [1/s] = 2 sqrt(q), q = u^T K u / u^T M u by Underwood's diagonal K where it is
        positive and below the secant quotient, otherwise by the secant -u . (f - f0)."""
        underwood = scalar(0.0)
        secant = scalar(0.0)
        mass_term = scalar(0.0)
        for i in range(motion.mass.shape[1]):
            u = motion.position[y, i] - motion.start_position[y, i]
            change = motion.force[y, i] - motion.previous_force[y, i]
            secant -= wp.dot(u, motion.force[y, i] - motion.start_force[y, i])
            for c in range(2):
                moved = dt * motion.velocity[y, i][c]
                if moved != scalar(0.0):
                    underwood += u[c] * u[c] * (-change[c] / moved)
            mass_term += wp.dot(u, u) * motion.mass[y, i]
        stiffness_term = secant
        if underwood > scalar(0.0) and underwood < secant:
            stiffness_term = underwood
        coefficient = scalar(0.0)
        if stiffness_term > scalar(0.0) and mass_term > scalar(0.0):
            coefficient = wp.min(scalar(2.0) * wp.sqrt(stiffness_term / mass_term), scalar(2.0) / dt)
        return coefficient

    @wp.func
    def step_with(y: int, motion: Motion, coefficient: scalar):
        """Advance yarn y by one time step damped by the given c [1/s]."""
        dt = motion.dt[y]
        half_damping = scalar(0.5) * coefficient * dt
        keep = (scalar(1.0) - half_damping) / (scalar(1.0) + half_damping)
        gain = dt / (scalar(1.0) + half_damping)
        energy = scalar(0.0)
        for i in range(motion.mass.shape[1]):
            m = motion.mass[y, i]
            v = keep * motion.velocity[y, i] + (gain / m) * motion.force[y, i]
            motion.velocity[y, i] = v
            motion.position[y, i] = motion.position[y, i] + dt * v
            motion.previous_force[y, i] = motion.force[y, i]
            energy += scalar(0.5) * m * wp.dot(v, v)
        motion.kinetic_energy[y] = energy

    @wp.func
    def step(y: int, motion: Motion, settings: Settings):
        """Advance yarn y by one damped time step; keeps the force for the next estimate."""
        dt = motion.dt[y]
        coefficient = settings.damping_coefficient
        if coefficient < scalar(0.0):
            coefficient = adaptive_coefficient(y, motion, dt)
        motion.damping_coefficient[y] = coefficient
        step_with(y, motion, coefficient)

    return SimpleNamespace(step=step, step_with=step_with)
