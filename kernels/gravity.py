"""Gravity along -z on the physical masses, in a kernel (MODEL.md section 2).

Warp twin of `dynfab.terms.gravity`: the weight -m_i g on every node, always
with the physical masses m_i = rho_l lbar_i (also under fictitious masses).
Linear in the positions: no stiffness.
"""

import functools
from types import SimpleNamespace

import warp as wp

from dynfab.kernels.precision import VECTORS


@functools.cache
def functions(scalar) -> SimpleNamespace:
    """The gravity `wp.func`s for one scalar type."""
    vec = VECTORS[scalar]

    @wp.func
    def add_forces(y: int, mass: wp.array2d(dtype=scalar), g: wp.array(dtype=scalar),
                   force: wp.array2d(dtype=vec)):
        """force_z -= m_i g [N]."""
        for i in range(mass.shape[1]):
            force[y, i] = force[y, i] - vec(scalar(0.0), mass[y, i] * g[y])

    return SimpleNamespace(add_forces=add_forces)
