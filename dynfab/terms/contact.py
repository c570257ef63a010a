"""Weft contact: the weft spring in series with both Kawabata laws (MODEL.md 3; eqs. 4-9).

At crossing j the closure is g_j = c_j - s_j z_{n_j} (c_j from the reference
state, `dynfab.model`). The contact force R_j >= 0 solves

    R / k_we + C_wa (1 - exp(-a_wa R)) + C_we (1 - exp(-a_we R)) = g_j   (g_j > 0),

R_j = 0 for g_j <= 0 (unilateral). The energy is the three series springs at
the common force, E = R^2 / (2 k_we) + sum_m (C_m / a_m)(1 - exp(-a_m R)(1 + a_m R)),
with dE/dg = R and d2E/dg2 = dR/dg = 1 / (1/k_we + sum_m C_m a_m exp(-a_m R)).

`law` is the array (k_we [N/m], C_wa [m], a_wa [1/N], C_we [m], a_we [1/N]).
"""

import numba
import numpy as np

from dynfab.banded import band_add

MAX_NEWTON = 100
"""Newton iterations allowed in `force_from_closure`; it needs fewer than 10 on the paper's data."""


@numba.njit(cache=True)
def closure_from_force(R, law):
    """g(R) [m]: the left side of the series law, increasing and concave in R."""
    return R / law[0] - law[1] * np.expm1(-law[2] * R) - law[3] * np.expm1(-law[4] * R)


@numba.njit(cache=True)
def tangent(R, law):
    """dR/dg [N/m] at force R on a closed contact; bounded by k_we."""
    return 1.0 / (1.0 / law[0] + law[1] * law[2] * np.exp(-law[2] * R)
                  + law[3] * law[4] * np.exp(-law[4] * R))


@numba.njit(cache=True)
def force_from_closure(g, law):
    """R(g) [N]: Newton on the series law from a lower bound of the root.

    g(R) <= R / k_we + C_wa + C_we gives R >= k_we (g - C_wa - C_we); Newton on an
    increasing concave function started left of the root stays left of it
    and increases monotonically, so it stops when a step no longer increases R.
    """
    if not g > 0.0:
        return 0.0
    R = max(0.0, law[0] * (g - law[1] - law[3]))
    for _ in range(MAX_NEWTON):
        step = (g - closure_from_force(R, law)) * tangent(R, law)
        if not step > 4e-16 * R:
            break
        R += step
    return R


@numba.njit(cache=True)
def _kawabata_energy(C, a, R):
    """(C / a)(1 - exp(-x)(1 + x)), x = a R [J]; series below x = 0.5 against cancellation.

    1 - e^-x (1 + x) = sum_{n>=2} (-1)^n (n - 1) x^n / n!.
    """
    x = a * R
    if x >= 0.5:
        return (C / a) * (1.0 - np.exp(-x) * (1.0 + x))
    term = x * x / 2.0
    total = 0.0
    n = 2
    while n < 40 and abs(term) * (n - 1) > 1e-18 * (x * x / 2.0) + 1e-300:
        total += (n - 1) * term
        n += 1
        term *= -x / n
    return (C / a) * total


@numba.njit(cache=True)
def energy_of_force(R, law):
    """E [J] stored in the series springs at the common force R."""
    return (R * R / (2.0 * law[0]) + _kawabata_energy(law[1], law[2], R)
            + _kawabata_energy(law[3], law[4], R))


@numba.njit(cache=True)
def closure(pos, node, side, offset):
    """g_j = c_j - s_j z_{n_j} [m]."""
    return offset - side * pos[node, 1]


@numba.njit(cache=True)
def forces(pos, nodes, sides, offsets, law, out):
    """Contact force R_j [N] of every crossing into out (C,)."""
    for j in range(nodes.size):
        out[j] = force_from_closure(closure(pos, nodes[j], sides[j], offsets[j]), law)


@numba.njit(cache=True)
def energy(pos, nodes, sides, offsets, law):
    """sum_j E_contact,j [J]."""
    total = 0.0
    for j in range(nodes.size):
        total += energy_of_force(force_from_closure(closure(pos, nodes[j], sides[j], offsets[j]), law), law)
    return total


@numba.njit(cache=True)
def add_gradient(pos, nodes, sides, offsets, law, grad):
    """grad_z += dE/dg dg/dz = -s_j R_j (the force on the warp is +s_j R_j)."""
    for j in range(nodes.size):
        R = force_from_closure(closure(pos, nodes[j], sides[j], offsets[j]), law)
        grad[nodes[j], 1] -= sides[j] * R


@numba.njit(cache=True)
def add_hessian(pos, nodes, sides, offsets, law, band):
    """band_zz += dR/dg on closed contacts (s_j^2 = 1); 0 on open ones."""
    for j in range(nodes.size):
        g = closure(pos, nodes[j], sides[j], offsets[j])
        if g > 0.0:
            dof = 2 * nodes[j] + 1
            band_add(band, dof, dof, tangent(force_from_closure(g, law), law))
