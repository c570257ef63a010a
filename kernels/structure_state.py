"""What the structure kernels update: one Warp struct of flat arrays per node, tie, block,
chain, dof and group (docs/model.md section 5).

Per group the integration state a time loop carries from one launch to the next (time step,
damping state, counters, the convergence bookkeeping of `structure_checks`, the status of
`dynfab.kernels.status`); per node positions, velocities, forces and masses; per tie the
contact and friction state and the anchors (and, where the crossings slide, the stretches
lambda_a, lambda_b their friction measures slips with, docs/model.md 11.13c); per block the partial sums of a group's sums
(`structure_arrays` docstring); per chain and dof the semi-implicit system and its
conjugate-gradient vectors (allocated only for that method: empty otherwise).
"""


import functools

import numpy as np
import warp as wp

from dynfab.linalg.banded import BANDWIDTH
from dynfab.kernels import band_lu
from dynfab.kernels.precision import vector

WIDTH = 2 * BANDWIDTH + 1
"""Entries of a planar band row: band[i, j - i + BANDWIDTH] = A_ij (`band_lu`; in space
2 `band_lu.bandwidth(3)` + 1)."""
TIE_HESSIAN = 7
"""Per spatial crossing, the semi-implicit tangent's numbers: dR/dg and the upper triangle of
the 3 x 3 Hessian on (s_x, s_y, phi) (`spatial_terms.tangent_terms`)."""
CG_SCALARS = 6
"""Per-group CG scalars: r^T z, the stop value, alpha, beta, done, iterations."""
BOUNDARY_SUMS = 6
"""Per-group sums of the moving planes (U_a, U_b, G_a, G_b) and the tied dofs' diagonals."""


def struct(scalar, dim: int = 2):
    """The `StructureState` Warp struct (`_struct`), one per (scalar, dim) however called."""
    return _struct(scalar, int(dim))


@functools.cache
def _struct(scalar, dim: int):
    """The `StructureState` Warp struct for one scalar type and `dim` coordinates per node
    (`rows` and `diagonal`: each node's Gershgorin row sum and diagonal where the host
    computes them, `allocate`)."""
    vec = vector(scalar, dim)
    vec4 = wp.types.vector(4, scalar)

    class StructureState:
        """The mutable state of a relaxation or transient (module docstring)."""

        # ---- per node (n)
        position: wp.array(dtype=vec)
        velocity: wp.array(dtype=vec)
        force: wp.array(dtype=vec)
        previous_force: wp.array(dtype=vec)
        previous_position: wp.array(dtype=vec)
        start_position: wp.array(dtype=vec)
        start_force: wp.array(dtype=vec)
        load: wp.array(dtype=vec)
        mass: wp.array(dtype=scalar)
        node_values: wp.array(dtype=vec4)
        # ---- per tie (T)
        anchors: wp.array(dtype=vec)
        stretch: wp.array(dtype=vec)
        held: wp.array(dtype=vec)
        contact: wp.array(dtype=scalar)
        tangent: wp.array(dtype=scalar)
        limit: wp.array(dtype=scalar)
        friction: wp.array(dtype=vec)
        dissipated: wp.array(dtype=scalar)
        coupling: wp.array(dtype=vec4)
        tie_hessian: wp.array2d(dtype=scalar)
        # ---- per block (B)
        block_values: wp.array(dtype=vec4)
        block_max: wp.array(dtype=scalar)
        # ---- per chain (Y)
        chain_failed: wp.array(dtype=wp.int32)
        chain_partial: wp.array(dtype=scalar)
        # ---- per dof (dim n; empty unless semi-implicit)
        band: wp.array2d(dtype=scalar)
        factor: wp.array2d(dtype=scalar)
        rhs: wp.array(dtype=scalar)
        x: wp.array(dtype=scalar)
        r: wp.array(dtype=scalar)
        z: wp.array(dtype=scalar)
        p: wp.array(dtype=scalar)
        q: wp.array(dtype=scalar)
        # ---- per group (G)
        dt: wp.array(dtype=scalar)
        stable_dt: wp.array(dtype=scalar)
        kinetic_energy: wp.array(dtype=scalar)
        damping_coefficient: wp.array(dtype=scalar)
        fire_alpha: wp.array(dtype=scalar)
        fire_positive: wp.array(dtype=wp.int32)
        fire_negative: wp.array(dtype=wp.int32)
        decision: wp.array(dtype=scalar)
        residual: wp.array(dtype=scalar)
        merit: wp.array(dtype=scalar)
        tolerance: wp.array(dtype=scalar)
        start_residual: wp.array(dtype=scalar)
        best_residual: wp.array(dtype=scalar)
        steps_since_best: wp.array(dtype=wp.int32)
        rounding_floor: wp.array(dtype=scalar)
        work_bound: wp.array(dtype=scalar)
        kinetic_peak: wp.array(dtype=scalar)
        energy_ratio: wp.array(dtype=scalar)
        steps: wp.array(dtype=wp.int32)
        force_evaluations: wp.array(dtype=wp.int32)
        status: wp.array(dtype=wp.int32)
        cg_iterations: wp.array(dtype=wp.int32)
        rejected: wp.array(dtype=wp.int32)
        shortened: wp.array(dtype=wp.int32)
        backtracks: wp.array(dtype=wp.int32)
        search: wp.array(dtype=wp.int32)
        factored: wp.array(dtype=wp.int32)
        refactorisations: wp.array(dtype=wp.int32)
        step_length: wp.array(dtype=scalar)
        mixing: wp.array(dtype=scalar)
        cg: wp.array2d(dtype=scalar)
        boundary: wp.array2d(dtype=scalar)
        rows: wp.array(dtype=scalar)
        diagonal: wp.array(dtype=scalar)

    return wp.struct(StructureState)


