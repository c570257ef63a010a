"""The two-node crossing contact of the fabric (docs/model.md section 10, with section 3's law).

Crossing c joins warp node a and weft node b. Its closure (how far the two centrelines
have approached since the as-woven state) is

    g = sigma ((z0_a - z0_b) - (z_a - z_b)) = gap_offset - sigma (z_a - z_b),

and for g > 0 the contact force R >= 0 solves the series law of both Kawabata
compressions and the core stiffness k_c,

    R / k_c + C_wa (1 - exp(-a_wa R)) + C_we (1 - exp(-a_we R)) = g,

R = 0 for g <= 0 (unilateral; at g = 0 the tangent is the open side's 0, the softer
branch). The energy is the series springs' at the common force (section 3 with k_c in
place of k_we), dE/dg = R, d2E/dg2 = dR/dg <= k_c. It pushes the warp node by
+sigma R in z and the weft node by -sigma R.

`law` = (k_c, C_wa, a_wa, C_we, a_we) as in `dynfab.terms.contact` (with k_c for k_s),
whose scalar law this module reuses. k_c = inf is allowed: then Kawabata's law is a
hard wall at g = C_wa + C_we, and a closure at or beyond it is never evaluated: the
energy is +inf there (a line search rejects the step).
"""

import numba
import numpy as np

from dynfab.terms import contact as law_1d


@numba.njit(cache=True)
def wall(law):
    """The largest closure the law allows [m]: inf with a finite k_c, C_wa + C_we without."""
    if np.isfinite(law[0]):
        return np.inf
    return law[1] + law[3]


@numba.njit(cache=True)
def closure(pos, warp_node, weft_node, side, gap_offset, c):
    """g of crossing c [m]."""
    return gap_offset[c] - side[c] * (pos[warp_node[c], 1] - pos[weft_node[c], 1])


@numba.njit(cache=True)
def force(g, law):
    """R(g) [N]: 0 where open; +inf at or beyond the wall."""
    if not g > 0.0:
        return 0.0
    if not g < wall(law):
        return np.inf
    return law_1d.force_from_closure(g, law)


@numba.njit(cache=True)
def crossing_energy(g, law):
    """E(g) [J]: the series springs' energy at R(g); +inf at or beyond the wall."""
    if not g > 0.0:
        return 0.0
    if not g < wall(law):
        return np.inf
    return law_1d.energy_of_force(law_1d.force_from_closure(g, law), law)


@numba.njit(cache=True)
def crossing_tangent(g, R, law):
    """dR/dg [N/m] at closure g (force R): 0 where open (g <= 0), at most k_c."""
    if not g > 0.0:
        return 0.0
    return law_1d.tangent(R, law)


@numba.njit(cache=True)
def energy(pos, warp_node, weft_node, side, gap_offset, law):
    """sum_c E_c [J]."""
    total = 0.0
    for c in range(warp_node.size):
        total += crossing_energy(closure(pos, warp_node, weft_node, side, gap_offset, c), law)
    return total


@numba.njit(cache=True)
def forces(pos, warp_node, weft_node, side, gap_offset, law, out):
    """R_c [N] of every crossing into out (C,)."""
    for c in range(warp_node.size):
        out[c] = force(closure(pos, warp_node, weft_node, side, gap_offset, c), law)


@numba.njit(cache=True)
def add_gradient(pos, warp_node, weft_node, side, gap_offset, law, grad):
    """grad += dE/dz: R dg/dz_a = -sigma R on the warp node, +sigma R on the weft node."""
    for c in range(warp_node.size):
        R = force(closure(pos, warp_node, weft_node, side, gap_offset, c), law)
        grad[warp_node[c], 1] -= side[c] * R
        grad[weft_node[c], 1] += side[c] * R


@numba.njit(cache=True)
def tangents(pos, warp_node, weft_node, side, gap_offset, law, out):
    """dR/dg [N/m] of every crossing into out (C,): the Hessian block on (z_a, z_b) is
    dR/dg [[1, -1], [-1, 1]] (sigma^2 = 1)."""
    for c in range(warp_node.size):
        g = closure(pos, warp_node, weft_node, side, gap_offset, c)
        out[c] = crossing_tangent(g, force(g, law), law)
