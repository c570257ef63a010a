"""Integration masses and the stable time step by Gershgorin's theorem (docs/model.md section 5).

Symplectic Euler is stable while dt omega_max < 2, and Gershgorin bounds
omega_max^2 = lambda_max(M^-1 K) <= max_i sum_j |K_ij| / m_i. So

- fictitious masses: dt = 1 s (or the dt asked for) and m_i = dt^2 / (4 safety^2)
  sum_j |K_ij|, the largest row sum over the node's two dofs;
- physical masses m_i = rho_l lbar_i: dt = safety x 2 min_i sqrt(m_i / sum_j |K_ij|)
  (or the dt asked for).

K is the stiffest tangent the load step can meet (`forces.assemble_band` with
`stiffest`): every contact at its bound k_we, every crossing sticking (k_t),
stretch and bending at the load step's starting positions.
"""

import functools
from types import SimpleNamespace

import warp as wp

from dynfab.kernels import forces, motion as motion_module, settings as settings_module
from dynfab.kernels import yarn_arrays


@functools.cache
def functions(scalar, terms: tuple) -> SimpleNamespace:
    """The mass-and-time-step `wp.func` of one term selection (`Configuration.terms`) and scalar type."""
    YarnArrays = yarn_arrays.struct(scalar)
    Motion = motion_module.struct(scalar)
    Settings = settings_module.struct(scalar)
    force_ops = forces.functions(scalar, terms)

    @wp.func
    def choose_masses(y: int, yarn: YarnArrays, motion: Motion, settings: Settings):
        """Set motion.mass [kg], motion.dt [s] and motion.stable_dt [s] of yarn y."""
        force_ops.assemble_band(y, motion.position, yarn, motion.anchors, motion.contact_tangent,
                                motion.friction_limit, False, True, motion.band)
        nodes = motion.mass.shape[1]
        if settings.fictitious != 0:
            dt = scalar(1.0)
            if settings.fixed_dt > scalar(0.0):
                dt = settings.fixed_dt
            for i in range(nodes):
                motion.mass[y, i] = dt * dt / (scalar(4.0) * settings.safety * settings.safety) \
                    * force_ops.gershgorin_row_sums(y, motion.band, i)
            motion.dt[y] = dt
            motion.stable_dt[y] = dt / settings.safety
        else:
            bound = scalar(1.0e30)
            for i in range(nodes):
                motion.mass[y, i] = yarn.mass[y, i]
                rows = force_ops.gershgorin_row_sums(y, motion.band, i)
                if rows > scalar(0.0):
                    bound = wp.min(bound, scalar(2.0) * wp.sqrt(yarn.mass[y, i] / rows))
            motion.stable_dt[y] = bound
            motion.dt[y] = settings.safety * bound
            if settings.fixed_dt > scalar(0.0):
                motion.dt[y] = settings.fixed_dt

    return SimpleNamespace(choose_masses=choose_masses)
