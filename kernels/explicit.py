"""The explicit relaxation kernel: symplectic Euler with kinetic, viscous or FIRE damping
(docs/model.md section 5).

One thread per yarn; each launch runs up to `settings.chunk` time steps of
every yarn still running, so Python can report progress and stop between
launches. A yarn's first launch of a load step (`start`) evaluates the
forces and chooses masses and time step; every step then integrates,
evaluates the forces at the new positions and checks the residual. The
damping is chosen with `wp.static`: a variant holds only its own.
"""

import warp as wp

from dynfab.kernels import fire, kinetic_damping, motion as motion_module, relaxation
from dynfab.kernels import settings as settings_module, status, viscous_damping, yarn_arrays
from dynfab.kernels.configuration import MODULE_OPTIONS, Configuration, cached


@cached
def relaxation_kernel(configuration: Configuration):
    """Kernel relax(yarn, motion, settings) for one variant (explicit, quasi-static)."""
    scalar = configuration.scalar
    YarnArrays = yarn_arrays.struct(scalar)
    Motion = motion_module.struct(scalar)
    Settings = settings_module.struct(scalar)
    relax_ops = relaxation.functions(scalar, configuration.terms)
    damping = configuration.damping
    kinetic_ops = kinetic_damping.functions(scalar)
    viscous_ops = viscous_damping.functions(scalar)
    fire_ops = fire.functions(scalar)

    @wp.kernel(module="unique", module_options=MODULE_OPTIONS)
    def relax(yarn: YarnArrays, motion: Motion, settings: Settings):
        y = wp.tid()
        if motion.force_evaluations[y] == 0:
            relax_ops.start(y, yarn, motion, settings)
            if wp.static(damping == "kinetic"):
                kinetic_ops.start(y, motion)
            if wp.static(damping == "fire"):
                fire_ops.start(y, motion)
        if motion.status[y] != status.RUNNING:
            return
        for _ in range(settings.chunk):
            if wp.static(damping == "kinetic"):
                kinetic_ops.step(y, motion)
            if wp.static(damping == "viscous"):
                viscous_ops.step(y, motion, settings)
            if wp.static(damping == "fire"):
                if not fire_ops.step(y, motion):
                    motion.status[y] = status.STALLED
                    return
            relax_ops.evaluate(y, yarn, motion, settings)
            code = relax_ops.check_energy(y, motion, relax_ops.check(y, motion, settings))
            if code != status.RUNNING:
                return
            if wp.static(damping == "kinetic"):
                kinetic_ops.escalate(y, motion)

    return relax
