"""Linearly implicit backward Euler relaxation (Baraff and Witkin 1998; docs/model.md section 5).

Each time step solves, per yarn in O(N) (banded LU without pivoting),

    (M (1 + dt c) + dt^2 K) dv = dt (f - dt K v - c M v),   v += dv,   x += dt v,

with f the force at x and K the banded tangent of V plus the Huber terms
(k_t on sticking crossings, F_T frozen), made positive semi-definite:

- a compressed segment's negative geometric stretch part (1 - l0/l < 0) is dropped;
- bending keeps k dphi dphi^T and drops k (phi - phi0) d2phi, which can be indefinite;

so the matrix, with M > 0 on the diagonal, is positive definite. If rounding
still gives a pivot that is not positive (at very large dt), dt is halved and
the matrix rebuilt.

Time step rule: start at the explicit dt (1 s with fictitious masses, safety x
the Gershgorin bound with physical ones). A step is accepted if it lowers the
residual measured in the mass metric, f^T M^-1 f, and dt then doubles;
otherwise it is undone (positions back, velocities zeroed) and dt halves.
As dt grows, dt (v + dv) tends to K^-1 f: the steps become Newton steps on the
definite part of K, so a load step ends in a few dozen steps. The mass metric,
not the largest component, decides: for small dt the step tends to
dt^2 M^-1 f, along which f^T M^-1 f falls wherever K is positive definite
(d/dt = -2 f^T M^-1 K M^-1 f), whereas the largest component need not; and
undoing, not merely shrinking, keeps Newton steps from cycling as crossings
switch between sticking and sliding.
`c` is the viscous coefficient when one is given (else 0).
"""

import functools
from types import SimpleNamespace

import warp as wp

from dynfab.banded import BANDWIDTH
from dynfab.kernels import banded, forces, motion as motion_module, relaxation
from dynfab.kernels import settings as settings_module, status, yarn_arrays
from dynfab.kernels.configuration import MODULE_OPTIONS, Configuration, cached
from dynfab.kernels.precision import VECTORS

DT_GROWTH = 2.0
"""dt factor after an accepted step [-]."""
DT_SHRINK = 0.5
"""dt factor after a rejected step, or after a pivot that is not positive [-]."""
MAX_REFACTORISATIONS = 60
"""dt halvings allowed to obtain positive pivots in one step."""
STALL_MIN_STEPS = 10_000
"""Time steps after which a load step whose residual has not reached a new low during the
last half of its steps stops (status.NO_PROGRESS) instead of running to max_steps. Where
semi_implicit converges it takes far fewer (docs/results.md, "semi_implicit's steps per
load step"); a step cycling between stick and slip sets no new low, and ends after at most
twice the steps it took to stop improving, not after dynamic.max_steps."""


