"""Per-yarn outcome codes that the time-stepping kernels write (`Motion.status`)."""

RUNNING = 0
"""Still relaxing: the next launch continues it."""
CONVERGED = 1
"""Residual at or below the tolerance."""
ROUNDING_FLOOR = 2
"""The residual stopped falling within the rounding floor, above the tolerance
(docs/model.md section 5)."""
MAX_STEPS = 3
"""The load step used `max_steps` time steps."""
DIVERGED = 4
"""The residual grew beyond `DIVERGENCE_FACTOR` x its value at the start of the load step,
or (explicit) the kinetic energy beyond `ENERGY_FACTOR` x the work the forces can have done
since then (`relaxation.check_energy`)."""
NON_FINITE = 5
"""A force or the kinetic energy became NaN or infinite."""
STALLED = 6
"""FIRE: the power stayed negative for `fire.MAX_NEGATIVE_STEPS` steps in a row."""
NOT_POSITIVE_DEFINITE = 7
"""semi_implicit: no time step gave the LU factorisation positive pivots."""

NO_PROGRESS = 8
"""semi_implicit: the residual has not reached a new low during the last half of the load
step's time steps, after at least `semi_implicit.STALL_MIN_STEPS`."""

SUCCESS = (CONVERGED, ROUNDING_FLOOR)
"""The codes of a load step that ended well."""

DIVERGENCE_FACTOR = 1e6
"""A residual this many times the load step's starting residual (or the tolerance,
if larger) means unstable motion. A stable damped relaxation stays within about
sqrt(cond(M^-1 K)) of its start (a few thousand on the paper's yarns); an unstable
explicit mode (omega dt > 2) multiplies the residual by about (omega dt)^2 - 2 per
step, so at 10x the stable time step it crosses the bound within a handful of steps."""

ENERGY_FACTOR = 1e3
"""Kinetic energy / the largest f0 . (x - x0) of the load step [-] beyond which an explicit
integration has diverged (`dynfab.kernels.structure_checks`). At most about 1 in exact stable
dynamics from rest with a convex energy, 5.3 for symplectic Euler's half-step velocities at
safety 0.9 (100 at omega dt = 1.99; tests/test_dynamic_relaxation.py checks 5.3 on the
paper relaxations). An unstable mode multiplies its energy every step, so it passes 1e3 in
a bounded number of steps (tests/test_dynamic_relaxation.py bounds it at 1.3 x the predicted
dt); the test, every `structure_checks.ENERGY_CHECK_INTERVAL` steps, sees it at the next
multiple."""
