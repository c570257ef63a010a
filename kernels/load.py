"""The traction load at the end node, in a kernel (MODEL.md section 2).

Warp twin of `dynfab.terms.load`: under force control the end node N feels +P
along x. Linear in the positions: no stiffness.
"""

import functools
from types import SimpleNamespace

import warp as wp

from dynfab.kernels.precision import VECTORS


@functools.cache
def functions(scalar) -> SimpleNamespace:
    """The load `wp.func`s for one scalar type."""
    vec = VECTORS[scalar]

    @wp.func
    def add_forces(y: int, end_load: scalar, force: wp.array2d(dtype=vec)):
        """force_{x_N} += P [N]."""
        last = force.shape[1] - 1
        force[y, last] = force[y, last] + vec(end_load, scalar(0.0))

    return SimpleNamespace(add_forces=add_forces)