@functools.cache
def functions(scalar, terms: tuple) -> SimpleNamespace:
    """The semi-implicit step `wp.func`s for one term selection (`Configuration.terms`) and scalar type."""
    vec = VECTORS[scalar]
    YarnArrays = yarn_arrays.struct(scalar)
    Motion = motion_module.struct(scalar)
    Settings = settings_module.struct(scalar)
    force_ops = forces.functions(scalar, terms)
    band_ops = banded.functions(scalar)
    force_control = "load" in terms

    @wp.func
    def velocity_dof(motion: Motion, y: int, dof: int) -> scalar:
        """Component dof % 2 of node dof / 2's velocity [m/s]."""
        return motion.velocity[y, dof / 2][dof % 2]

    @wp.func
    def build_system(y: int, yarn: YarnArrays, motion: Motion, dt: scalar, c: scalar):
        """band = M (1 + dt c) + dt^2 K, solution = dt (f - dt K v - c M v), fixed dofs constrained."""
        force_ops.assemble_band(y, motion.position, yarn, motion.anchors, motion.contact_tangent,
                                motion.friction_limit, True, False, motion.band)
        dofs = motion.band.shape[1]
        for dof in range(dofs):
            m = motion.mass[y, dof / 2]
            stiffness_velocity = scalar(0.0)
            for j in range(wp.max(0, dof - BANDWIDTH), wp.min(dofs, dof + BANDWIDTH + 1)):
                stiffness_velocity += (motion.band[y, dof, j - dof + BANDWIDTH]
                                       * velocity_dof(motion, y, j))
            motion.solution[y, dof] = dt * (motion.force[y, dof / 2][dof % 2] - dt * stiffness_velocity
                                            - c * m * velocity_dof(motion, y, dof))
        for dof in range(dofs):
            for k in range(2 * BANDWIDTH + 1):
                motion.band[y, dof, k] = dt * dt * motion.band[y, dof, k]
            motion.band[y, dof, BANDWIDTH] += (scalar(1.0) + dt * c) * motion.mass[y, dof / 2]
        band_ops.constrain(motion.band, y, 0, motion.solution)
        band_ops.constrain(motion.band, y, 1, motion.solution)
        band_ops.constrain(motion.band, y, dofs - 1, motion.solution)
        if wp.static(not force_control):
            band_ops.constrain(motion.band, y, dofs - 2, motion.solution)

    @wp.func
    def step(y: int, yarn: YarnArrays, motion: Motion, settings: Settings) -> bool:
        """One linearly implicit step of yarn y; False if no dt gave positive pivots."""
        c = wp.max(settings.damping_coefficient, scalar(0.0))
        dt = motion.dt[y]
        factored = bool(False)
        for _ in range(MAX_REFACTORISATIONS):
            build_system(y, yarn, motion, dt, c)
            if band_ops.lu_factor(motion.band, y) < 0:
                factored = True
                break
            dt = dt * scalar(DT_SHRINK)
        if not factored:
            return False
        motion.dt[y] = dt
        band_ops.lu_solve(motion.band, y, motion.solution)
        energy = scalar(0.0)
        for i in range(motion.mass.shape[1]):
            motion.previous_position[y, i] = motion.position[y, i]
            v = motion.velocity[y, i] + vec(motion.solution[y, 2 * i], motion.solution[y, 2 * i + 1])
            motion.velocity[y, i] = v
            motion.position[y, i] = motion.position[y, i] + dt * v
            energy += scalar(0.5) * motion.mass[y, i] * wp.dot(v, v)
        motion.kinetic_energy[y] = energy
        return True

    @wp.func
    def merit(y: int, motion: Motion) -> scalar:
        """f^T M^-1 f [N^2/kg]: the squared residual in the mass metric."""
        total = scalar(0.0)
        for i in range(motion.mass.shape[1]):
            total += wp.dot(motion.force[y, i], motion.force[y, i]) / motion.mass[y, i]
        return total

    @wp.func
    def adapt(y: int, motion: Motion, previous_merit: scalar) -> bool:
        """The time step rule: double dt after a step that lowered f^T M^-1 f; otherwise undo the
        step (positions back, velocities 0), halve dt and return True (forces to re-evaluate)."""
        rejected = not merit(y, motion) < previous_merit
        if rejected:
            motion.dt[y] = motion.dt[y] * scalar(DT_SHRINK)
            for i in range(motion.mass.shape[1]):
                motion.position[y, i] = motion.previous_position[y, i]
                motion.velocity[y, i] = vec(scalar(0.0), scalar(0.0))
        else:
            motion.dt[y] = motion.dt[y] * scalar(DT_GROWTH)
        return rejected

    return SimpleNamespace(step=step, merit=merit, adapt=adapt)


@cached
def relaxation_kernel(configuration: Configuration):
    """Kernel relax(yarn, motion, settings) for one variant (semi_implicit, quasi-static)."""
    scalar = configuration.scalar
    YarnArrays = yarn_arrays.struct(scalar)
    Motion = motion_module.struct(scalar)
    Settings = settings_module.struct(scalar)
    relax_ops = relaxation.functions(scalar, configuration.terms)
    semi_ops = functions(scalar, configuration.terms)

    @wp.kernel(module="unique", module_options=MODULE_OPTIONS)
    def relax(yarn: YarnArrays, motion: Motion, settings: Settings):
        y = wp.tid()
        if motion.force_evaluations[y] == 0:
            relax_ops.start(y, yarn, motion, settings)
        if motion.status[y] != status.RUNNING:
            return
        for _ in range(settings.chunk):
            previous_merit = semi_ops.merit(y, motion)
            if not semi_ops.step(y, yarn, motion, settings):
                motion.status[y] = status.NOT_POSITIVE_DEFINITE
                return
            relax_ops.evaluate(y, yarn, motion, settings)
            if semi_ops.adapt(y, motion, previous_merit):
                relax_ops.evaluate(y, yarn, motion, settings)
            code = relax_ops.check(y, motion, settings)
            if relax_ops.check_progress(y, motion, code, STALL_MIN_STEPS) != status.RUNNING:
                return

    return relax
