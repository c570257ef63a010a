"""Kinetic damping (Barnes): zero the velocities at each peak of kinetic energy
(docs/model.md section 5), with a viscous fallback where the relaxation stops settling.

One symplectic Euler step v += dt M^-1 f(x); x += dt v, unless the kinetic
energy of the new half-step velocities is below the last one: the peak has
just been passed. Then, with the usual back-step correction, the positions go
back to the estimated peak, half a step before the current ones,
x* = x - dt/2 v^{n-1/2} (= x^{n+1} - 3/2 dt v^{n+1/2} + dt^2/2 M^-1 f^n), and v = 0.

Fallback (`escalate`). Kinetic damping dissipates only at its resets, and between
them the motion is undamped. With the friction limit coupled to the closure
(F_T(R(g)), docs/model.md section 4) the force is not the gradient of an energy: near a crossing
at g ~ 0 the Jacobian's circulatory part (dF_T/dg up to ~4e3 N/m against slow-mode
stiffnesses of ~1 N/m) gives M^-1 J complex eigenvalue pairs with |Im| ~ Re, which
undamped motion amplifies, and the crossing's open/closed kink bounds that growth into a
limit cycle: the crossing opens and closes with g near the static solution while the
residual cycles for good. A weak viscous damping cycles there as well, a stronger one
converges. Kinetic damping's own residual is no guide to when it is stuck: the largest
force component falls in bursts. (The measurements behind this and behind the constants
below: docs/model.md, "The dynamic solver (decisions)", kinetic damping.) So a yarn still
running after KINETIC_STEPS steps switches, for the rest of the load step, to viscous
damping with c dt = FALLBACK_DAMPING, and c is multiplied by FALLBACK_GROWTH each time
the fallback's residual then sets no new low for STALL_STEPS steps (at most c dt = 2,
where the centred damping's velocity factor reaches 0). A relaxation that settles
within KINETIC_STEPS (every paper relaxation does) is unchanged bit for bit.
"""

import functools
from types import SimpleNamespace

import warp as wp

from dynfab.kernels import motion as motion_module, viscous_damping
from dynfab.kernels.precision import VECTORS

KINETIC_STEPS = 200_000
"""Time steps of kinetic damping before the viscous fallback: above the slowest settling
kinetic relaxation measured (docs/model.md, "The dynamic solver (decisions)")."""
STALL_STEPS = 100_000
"""Time steps without a new low of the residual after which the fallback's c grows."""
FALLBACK_DAMPING = 0.05
"""c dt [-] of the first viscous fallback."""
FALLBACK_GROWTH = 2.0
"""Factor on c at each further stall of the fallback [-]. With FALLBACK_DAMPING = 0.05 and
2 the hardest steps measured on the as-woven onset path finish (steps 5 and 10 in
`tests/test_dynamic_onset.py`); 0.1 and 4 left one unfinished (docs/model.md, "The dynamic
solver (decisions)", kinetic damping)."""


@functools.cache
def functions(scalar) -> SimpleNamespace:
    """The kinetic-damping step `wp.func`s for one scalar type."""
    vec = VECTORS[scalar]
    Motion = motion_module.struct(scalar)
    viscous_ops = viscous_damping.functions(scalar)

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
    def kinetic_step(y: int, motion: Motion):
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

    @wp.func
    def start(y: int, motion: Motion):
        """At the load step's start: kinetic damping, no fallback yet (c = 0)."""
        motion.damping_coefficient[y] = scalar(0.0)

    @wp.func
    def step(y: int, motion: Motion):
        """One time step: kinetic damping, or the viscous fallback once it has begun (c > 0)."""
        coefficient = motion.damping_coefficient[y]
        if coefficient > scalar(0.0):
            viscous_ops.step_with(y, motion, coefficient)
        else:
            kinetic_step(y, motion)

    @wp.func
    def escalate(y: int, motion: Motion):
        """Start the viscous fallback at c dt = FALLBACK_DAMPING after KINETIC_STEPS steps, or,
        once it runs, multiply its c by FALLBACK_GROWTH (at most c dt = 2) after STALL_STEPS
        steps without a new low of the residual; each time from rest, the stall count starting
        again from the current residual."""
        coefficient = motion.damping_coefficient[y]
        dt = motion.dt[y]
        if coefficient == scalar(0.0):
            if motion.steps[y] < KINETIC_STEPS:
                return
            coefficient = scalar(FALLBACK_DAMPING) / dt
        else:
            if motion.steps_since_best[y] < STALL_STEPS:
                return
            coefficient = wp.min(coefficient * scalar(FALLBACK_GROWTH), scalar(2.0) / dt)
        motion.damping_coefficient[y] = coefficient
        for i in range(motion.mass.shape[1]):
            motion.velocity[y, i] = vec(scalar(0.0), scalar(0.0))
        motion.kinetic_energy[y] = scalar(0.0)
        motion.best_residual[y] = motion.residual[y]
        motion.steps_since_best[y] = 0

    return SimpleNamespace(start=start, step=step, escalate=escalate)
