"""The Huber stick-slip law of a crossing's slip, in any slip dimension (docs/model.md
sections 4 (the paper yarn's 1-D slip along x), 10 (10.8: the planar fabric's 2-D slip) and
11.4 (the spatial fabric's three-component slip)): one statement of its branches and its
energy, which the three slips share (`dynfab.model.terms.friction`, `dynfab.model.fabric.friction`,
`dynfab.model.terms.spatial`).

The law depends on the slip S only through its size n = |S| [m], the friction limit F_T [N]
(frozen in a Newton solve) and the stick stiffness k_t [N/m]:

    H = 1/2 k_t n^2                  sticking, k_t n < F_T,
      = F_T n - F_T^2 / (2 k_t)      sliding,  k_t n >= F_T,
      = 0                            open,     F_T <= 0;

dH/dS = k_t S sticking, F_T S / n sliding, 0 open; d2H/dS2 = k_t I sticking,
(F_T / n)(I - S S^T / n^2) sliding (its secant blend: the dimension's own module), 0 open.
At k_t n = F_T the energy and force are continuous and the curvature takes the softer,
sliding branch (docs/model.md section 6: at a kink the softer branch). The return map moves
the anchor by m S, m = 1 - F_T / (k_t n), where k_t n > max(F_T, 0): an open crossing's
anchor follows its nodes (m = 1); at the boundary nothing moves.
"""

import numba


@numba.njit(cache=True)
def slides(size, limit, stick):
    """Whether a slip of size `size` [m] is on the sliding branch (or open, F_T <= 0): the
    branch of the energy's curvature (module docstring)."""
    return not limit > 0.0 or stick * size >= limit


@numba.njit(cache=True)
def energy(size, limit, stick):
    """H [J] of a slip of size `size` [m]; limit = F_T [N], stick = k_t [N/m]."""
    if not limit > 0.0:
        return 0.0
    if stick * size < limit:
        return 0.5 * stick * size * size
    return limit * size - limit * limit / (2.0 * stick)


@numba.njit(cache=True)
def moves(size, limit, stick):
    """Whether the return map moves the anchor of a slip of size `size` [m]: k_t |S| >
    max(F_T, 0) (module docstring)."""
    return stick * size > max(limit, 0.0)


@numba.njit(cache=True)
def force_per_slip(size, limit, stick):
    """g [N/m] with dH/dS = g S: k_t sticking, F_T / n sliding, 0 open (module docstring)."""
    if not limit > 0.0:
        return 0.0
    if stick * size < limit:
        return stick
    return limit / size
