"""The solver options a time-stepping kernel reads (docs/model.md section 5;
`dynfab.scene.Dynamic`)."""

import functools

import warp as wp

RELATIVE_TOLERANCE = 1e-6
"""The default tolerance's share of the load step's force scale [-] (`relaxation.start`):
the default residual is min(DEFAULT_TOLERANCE, max(RELATIVE_TOLERANCE x scale, rounding
floor)), so 1e-8 N from a force scale of 0.01 N up (the paper's loads and contact forces)
and proportionally less below it."""


@functools.cache
def struct(scalar):
    """The `Settings` struct type for one scalar type."""

    @wp.struct
    class Settings:
        """Options of one load step, the same for every yarn."""

        end_load: scalar
        """P [N] under force control (unused under displacement control)."""
        tolerance: scalar
        """Residual to reach [N] (with relative_tolerance > 0: at most)."""
        relative_tolerance: scalar
        """Default tolerance's share of the load step's force scale [-]; 0: `tolerance` as
        given (a tolerance the user asked for)."""
        safety: scalar
        """Fraction of the Gershgorin stable time step used [-]."""
        fixed_dt: scalar
        """Time step asked for [s]; 0: 1 s with fictitious masses, safety x bound with physical ones."""
        fictitious: wp.int32
        """1: fictitious Gershgorin masses; 0: physical masses."""
        damping_coefficient: scalar
        """Viscous c [1/s]; negative: adaptive (Rayleigh quotient)."""
        max_steps: wp.int32
        """Time steps allowed in the load step."""
        chunk: wp.int32
        """Time steps this launch may take before returning to Python."""
        time: scalar
        """transient: the time at the start of this launch [s]."""
        duration: scalar
        """transient: the time over which the load path is ramped [s]."""

    return Settings


def fill(scalar, **values):
    """A Settings instance with the given fields."""
    settings = struct(scalar)()
    for name, value in values.items():
        setattr(settings, name, value)
    return settings
