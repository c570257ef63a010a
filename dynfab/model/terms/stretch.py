"""Extension springs, geometrically exact (docs/model.md section 2; paper C_e = EA / Delta).

E_stretch = sum_i 1/2 (EA / l0_i) (l_i - l0_i)^2,  l_i = |r_{i+1} - r_i|.
"""

import numba
import numpy as np

from dynfab.linalg.banded import band_add


@numba.njit(cache=True)
def energy(pos, rest_length, stiffness):
    """E_stretch [J]; `stiffness` = EA / l0_i per segment [N/m]."""
    total = 0.0
    for i in range(rest_length.size):
        ex, ez = pos[i + 1, 0] - pos[i, 0], pos[i + 1, 1] - pos[i, 1]
        stretch = np.sqrt(ex * ex + ez * ez) - rest_length[i]
        total += 0.5 * stiffness[i] * stretch * stretch
    return total


@numba.njit(cache=True)
def add_gradient(pos, rest_length, stiffness, grad):
    """grad += dE/dr: the spring force k (l - l0) e / l, with e = r_{i+1} - r_i."""
    for i in range(rest_length.size):
        ex, ez = pos[i + 1, 0] - pos[i, 0], pos[i + 1, 1] - pos[i, 1]
        length = np.sqrt(ex * ex + ez * ez)
        tension = stiffness[i] * (length - rest_length[i]) / length
        grad[i, 0] -= tension * ex
        grad[i, 1] -= tension * ez
        grad[i + 1, 0] += tension * ex
        grad[i + 1, 1] += tension * ez


@numba.njit(cache=True)
def add_hessian(pos, rest_length, stiffness, band):
    """band += d2E/dr2.

    Per segment, d2E/de2 = k [ e e^T / l^2 + (1 - l0 / l) (I - e e^T / l^2) ],
    entered with signs (+ on the diagonal node blocks, - off them).
    """
    for i in range(rest_length.size):
        ex, ez = pos[i + 1, 0] - pos[i, 0], pos[i + 1, 1] - pos[i, 1]
        l2 = ex * ex + ez * ez
        geometric = 1.0 - rest_length[i] / np.sqrt(l2)
        k = stiffness[i]
        hxx = k * (ex * ex / l2 + geometric * (1.0 - ex * ex / l2))
        hzz = k * (ez * ez / l2 + geometric * (1.0 - ez * ez / l2))
        hxz = k * (1.0 - geometric) * ex * ez / l2
        a, b = 2 * i, 2 * i + 2
        for p, q, sign in ((a, a, 1.0), (b, b, 1.0), (a, b, -1.0), (b, a, -1.0)):
            band_add(band, p, q, sign * hxx)
            band_add(band, p + 1, q + 1, sign * hzz)
            band_add(band, p, q + 1, sign * hxz)
            band_add(band, p + 1, q, sign * hxz)


# The term's entry points (`dynfab.model.terms`).


@numba.njit(cache=True)
def yarn_energy(pos, yarn, frozen):
    """E_stretch [J] of a `dynfab.model.yarn.Yarn`."""
    return energy(pos, yarn.rest_length, yarn.stretch_stiffness)


@numba.njit(cache=True)
def add_yarn_gradient(pos, yarn, frozen, grad):
    """grad += dE_stretch/dr."""
    add_gradient(pos, yarn.rest_length, yarn.stretch_stiffness, grad)


@numba.njit(cache=True)
def add_yarn_hessian(pos, yarn, frozen, band):
    """band += d2E_stretch/dr2."""
    add_hessian(pos, yarn.rest_length, yarn.stretch_stiffness, band)
