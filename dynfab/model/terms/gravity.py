"""Gravity along -z on the physical masses (docs/model.md section 2).

E_gravity = -W_gravity = sum_i m_i g (z_i - z0_i),  m_i = rho_l lbar_i.
Linear in the positions: no Hessian.
"""

import numba


@numba.njit(cache=True)
def energy(pos, rest_pos, mass, g):
    """sum_i m_i g (z_i - z0_i) [J]."""
    total = 0.0
    for i in range(mass.size):
        total += mass[i] * g * (pos[i, 1] - rest_pos[i, 1])
    return total


@numba.njit(cache=True)
def add_gradient(mass, g, grad):
    """grad_z += m_i g (the weight -m_i g on each node)."""
    for i in range(mass.size):
        grad[i, 1] += mass[i] * g


@numba.njit(cache=True)
def energy_per_node(pos, rest_pos, mass, g):
    """sum_i m_i g_i (z_i - z0_i) [J], g per node (a structure's `gravity`)."""
    total = 0.0
    for i in range(mass.size):
        if g[i] != 0.0:
            total += mass[i] * g[i] * (pos[i, 1] - rest_pos[i, 1])
    return total


@numba.njit(cache=True)
def add_gradient_per_node(mass, g, grad):
    """grad_z += m_i g_i."""
    for i in range(mass.size):
        if g[i] != 0.0:
            grad[i, 1] += mass[i] * g[i]


# The term's entry points (`dynfab.model.terms`).


@numba.njit(cache=True)
def yarn_energy(pos, yarn, frozen):
    """E_gravity [J] of a `dynfab.model.yarn.Yarn`."""
    return energy(pos, yarn.rest_position, yarn.mass, yarn.gravity)


@numba.njit(cache=True)
def add_yarn_gradient(pos, yarn, frozen, grad):
    """grad_z += m_i g."""
    add_gradient(yarn.mass, yarn.gravity, grad)


@numba.njit(cache=True)
def add_yarn_hessian(pos, yarn, frozen, band):
    """Linear in the positions: nothing."""
