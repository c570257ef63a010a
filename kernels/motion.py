"""The time-integration state of a batch of yarns: a Warp struct of per-yarn arrays.

What a time-stepping kernel carries from one launch to the next: positions,
velocities, the forces at the positions, the integration masses and time step,
the damping's own state, counters and the outcome (`dynfab.kernels.status`).
Row y belongs to yarn y; N+1 nodes, C crossings, 2 (N+1) dofs.
"""

import functools

import numpy as np
import warp as wp

from dynfab.banded import BANDWIDTH
from dynfab.kernels.precision import VECTORS
from dynfab.kernels.yarn_arrays import rows


@functools.cache
def struct(scalar):
    """The `Motion` struct type for one scalar type."""
    vec = VECTORS[scalar]

    @wp.struct
    class Motion:
        """Per-yarn time-integration state (docs/model.md section 5)."""

        position: wp.array2d(dtype=vec)
        """Node positions [m], shape (yarns, N+1)."""
        velocity: wp.array2d(dtype=vec)
        """Node velocities [m/s] (half-step velocities of symplectic Euler), shape (yarns, N+1)."""
        force: wp.array2d(dtype=vec)
        """Force at `position` [N], zero on fixed dofs, shape (yarns, N+1)."""
        previous_force: wp.array2d(dtype=vec)
        """Force one time step earlier [N] (adaptive viscous damping), shape (yarns, N+1)."""
        previous_position: wp.array2d(dtype=vec)
        """Positions before the last time step [m] (semi_implicit: to undo a rejected step),
        shape (yarns, N+1)."""
        start_position: wp.array2d(dtype=vec)
        """Positions at the start of the load step [m], shape (yarns, N+1)."""
        start_force: wp.array2d(dtype=vec)
        """Force at the start of the load step [N] (the energy check), shape (yarns, N+1)."""
        mass: wp.array2d(dtype=scalar)
        """Integration masses [kg] (fictitious or physical), shape (yarns, N+1)."""
        band: wp.array3d(dtype=scalar)
        """Banded tangent stiffness scratch [N/m], shape (yarns, 2 (N+1), 11)."""
        solution: wp.array2d(dtype=scalar)
        """Right-hand side / solution scratch of banded solves, shape (yarns, 2 (N+1))."""
        anchors: wp.array2d(dtype=scalar)
        """Friction anchors xi_j [m], shape (yarns, C)."""
        contact_force: wp.array2d(dtype=scalar)
        """R_j at `position` [N], shape (yarns, C)."""
        contact_tangent: wp.array2d(dtype=scalar)
        """dR/dg at `position` [N/m], 0 where open, shape (yarns, C)."""
        friction_limit: wp.array2d(dtype=scalar)
        """F_T,j at `position` [N], shape (yarns, C)."""
        dt: wp.array(dtype=scalar)
        """Time step [s] in use, shape (yarns,)."""
        stable_dt: wp.array(dtype=scalar)
        """Gershgorin bound 2 min_i sqrt(m_i / sum_j |K_ij|) [s] at the load step's start,
        shape (yarns,)."""
        kinetic_energy: wp.array(dtype=scalar)
        """1/2 v^T M v [J] after the last step, shape (yarns,)."""
        damping_coefficient: wp.array(dtype=scalar)
        """Viscous c [1/s] in use, shape (yarns,)."""
        fire_alpha: wp.array(dtype=scalar)
        """FIRE mixing parameter alpha [-], shape (yarns,)."""
        fire_positive_steps: wp.array(dtype=wp.int32)
        """FIRE: steps in a row with positive power, shape (yarns,)."""
        fire_negative_steps: wp.array(dtype=wp.int32)
        """FIRE: steps in a row with non-positive power, shape (yarns,)."""
        dissipated: wp.array(dtype=scalar)
        """transient: friction work since the start of the run [J], shape (yarns,)."""
        residual: wp.array(dtype=scalar)
        """Largest |free force component| at `position` [N], shape (yarns,)."""
        tolerance: wp.array(dtype=scalar)
        """Residual to reach in this load step [N] (`relaxation.start`), shape (yarns,)."""
        start_residual: wp.array(dtype=scalar)
        """The residual at the start of the load step [N], shape (yarns,)."""
        work_bound: wp.array(dtype=scalar)
        """explicit: the largest f0 . (x - x0) of the load step so far [J], f0 and x0 at its
        start: what the forces can have released (`relaxation.check_energy`), shape (yarns,)."""
        kinetic_peak: wp.array(dtype=scalar)
        """explicit: the largest kinetic energy since the last energy test [J], shape (yarns,)."""
        energy_ratio: wp.array(dtype=scalar)
        """explicit: the largest kinetic energy / work_bound of the load step so far [-],
        shape (yarns,)."""
        best_residual: wp.array(dtype=scalar)
        """The smallest residual of the load step so far [N], shape (yarns,)."""
        steps_since_best: wp.array(dtype=wp.int32)
        """Time steps since `best_residual` last fell, shape (yarns,)."""
        rounding_floor: wp.array(dtype=scalar)
        """Estimated rounding floor of the residual [N], shape (yarns,)."""
        steps: wp.array(dtype=wp.int32)
        """Time steps taken in this load step, shape (yarns,)."""
        force_evaluations: wp.array(dtype=wp.int32)
        """Force evaluations in this load step, shape (yarns,)."""
        status: wp.array(dtype=wp.int32)
        """Outcome code (`dynfab.kernels.status`), shape (yarns,)."""

    return Motion


