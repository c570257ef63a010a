"""The traction load at the end node (docs/model.md section 2).

Force control: E_load = -W_load = -P (x_N - x0_N).  Displacement control
prescribes x_N = x0_N + u instead; the reaction P = dV/dx_N is reported.
Linear in the positions: no Hessian.
"""

import numba


@numba.njit(cache=True)
def energy(pos, rest_pos, P):
    """-P (x_N - x0_N) [J]."""
    return -P * (pos[-1, 0] - rest_pos[-1, 0])


@numba.njit(cache=True)
def add_gradient(P, grad):
    """grad_{x_N} -= P."""
    grad[grad.shape[0] - 1, 0] -= P


# The term's entry points (`dynfab.model.terms`): P = `frozen.load`.


@numba.njit(cache=True)
def yarn_energy(pos, yarn, frozen):
    """-P (x_N - x0_N) [J] of a `dynfab.model.yarn.Yarn`."""
    return energy(pos, yarn.rest_position, frozen.load)


@numba.njit(cache=True)
def add_yarn_gradient(pos, yarn, frozen, grad):
    """grad_{x_N} -= P."""
    add_gradient(frozen.load, grad)


@numba.njit(cache=True)
def add_yarn_hessian(pos, yarn, frozen, band):
    """Linear in the positions: nothing."""
