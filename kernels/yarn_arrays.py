"""A batch of yarns' Model arrays as one Warp struct (docs/model.md sections 1-4).

Row y of every array is yarn y of `dynfab.model.Model.yarns` (a [sweep] entry
or one of geometry.yarns adjacent yarns); all yarns share N and the crossing nodes.
"""

import functools

import numpy as np
import warp as wp

from dynfab.kernels.precision import VECTORS, numpy_dtype


@functools.cache
def struct(scalar):
    """The `YarnArrays` struct type for one scalar type."""
    vec = VECTORS[scalar]

    @wp.struct
    class YarnArrays:
        """Everything a kernel needs to know about the yarns; constant during a run."""

        rest_position: wp.array2d(dtype=vec)
        """As-woven node positions r0 [m], shape (yarns, N+1)."""
        rest_length: wp.array2d(dtype=scalar)
        """Segment rest lengths l0 [m], shape (yarns, N)."""
        stretch_stiffness: wp.array2d(dtype=scalar)
        """EA / l0 per segment [N/m], shape (yarns, N)."""
        bend_stiffness: wp.array2d(dtype=scalar)
        """EI / lbar per node [N m], shape (yarns, N+1); 0 at the end nodes."""
        rest_angle: wp.array2d(dtype=scalar)
        """Rest turning angles phi0 [rad], shape (yarns, N+1)."""
        mass: wp.array2d(dtype=scalar)
        """Physical lumped masses rho_l lbar [kg], shape (yarns, N+1)."""
        crossing_node: wp.array(dtype=wp.int32)
        """Node n_j of each crossing [-], shape (C,), shared by all yarns."""
        crossing_side: wp.array2d(dtype=scalar)
        """Side s_j [-], shape (yarns, C); +1 above the weft."""
        gap_offset: wp.array2d(dtype=scalar)
        """c_j of g_j = c_j - s_j z_{n_j} [m], shape (yarns, C)."""
        contact_law: wp.array2d(dtype=scalar)
        """(k_s [N/m], C_wa [m], a_wa [1/N], C_we [m], a_we [1/N]), shape (yarns, 5); k_s the
        weft spring in series with the core stiffness (`dynfab.model`)."""
        friction_alpha: wp.array(dtype=scalar)
        """Gralen alpha [-], shape (yarns,)."""
        friction_constant: wp.array(dtype=scalar)
        """Gralen beta ell r_f [N], shape (yarns,)."""
        friction_onset: wp.array(dtype=scalar)
        """R_0 [N] of the limit's onset, shape (yarns,); 0: the literal jump law."""
        stick_stiffness: wp.array(dtype=scalar)
        """k_t [N/m], shape (yarns,)."""
        gravity: wp.array(dtype=scalar)
        """g [m/s^2], shape (yarns,)."""

    return YarnArrays


PER_YARN_FIELDS = ("rest_position", "rest_length", "stretch_stiffness", "bend_stiffness",
                   "rest_angle", "mass", "crossing_side", "gap_offset", "contact_law",
                   "friction_alpha", "friction_constant", "friction_onset", "stick_stiffness",
                   "gravity")
"""The fields with one row per yarn (crossing_node is shared by all yarns)."""


def upload(model, scalar, device: str):
    """The YarnArrays of a `dynfab.model.Model` on `device`, in precision `scalar`."""
    dtype = numpy_dtype(scalar)
    arrays = struct(scalar)()
    vec = VECTORS[scalar]
    arrays.rest_position = wp.array(model.stacked("rest_position").astype(dtype), dtype=vec,
                                    device=device)
    for field in PER_YARN_FIELDS[1:]:  # every per-yarn field but rest_position: scalars
        setattr(arrays, field, wp.array(model.stacked(field).astype(dtype), dtype=scalar,
                                        device=device))
    arrays.crossing_node = wp.array(np.asarray(model.yarns[0].crossing_node, np.int32),
                                    dtype=wp.int32, device=device)
    return arrays


def rows(array, first: int, stop: int):
    """Rows first..stop-1 of a Warp array, as a view of its memory. An array without elements
    (no crossings: shape (yarns, 0)) cannot be sliced by Warp and has no memory to share:
    an empty array of the rows' shape stands in."""
    if array.size == 0:
        return wp.empty((stop - first, *array.shape[1:]), dtype=array.dtype, device=array.device)
    return array[first:stop]


def view(arrays, first: int, stop: int):
    """The YarnArrays of yarns first..stop-1 of `arrays`, as views of its memory (no copy):
    row y of each view is row first + y of `arrays`, so a kernel launched on the view with
    dim = stop - first computes exactly what it computes for those yarns in a launch on
    `arrays` (thread y reads and writes only row y)."""
    part = struct(arrays.rest_length.dtype)()
    for field in PER_YARN_FIELDS:
        setattr(part, field, rows(getattr(arrays, field), first, stop))
    part.crossing_node = arrays.crossing_node
    return part
