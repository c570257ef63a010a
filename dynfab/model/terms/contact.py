"""Weft contact: the weft spring in series with both Kawabata laws (docs/model.md section 3; paper
eqs. 4-9).

At crossing j the closure is g_j = c_j - s_j z_{n_j} (c_j from the reference
state, `dynfab.model.yarn`). The contact force R_j >= 0 solves

    R / k_s + C_wa (1 - exp(-a_wa R)) + C_we (1 - exp(-a_we R)) = g_j   (g_j > 0),

R_j = 0 for g_j <= 0 (unilateral). The energy is the three series springs at
the common force, E = R^2 / (2 k_s) + sum_m (C_m / a_m)(1 - exp(-a_m R)(1 + a_m R)),
with dE/dg = R and d2E/dg2 = dR/dg = 1 / (1/k_s + sum_m C_m a_m exp(-a_m R)).

`law` is the array (k_s [N/m], C_wa [m], a_wa [1/N], C_we [m], a_we [1/N]); k_s is the
series spring: the weft spring k_we, in series with the yarns' core stiffness k_c when the
scene gives one (`contact.core_stiffness`, docs/model.md section 3): 1/k_s = 1/k_we + 1/k_c, so the
left side gains R/k_c and the energy R^2/(2 k_c) with no further term (`dynfab.model.yarn`).

Branches: the functions taking `branch` (None, or one of NATURAL, OPEN, CLOSED per
crossing) let the static solver hold a crossing open or closed during a Newton solve
(docs/model.md section 4, `dynfab.solvers.active_set`). OPEN: R = 0 and dR/dg = 0 at any g.
CLOSED: the unilateral law's force (R = 0 for g <= 0: no adhesion), but for g <= 0 the
tangent from the closed side, k_0 = 1/(1/k_s + C_wa a_wa + C_we a_we): the Newton
matrix of a crossing held closed keeps its contact stiffness across g = 0. NATURAL (and
None): the unilateral law. CLOSED gives the unilateral law's forces, OPEN too wherever
g <= 0: a state whose open crossings have g <= 0 satisfies the unilateral law. (A closed
branch continued as an adhesive spring, R = k_0 g for g < 0, was tried: its spurious
solutions with R < 0 made the set updates cycle on the paper's yarn, at load step 19.)
"""

import numba
import numpy as np

from dynfab.linalg.banded import band_add

MAX_NEWTON = 100
"""Newton iterations allowed in `force_from_closure`; it needs fewer than 10 on the paper's data."""


@numba.njit(cache=True)
def closure_from_force(R, law):
    """g(R) [m]: the left side of the series law, increasing and concave in R."""
    return R / law[0] - law[1] * np.expm1(-law[2] * R) - law[3] * np.expm1(-law[4] * R)


@numba.njit(cache=True)
def tangent(R, law):
    """dR/dg [N/m] at force R on a closed contact; bounded by k_s."""
    return 1.0 / (1.0 / law[0] + law[1] * law[2] * np.exp(-law[2] * R)
                  + law[3] * law[4] * np.exp(-law[4] * R))


@numba.njit(cache=True)
def force_from_closure(g, law):
    """R(g) [N]: Newton on the series law from a lower bound of the root.

    g(R) <= R / k_s + C_wa + C_we gives R >= k_s (g - C_wa - C_we); Newton on an
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
    """E [J] stored in the series springs at the common force R (R^2 / (2 k_s) + Kawabata)."""
    return (R * R / (2.0 * law[0]) + _kawabata_energy(law[1], law[2], R)
            + _kawabata_energy(law[3], law[4], R))


NATURAL, OPEN, CLOSED = -1, 0, 1
"""Branches of a crossing's contact law (module docstring)."""


@numba.njit(cache=True)
def branch_of(branch, j):
    """Crossing j's branch: NATURAL when `branch` is None."""
    if branch is None:
        return NATURAL
    return branch[j]


@numba.njit(cache=True)
def force_on_branch(g, law, branch):
    """R [N] at closure g on one branch (module docstring): 0 when OPEN."""
    if branch == OPEN:
        return 0.0
    return force_from_closure(g, law)


@numba.njit(cache=True)
def tangent_on_branch(g, R, law, branch):
    """dR/dg [N/m] at closure g (force R) on one branch."""
    if branch == OPEN:
        return 0.0
    if g > 0.0:
        return tangent(R, law)
    return tangent(0.0, law) if branch == CLOSED else 0.0


@numba.njit(cache=True)
def energy_on_branch(g, law, branch):
    """E_contact [J] at closure g on one branch."""
    if branch == OPEN:
        return 0.0
    return energy_of_force(force_from_closure(g, law), law)


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
def energy(pos, nodes, sides, offsets, law, branch=None):
    """sum_j E_contact,j [J] (each crossing on its branch; unilateral without `branch`)."""
    total = 0.0
    for j in range(nodes.size):
        total += energy_on_branch(closure(pos, nodes[j], sides[j], offsets[j]), law,
                                  branch_of(branch, j))
    return total


@numba.njit(cache=True)
def add_gradient(pos, nodes, sides, offsets, law, grad, branch=None):
    """grad_z += dE/dg dg/dz = -s_j R_j (the force on the warp is +s_j R_j)."""
    for j in range(nodes.size):
        R = force_on_branch(closure(pos, nodes[j], sides[j], offsets[j]), law, branch_of(branch, j))
        grad[nodes[j], 1] -= sides[j] * R


@numba.njit(cache=True)
def add_hessian(pos, nodes, sides, offsets, law, band, branch=None):
    """band_zz += dR/dg (s_j^2 = 1): 0 on open contacts."""
    for j in range(nodes.size):
        g = closure(pos, nodes[j], sides[j], offsets[j])
        on = branch_of(branch, j)
        stiffness = tangent_on_branch(g, force_on_branch(g, law, on), law, on)
        if stiffness > 0.0:
            dof = 2 * nodes[j] + 1
            band_add(band, dof, dof, stiffness)


# The term's entry points (`dynfab.model.terms`): each crossing on its branch `frozen.branch`.


@numba.njit(cache=True)
def yarn_energy(pos, yarn, frozen):
    """sum_j E_contact,j [J] of a `dynfab.model.yarn.Yarn`."""
    return energy(pos, yarn.crossing_node, yarn.crossing_side, yarn.gap_offset, yarn.contact_law,
                  frozen.branch)


@numba.njit(cache=True)
def add_yarn_gradient(pos, yarn, frozen, grad):
    """grad_z += -s_j R_j."""
    add_gradient(pos, yarn.crossing_node, yarn.crossing_side, yarn.gap_offset, yarn.contact_law,
                 grad, frozen.branch)


@numba.njit(cache=True)
def add_yarn_hessian(pos, yarn, frozen, band):
    """band_zz += dR/dg."""
    add_hessian(pos, yarn.crossing_node, yarn.crossing_side, yarn.gap_offset, yarn.contact_law,
                band, frozen.branch)
