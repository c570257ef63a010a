"""Extension springs, geometrically exact, in a kernel (docs/model.md section 2; paper C_e = EA /
Delta).

Warp twin of `dynfab.terms.stretch`, in its sign convention (grad += dV/dr):
E_stretch = sum_i 1/2 (EA / l0_i) (l_i - l0_i)^2, l_i = |r_{i+1} - r_i|, with
`stiffness` = EA / l0_i (`YarnArrays.stretch_stiffness`) and `rest_length` = l0_i.
Every term module has the same three `wp.func`s with the same arguments
(`dynfab.kernels.forces`): energy, add_gradient and add_hessian.
"""

import functools
from types import SimpleNamespace

import warp as wp

from dynfab.kernels import banded, yarn_arrays
from dynfab.kernels.precision import VECTORS


@functools.cache
def functions(scalar) -> SimpleNamespace:
    """The stretch `wp.func`s for one scalar type."""
    vec = VECTORS[scalar]
    YarnArrays = yarn_arrays.struct(scalar)
    band_ops = banded.functions(scalar)

    @wp.func
    def energy(y: int, pos: wp.array2d(dtype=vec), yarn: YarnArrays,
               anchors: wp.array2d(dtype=scalar), P: scalar,
               contact_force: wp.array2d(dtype=scalar)) -> scalar:
        """E_stretch [J] = sum_i 1/2 k_i (l_i - l0_i)^2."""
        rest_length = yarn.rest_length
        stiffness = yarn.stretch_stiffness
        total = scalar(0.0)
        for i in range(rest_length.shape[1]):
            stretch = wp.length(pos[y, i + 1] - pos[y, i]) - rest_length[y, i]
            total += scalar(0.5) * stiffness[y, i] * stretch * stretch
        return total

    @wp.func(inline=True)
    def add_gradient(y: int, pos: wp.array2d(dtype=vec), yarn: YarnArrays,
                     anchors: wp.array2d(dtype=scalar), P: scalar,
                     contact_force: wp.array2d(dtype=scalar), contact_tangent: wp.array2d(dtype=scalar),
                     friction_limit: wp.array2d(dtype=scalar), grad: wp.array2d(dtype=vec)):
        """grad += dE/dr [N]: -k (l - l0) e / l on node i, + on node i+1, e = r_{i+1} - r_i."""
        rest_length = yarn.rest_length
        stiffness = yarn.stretch_stiffness
        for i in range(rest_length.shape[1]):
            e = pos[y, i + 1] - pos[y, i]
            length = wp.length(e)
            pull = (stiffness[y, i] * (length - rest_length[y, i]) / length) * e
            grad[y, i] = grad[y, i] - pull
            grad[y, i + 1] = grad[y, i + 1] + pull

    @wp.func(inline=True)
    def add_hessian(y: int, pos: wp.array2d(dtype=vec), yarn: YarnArrays,
                    anchors: wp.array2d(dtype=scalar), contact_tangent: wp.array2d(dtype=scalar),
                    friction_limit: wp.array2d(dtype=scalar), definite: bool, stiffest: bool,
                    band: wp.array3d(dtype=scalar)):
        """band += d2E/dr2 [N/m]: per segment k [e e^T/l^2 + (1 - l0/l)(I - e e^T/l^2)].

        With `definite`, a compressed segment's negative geometric part (1 - l0/l < 0)
        is dropped, leaving a positive semi-definite block (docs/model.md section 5, semi_implicit).
        """
        rest_length = yarn.rest_length
        stiffness = yarn.stretch_stiffness
        for i in range(rest_length.shape[1]):
            e = pos[y, i + 1] - pos[y, i]
            l2 = wp.dot(e, e)
            geometric = scalar(1.0) - rest_length[y, i] / wp.sqrt(l2)
            if definite:
                geometric = wp.max(geometric, scalar(0.0))
            axial = wp.outer(e, e) / l2
            block = stiffness[y, i] * (axial + geometric * (wp.identity(2, scalar) - axial))
            band_ops.add_block(band, y, i, i, block)
            band_ops.add_block(band, y, i + 1, i + 1, block)
            band_ops.add_block(band, y, i, i + 1, -block)
            band_ops.add_block(band, y, i + 1, i, -block)

    return SimpleNamespace(energy=energy, add_gradient=add_gradient, add_hessian=add_hessian)
