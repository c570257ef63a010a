"""The contact of a tie (docs/model.md sections 3 and 10): node a against node b, or against
ground.

Tie c joins node a to node b (`dynfab.model.structure`). Its closure (how far the two centrelines
have approached since the stress-free state) is

    g = gap_offset - sigma (z_a - z_b),      z_b = 0 for a tie to ground,

z the last coordinate (the planar fabric's second, the spatial one's third, docs/model.md
section 11),

and for g > 0 the contact force R >= 0 solves the tie's series law of both Kawabata
compressions and its series spring k_s (the core stiffness k_c of a fabric crossing; the
weft spring in series with it on the paper's yarn),

    R / k_s + C_a (1 - exp(-a_a R)) + C_b (1 - exp(-a_b R)) = g,

R = 0 for g <= 0 (unilateral; at g = 0 the tangent is the open side's 0, the softer
branch). The energy is the series springs' at the common force (section 3),
dE/dg = R, d2E/dg2 = dR/dg <= k_s. It pushes node a by +sigma R in z and node b by -sigma R.

The law of tie c is the row `tie_contact_law[c]` = (k_s, C_a, a_a, C_b, a_b), as in
`dynfab.model.terms.contact`, whose scalar law this module reuses. k_s = inf is allowed: then
Kawabata's law is a hard wall at g = C_a + C_b, and a closure at or beyond it is never
evaluated: the energy is +inf there (a line search rejects the step).
"""

import numba
import numpy as np

from dynfab.model.terms import contact as law_1d
from dynfab.model.terms import friction as gralen


@numba.njit(cache=True)
def wall(law):
    """The largest closure the law allows [m]: inf with a finite k_s, C_a + C_b without."""
    if np.isfinite(law[0]):
        return np.inf
    return law[1] + law[3]


@numba.njit(cache=True)
def closure(pos, s, c):
    """g of tie c [m]."""
    b, z = s.tie_b[c], pos.shape[1] - 1
    z_b = pos[b, z] if b >= 0 else 0.0
    return s.tie_gap_offset[c] - s.tie_side[c] * (pos[s.tie_a[c], z] - z_b)


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
    """dR/dg [N/m] at closure g (force R): 0 where open (g <= 0), at most k_s."""
    if not g > 0.0:
        return 0.0
    return law_1d.tangent(R, law)


@numba.njit(cache=True)
def energy(pos, s):
    """sum_c E_c [J]."""
    total = 0.0
    for c in range(s.tie_a.size):
        total += crossing_energy(closure(pos, s, c), s.tie_contact_law[c])
    return total


@numba.njit(cache=True)
def forces(pos, s, out):
    """R_c [N] of every tie into out (T,)."""
    for c in range(s.tie_a.size):
        out[c] = force(closure(pos, s, c), s.tie_contact_law[c])


@numba.njit(cache=True)
def add_gradient(pos, s, grad):
    """grad += dE/dz: R dg/dz_a = -sigma R on node a, +sigma R on node b."""
    z = pos.shape[1] - 1
    for c in range(s.tie_a.size):
        R = force(closure(pos, s, c), s.tie_contact_law[c])
        grad[s.tie_a[c], z] -= s.tie_side[c] * R
        if s.tie_b[c] >= 0:
            grad[s.tie_b[c], z] += s.tie_side[c] * R


@numba.njit(cache=True)
def tangents(pos, s, out):
    """dR/dg [N/m] of every tie into out (T,): the Hessian block on (z_a, z_b) is
    dR/dg [[1, -1], [-1, 1]] (sigma^2 = 1; on z_a alone for a tie to ground)."""
    for c in range(s.tie_a.size):
        g = closure(pos, s, c)
        law = s.tie_contact_law[c]
        out[c] = crossing_tangent(g, force(g, law), law)


def friction_limits(pos, s) -> np.ndarray:
    """F_T (T,) [N] of Gralen's law at the contact forces of `pos`, each tie its own law
    (docs/model.md section 4); 0 without friction."""
    out = np.zeros(s.tie_a.size)
    if s.has_friction:
        R = np.zeros(s.tie_a.size)
        forces(pos, s, R)
        gralen.tie_limits(R, s.tie_friction_law, -1.0, out)
    return out