VECTOR_FIELDS = ("position", "velocity", "force", "previous_force", "previous_position",
                 "start_position", "start_force")
"""Fields of shape (yarns, N+1) of vectors."""
CROSSING_FIELDS = ("anchors", "contact_force", "contact_tangent", "friction_limit")
"""Fields of shape (yarns, C)."""
SCALAR_FIELDS = ("dt", "stable_dt", "kinetic_energy", "damping_coefficient", "fire_alpha",
                 "dissipated", "residual", "start_residual", "best_residual", "rounding_floor",
                 "work_bound", "kinetic_peak", "energy_ratio", "tolerance")
"""Fields of shape (yarns,) of scalars."""
COUNTER_FIELDS = ("fire_positive_steps", "fire_negative_steps", "steps_since_best", "steps",
                  "force_evaluations", "status")
"""Fields of shape (yarns,) of int32."""
FIELDS = (*VECTOR_FIELDS, "mass", "band", "solution", *CROSSING_FIELDS, *SCALAR_FIELDS,
          *COUNTER_FIELDS)
"""Every field; each has one row per yarn."""


def allocate(scalar, yarns: int, nodes: int, crossings: int, device: str):
    """A zeroed Motion for `yarns` yarns of `nodes` nodes and `crossings` crossings."""
    vec = VECTORS[scalar]
    motion = struct(scalar)()
    for name in VECTOR_FIELDS:
        setattr(motion, name, wp.zeros((yarns, nodes), dtype=vec, device=device))
    motion.mass = wp.zeros((yarns, nodes), dtype=scalar, device=device)
    motion.band = wp.zeros((yarns, 2 * nodes, 2 * BANDWIDTH + 1), dtype=scalar, device=device)
    motion.solution = wp.zeros((yarns, 2 * nodes), dtype=scalar, device=device)
    for name in CROSSING_FIELDS:
        setattr(motion, name, wp.zeros((yarns, crossings), dtype=scalar, device=device))
    for name in SCALAR_FIELDS:
        setattr(motion, name, wp.zeros(yarns, dtype=scalar, device=device))
    for name in COUNTER_FIELDS:
        setattr(motion, name, wp.zeros(yarns, dtype=wp.int32, device=device))
    return motion


def view(motion, first: int, stop: int):
    """The Motion of yarns first..stop-1 of `motion`, as views of its memory (no copy): what
    a kernel launched on the view writes is what `motion` then holds for those yarns."""
    part = struct(motion.mass.dtype)()
    for name in FIELDS:
        setattr(part, name, rows(getattr(motion, name), first, stop))
    return part


def start_load_step(motion, positions: np.ndarray, anchors: np.ndarray, scalar, device: str) -> None:
    """Reset a Motion for a new load step from positions (yarns, N+1, 2) [m] and anchors (yarns, C) [m].

    Velocities and counters go to zero; the kernel's first step computes forces,
    masses and the time step.
    """
    motion.position.assign(wp.array(positions, dtype=VECTORS[scalar], device=device))
    motion.anchors.assign(wp.array(anchors, dtype=scalar, device=device))
    for name in ("velocity", "steps", "force_evaluations", "status"):
        getattr(motion, name).zero_()


def restore(motion, frame: dict, scalar, device: str) -> None:
    """Put a saved transient frame back: positions, velocities and nodal forces (yarns, N+1, 2)
    [m, m/s, N] and anchors (yarns, C) [m]; the masses and time step already in `motion` are
    kept. The force is the one the next time step uses, stored rather than re-evaluated so
    that a resumed run repeats the uninterrupted one bit for bit."""
    for name, field in (("positions", "position"), ("velocities", "velocity"), ("force", "force")):
        getattr(motion, field).assign(wp.array(frame[name], dtype=VECTORS[scalar], device=device))
    motion.anchors.assign(wp.array(frame["anchors"], dtype=scalar, device=device))