NODE_VECTORS = ("position", "velocity", "force", "previous_force", "previous_position",
                "start_position", "start_force", "load")
NODE_SCALARS = ("mass",)
TIE_SCALARS = ("contact", "tangent", "limit", "dissipated")
GROUP_SCALARS = ("dt", "stable_dt", "kinetic_energy", "damping_coefficient", "fire_alpha",
                 "decision", "residual", "merit", "tolerance", "start_residual", "best_residual",
                 "rounding_floor", "work_bound", "kinetic_peak", "energy_ratio", "step_length",
                 "mixing")
GROUP_COUNTERS = ("fire_positive", "fire_negative", "steps_since_best", "steps",
                  "force_evaluations", "status", "cg_iterations", "rejected", "shortened",
                  "backtracks", "search", "factored", "refactorisations")
DOF_VECTORS = ("rhs", "x", "r", "z", "p", "q")


def allocate(arrays, scalar, device: str, semi_implicit: bool, rows_from_host: bool):
    """A zeroed StructureState for `arrays` (`structure_arrays.StructureArrays`); the dof arrays
    of the semi-implicit system only with `semi_implicit`; the masses' Gershgorin rows and
    diagonals (`rows`, `diagonal`) where the host gives them (`rows_from_host`, the elements'
    `ROWS_FROM_HOST`), otherwise the band for the kernels to assemble them in."""
    dim = arrays.dim
    vec, vec4 = vector(scalar, dim), wp.types.vector(4, scalar)
    n, T, B, Y, G = arrays.nodes, arrays.ties, arrays.blocks, arrays.chains, arrays.groups
    dofs = dim * n if semi_implicit else 0
    width = 2 * band_lu.bandwidth(dim) + 1
    state = struct(scalar, dim)()

    def zeros(shape, dtype):
        return wp.zeros(shape, dtype=dtype, device=device)

    for name in NODE_VECTORS:
        setattr(state, name, zeros(n, vec))
    for name in NODE_SCALARS:
        setattr(state, name, zeros(n, scalar))
    state.node_values = zeros(n, vec4)
    state.anchors, state.friction, state.coupling = zeros(T, vec), zeros(T, vec), zeros(T, vec4)
    state.stretch = zeros(T if arrays.sliding else 0, vec)
    state.held = zeros(T if arrays.sliding else 0, vec)
    for name in TIE_SCALARS:
        setattr(state, name, zeros(T, scalar))
    state.block_values, state.block_max = zeros(B, vec4), zeros(B, scalar)
    state.chain_failed = zeros(Y, wp.int32)
    state.chain_partial = zeros(Y, scalar)
    state.band = zeros((dofs if rows_from_host else max(dofs, dim * n), width), scalar)
    state.tie_hessian = zeros((T if semi_implicit else 0, TIE_HESSIAN), scalar)
    host_rows = n if rows_from_host else 0
    state.rows, state.diagonal = zeros(host_rows, scalar), zeros(host_rows, scalar)
    state.factor = zeros((dofs, width), scalar)
    for name in DOF_VECTORS:
        setattr(state, name, zeros(dofs, scalar))
    for name in GROUP_SCALARS:
        setattr(state, name, zeros(G, scalar))
    for name in GROUP_COUNTERS:
        setattr(state, name, zeros(G, wp.int32))
    state.cg = zeros((G, CG_SCALARS), scalar)
    state.boundary = zeros((G, BOUNDARY_SUMS), scalar)
    return state


def read(state, name: str) -> np.ndarray:
    """A field of the state as a float64 (or int) numpy array."""
    values = getattr(state, name).numpy()
    return values.astype(np.float64) if values.dtype.kind == "f" else values.copy()
