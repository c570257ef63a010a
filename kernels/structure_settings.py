"""The options a structure kernel reads, the same for every group of one launch
(docs/model.md section 5)."""

import functools

import warp as wp

MODULE_OPTIONS = {"enable_backward": False}
"""Every structure kernel is forward-only: no adjoint code to generate and compile."""
DAMPINGS = ("viscous", "kinetic", "fire")
"""The explicit dampings; `StructureSettings.damping` is an index in it (docs/model.md section
5). A kernel holds all three (one compile for any damping; the choice, one per run, is a branch
the CPU predicts)."""
VISCOUS, KINETIC, FIRE = range(3)
RELATIVE_TOLERANCE = 1e-6
"""The default tolerance's share of the load step's force scale [-] (docs/model.md, the
dynamic solver's default tolerance: min(D, max(1e-6 F, floor)))."""


@functools.cache
def struct(scalar):
    """The `StructureSettings` struct type for one scalar type."""

    @wp.struct
    class StructureSettings:
        """Options of one relaxation or transient launch."""

        tolerance: scalar
        """Residual to reach [N] (with relative_tolerance > 0: at most)."""
        relative_tolerance: scalar
        """Default tolerance's share of the force scale [-]; 0: `tolerance` as given."""
        safety: scalar
        """Fraction of the Gershgorin stable time step used [-]."""
        fixed_dt: scalar
        """Time step asked for [s]; 0: 1 s with fictitious masses, safety x bound with physical."""
        fictitious: wp.int32
        """1: fictitious Gershgorin masses; 0: physical masses."""
        damping: wp.int32
        """explicit: the damping, its index in `DAMPINGS`."""
        damping_coefficient: scalar
        """Viscous c [1/s]; negative: adaptive (explicit viscous damping)."""
        max_steps: wp.int32
        """Time steps allowed."""
        chunk: wp.int32
        """Time steps of this launch at most (grouped layout)."""
        cg_tolerance: scalar
        """semi-implicit: CG's relative tolerance on the P^-1 norm of the residual [-]."""
        backtracks: wp.int32
        """semi-implicit: halvings of a step's length before it is undone."""
        secant: wp.int32
        """semi-implicit: 1 gives sliding ties the secant Huber block."""
        direct: wp.int32
        """semi-implicit: 1 solves a group whose preconditioner is exact by it alone."""
        time: scalar
        """transient: the time at the start of this launch [s]."""
        duration: scalar
        """transient: the time over which the load path is ramped [s]."""

    return StructureSettings


def fill(scalar, **values):
    """A settings instance with the given fields (the others zero)."""
    settings = struct(scalar)()
    for name, value in values.items():
        setattr(settings, name, value)
    return settings
