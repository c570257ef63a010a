"""Scalar types of the Warp kernels (docs/model.md section 5: float64 default, float32 on
request)."""

import numpy as np
import warp as wp

SCALARS = {"float64": wp.float64, "float32": wp.float32}
"""Precision name -> Warp scalar type."""

VECTORS = {(wp.float64, 2): wp.vec2d, (wp.float32, 2): wp.vec2f,
           (wp.float64, 3): wp.types.vector(3, wp.float64),
           (wp.float32, 3): wp.types.vector(3, wp.float32)}
"""(Warp scalar type, coordinates per node) -> the node's vector type: (x, z) planar, (x, y, z)
spatial."""

KINEMATICS = {"planar": 2, "spatial": 3, "planar_sliding": 2, "spatial_sliding": 3}
"""A kernel variant's kinematics -> coordinates per node: "planar" (x along the chain, z; each
chain in its own plane, docs/model.md sections 2-10), "spatial" (x, y, z, docs/model.md
section 11), or either with its crossings sliding along the yarns (docs/model.md 11.13)."""
KINEMATICS_OF_DIM = {2: "planar", 3: "spatial"}
"""Coordinates per node -> the kinematics' name (of crossings that do not slide)."""


def vector(scalar, dim: int = 2):
    """The Warp vector type of a node's `dim` coordinates in precision `scalar`."""
    return VECTORS[scalar, dim]

DEFAULT_TOLERANCE = {"float64": 1e-8, "float32": 1e-4}
"""Default force residual [N] per precision (docs/model.md section 5: float32's rounding floor is
about 1e-4 N)."""


def numpy_dtype(scalar) -> type:
    """The numpy dtype of a Warp scalar type."""
    return np.float64 if scalar is wp.float64 else np.float32


def epsilon(scalar) -> float:
    """Machine epsilon of a Warp scalar type."""
    return float(np.finfo(numpy_dtype(scalar)).eps)
