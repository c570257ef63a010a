"""The transient kernel: symplectic Euler in physical time, viscous c (default 0)
(docs/model.md sections 4-5).

Each time step, from the force f^n at x^n and time t:

    v = ((1 - c dt/2) v + dt M^-1 f^n) / (1 + c dt/2),   x += dt v,

under displacement control x_N = x0_N + u(t + dt) with the ramp's velocity;
then f^{n+1} at the new positions and time, and the friction anchors are
return-mapped at every step (docs/model.md section 4: transient runs do not use the
incremental form), dissipating F_T |delta xi|. The load path is piecewise
linear in time through (0, 0) and (k T / n, value_k), k = 1..n, T = duration,
and held at its last value after T.
"""

import functools
from types import SimpleNamespace

import warp as wp

from dynfab.kernels import forces, friction, motion as motion_module, settings as settings_module
from dynfab.kernels import stability, status, viscous_damping, yarn_arrays
from dynfab.kernels.configuration import MODULE_OPTIONS, Configuration, cached
from dynfab.kernels.precision import VECTORS


@functools.cache
def functions(scalar) -> SimpleNamespace:
    """The load ramp `wp.func` for one scalar type."""

    @wp.func
    def load_at(time: scalar, values: wp.array(dtype=scalar), duration: scalar) -> scalar:
        """The load [N or m] at `time` [s]: linear between (0, 0) and the values at k T / n."""
        n = values.shape[0]
        position = wp.min(time / duration, scalar(1.0)) * scalar(n)
        k = wp.min(int(position), n - 1)
        before = scalar(0.0)
        if k > 0:
            before = values[k - 1]
        return before + (position - scalar(k)) * (values[k] - before)

    return SimpleNamespace(load_at=load_at)


@cached
def transient_kernel(configuration: Configuration):
    """Kernel advance(yarn, motion, settings, load_path) for one variant (transient)."""
    scalar = configuration.scalar
    vec = VECTORS[scalar]
    YarnArrays = yarn_arrays.struct(scalar)
    Motion = motion_module.struct(scalar)
    Settings = settings_module.struct(scalar)
    force_ops = forces.functions(scalar, configuration.terms)
    stability_ops = stability.functions(scalar, configuration.terms)
    viscous_ops = viscous_damping.functions(scalar)
    friction_ops = friction.functions(scalar)
    load_at = functions(scalar).load_at
    has_friction, force_control = "friction" in configuration.terms, configuration.force_control

    @wp.func
    def evaluate(y: int, yarn: YarnArrays, motion: Motion, end_load: scalar):
        """f [N] at motion.position under the load at this time; counts the evaluation."""
        force_ops.evaluate(y, motion.position, yarn, motion.anchors, end_load, motion.force,
                           motion.contact_force, motion.contact_tangent, motion.friction_limit)
        motion.force_evaluations[y] = motion.force_evaluations[y] + 1

    @wp.func
    def prescribe_end(y: int, yarn: YarnArrays, motion: Motion, before: scalar, after: scalar,
                      dt: scalar):
        """Displacement control: x_N = x0_N + u(t + dt), v_N = (u(t + dt) - u(t)) / dt."""
        last = motion.position.shape[1] - 1
        motion.position[y, last] = vec(yarn.rest_position[y, last][0] + after,
                                       motion.position[y, last][1])
        motion.velocity[y, last] = vec((after - before) / dt, motion.velocity[y, last][1])

    @wp.kernel(module="unique", module_options=MODULE_OPTIONS)
    def advance(yarn: YarnArrays, motion: Motion, settings: Settings, load_path: wp.array(dtype=scalar)):
        y = wp.tid()
        if motion.force_evaluations[y] == 0:
            evaluate(y, yarn, motion, load_at(settings.time, load_path, settings.duration))
            stability_ops.choose_masses(y, yarn, motion, settings)
            motion.dissipated[y] = scalar(0.0)
            return
        dt = settings.fixed_dt
        motion.dt[y] = dt
        for k in range(settings.chunk):
            time = settings.time + scalar(k) * dt
            before = load_at(time, load_path, settings.duration)
            after = load_at(time + dt, load_path, settings.duration)
            viscous_ops.step(y, motion, settings)
            if wp.static(not force_control):
                prescribe_end(y, yarn, motion, before, after, dt)
            evaluate(y, yarn, motion, after)
            if wp.static(has_friction):
                motion.dissipated[y] = motion.dissipated[y] + friction_ops.return_map(
                    y, motion.position, yarn.crossing_node, motion.anchors, motion.friction_limit,
                    yarn.stick_stiffness)
            motion.steps[y] = motion.steps[y] + 1
            if not wp.isfinite(motion.kinetic_energy[y]):
                motion.status[y] = status.NON_FINITE
                return

    return advance
