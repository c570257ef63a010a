"""The traction load at the end node, in a kernel (docs/model.md section 2).

Warp twin of `dynfab.terms.load`, in its sign convention (grad += dV/dr): under
force control E_load = -W_load = -P (x_N - x0_N), P [N] the end load. Linear in
the positions: no Hessian.
"""

import functools
from types import SimpleNamespace

import warp as wp

from dynfab.kernels import yarn_arrays
from dynfab.kernels.precision import VECTORS


@functools.cache
def functions(scalar) -> SimpleNamespace:
    """The load `wp.func`s for one scalar type."""
    vec = VECTORS[scalar]
    YarnArrays = yarn_arrays.struct(scalar)

    @wp.func
    def energy(y: int, pos: wp.array2d(dtype=vec), yarn: YarnArrays,
               anchors: wp.array2d(dtype=scalar), P: scalar,
               contact_force: wp.array2d(dtype=scalar)) -> scalar:
        """-P (x_N - x0_N) [J]."""
        last = pos.shape[1] - 1
        return -P * (pos[y, last][0] - yarn.rest_position[y, last][0])

    @wp.func(inline=True)
    def add_gradient(y: int, pos: wp.array2d(dtype=vec), yarn: YarnArrays,
                     anchors: wp.array2d(dtype=scalar), P: scalar,
                     contact_force: wp.array2d(dtype=scalar), contact_tangent: wp.array2d(dtype=scalar),
                     friction_limit: wp.array2d(dtype=scalar), grad: wp.array2d(dtype=vec)):
        """grad_{x_N} -= P [N]."""
        last = grad.shape[1] - 1
        grad[y, last] = grad[y, last] - vec(P, scalar(0.0))

    return SimpleNamespace(energy=energy, add_gradient=add_gradient)
