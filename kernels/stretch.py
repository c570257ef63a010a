"""Extension springs in a kernel (MODEL.md section 2; Warp twin of `dynfab.terms.stretch`).

E_stretch = sum_i 1/2 (EA / l0_i) (l_i - l0_i)^2,  l_i = |r_{i+1} - r_i|;
the force on node i+1 is -k (l - l0) e / l (e = r_{i+1} - r_i), its opposite on node i.
"""

import functools
from types import SimpleNamespace

import warp as wp

from dynfab.kernels import banded
from dynfab.kernels.precision import VECTORS


@functools.cache
def functions(scalar) -> SimpleNamespace:
    """The stretch `wp.func`s for one scalar type."""
    vec = VECTORS[scalar]
    band_ops = banded.functions(scalar)

    @wp.func
    def add_forces(y: int, pos: wp.array2d(dtype=vec), rest_length: wp.array2d(dtype=scalar),
                   stiffness: wp.array2d(dtype=scalar), force: wp.array2d(dtype=vec)):
        """force -= dE_stretch/dr [N]; `stiffness` = EA / l0_i [N/m]."""
        for i in range(rest_length.shape[1]):
            e = pos[y, i + 1] - pos[y, i]
            length = wp.length(e)
            pull = (stiffness[y, i] * (length - rest_length[y, i]) / length) * e
            force[y, i] = force[y, i] + pull
            force[y, i + 1] = force[y, i + 1] - pull

    @wp.func
    def add_band(y: int, pos: wp.array2d(dtype=vec), rest_length: wp.array2d(dtype=scalar),
                 stiffness: wp.array2d(dtype=scalar), definite: bool,
                 band: wp.array3d(dtype=scalar)):
        """band += d2E_stretch/dr2 [N/m]: per segment k [e e^T/l^2 + (1 - l0/l)(I - e e^T/l^2)].

        With `definite`, a compressed segment's negative geometric part (1 - l0/l < 0)
        is dropped, leaving a positive semi-definite block (MODEL.md 5, semi_implicit).
        """
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

    return SimpleNamespace(add_forces=add_forces, add_band=add_band)
