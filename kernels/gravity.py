"""Gravity along -z on the physical masses, in a kernel (docs/model.md section 2).

Warp twin of `dynfab.terms.gravity`, in its sign convention (grad += dV/dr):
E_gravity = -W_gravity = sum_i m_i g (z_i - z0_i), always with the physical masses
m_i = rho_l lbar_i (also under fictitious masses); `mass` = m_i, `g` = g.
Linear in the positions: no Hessian.
"""

import functools
from types import SimpleNamespace

import warp as wp

from dynfab.kernels import yarn_arrays
from dynfab.kernels.precision import VECTORS


@functools.cache
def functions(scalar) -> SimpleNamespace:
    """The gravity `wp.func`s for one scalar type."""
    vec = VECTORS[scalar]
    YarnArrays = yarn_arrays.struct(scalar)

    @wp.func
    def energy(y: int, pos: wp.array2d(dtype=vec), yarn: YarnArrays,
               anchors: wp.array2d(dtype=scalar), P: scalar,
               contact_force: wp.array2d(dtype=scalar)) -> scalar:
        """sum_i m_i g (z_i - z0_i) [J]."""
        mass = yarn.mass
        total = scalar(0.0)
        for i in range(mass.shape[1]):
            total += mass[y, i] * yarn.gravity[y] * (pos[y, i][1] - yarn.rest_position[y, i][1])
        return total

    @wp.func(inline=True)
    def add_gradient(y: int, pos: wp.array2d(dtype=vec), yarn: YarnArrays,
                     anchors: wp.array2d(dtype=scalar), P: scalar,
                     contact_force: wp.array2d(dtype=scalar), contact_tangent: wp.array2d(dtype=scalar),
                     friction_limit: wp.array2d(dtype=scalar), grad: wp.array2d(dtype=vec)):
        """grad_z += m_i g [N] (the weight -m_i g on each node)."""
        mass = yarn.mass
        g = yarn.gravity[y]
        for i in range(mass.shape[1]):
            grad[y, i] = grad[y, i] + vec(scalar(0.0), mass[y, i] * g)

    return SimpleNamespace(energy=energy, add_gradient=add_gradient)
