"""Isotropic Huber stick-slip friction at a tie (docs/model.md sections 4 and 10).

The slip of tie c (node a, node b; the planes X, Y of the chains they cross) is

    s = (x_a - X - xi_x, y_b - Y - xi_y),

xi the tie's anchor; a tie to ground has only the first component (its planes are 0 and
its anchor a position). With the limit F_T (Gralen's law of section 4 at the contact
force, frozen during a Newton solve) and the tie's stick stiffness k_t
(`tie_friction_law[c, 3]`), the incremental potential is the isotropic Huber

    H(s) = 1/2 k_t |s|^2                 for k_t |s| < F_T   (sticking)
         = F_T |s| - F_T^2 / (2 k_t)     otherwise            (sliding),

dH/ds = k_t s or F_T s / |s|, d2H/ds2 = k_t I or (F_T / |s|)(I - s s^T / |s|^2)
(the softer, sliding branch at k_t |s| = F_T, docs/model.md section 6). F_T = 0 (an open
tie) gives H = 0 identically. After a load step the anchors are return-mapped radially,
xi += (1 - F_T / (k_t |s|)) s where sliding, and the energy lost is F_T |delta xi|.
"""

import numba
import numpy as np

from dynfab.model.terms import huber as huber_law

STICK = 3
"""Column of k_t [N/m] in `tie_friction_law`."""


@numba.njit(cache=True)
def slip(pos, anchors, s, plane_x, plane_y, c):
    """s of tie c (2 floats) [m]; the second 0 for a tie to ground."""
    b = s.tie_b[c]
    second = pos[b, 0] - plane_y[c] - anchors[c, 1] if b >= 0 else 0.0
    return pos[s.tie_a[c], 0] - plane_x[c] - anchors[c, 0], second


@numba.njit(cache=True)
def is_sliding(sx, sy, limit, stick):
    """The sliding branch: k_t |s| >= F_T with F_T > 0, or F_T <= 0 (H = 0)
    (`dynfab.model.terms.huber.slides`)."""
    return huber_law.slides(np.hypot(sx, sy), limit, stick)


@numba.njit(cache=True)
def huber(sx, sy, limit, stick):
    """H(s) [J] (`dynfab.model.terms.huber.energy`)."""
    return huber_law.energy(np.hypot(sx, sy), limit, stick)


@numba.njit(cache=True)
def huber_gradient(sx, sy, limit, stick):
    """dH/ds (2 floats) [N]: minus the friction force on the slip."""
    g = huber_law.force_per_slip(np.hypot(sx, sy), limit, stick)
    return g * sx, g * sy


@numba.njit(cache=True)
def huber_hessian(sx, sy, limit, stick, secant=0.0):
    """d2H/ds2 as (h_xx, h_xy, h_yy) [N/m], a sliding tie's moved towards the secant by the
    weight `secant` in [0, 1] (True: 1).

    The secant, (F_T / |s|) I, is the curvature of the quadratic that touches H at s and
    lies above it everywhere (|s'| <= |s'|^2 / (2 |s|) + |s| / 2), so a Newton step on it
    cannot overshoot a tie about to stick again (the one-yarn solver's secant,
    `dynfab.model.terms.friction`); the sparse Newton blends towards it after shortened steps
    (`dynfab.solvers.newton_sparse`).
    """
    if not limit > 0.0:
        return 0.0, 0.0, 0.0
    n = np.hypot(sx, sy)
    if not huber_law.slides(n, limit, stick):
        return stick, 0.0, stick
    if secant >= 1.0:
        return limit / n, 0.0, limit / n
    scale = limit / (n * n * n)
    xx, xy, yy = scale * sy * sy, -scale * sx * sy, scale * sx * sx
    return xx + secant * (limit / n - xx), (1.0 - secant) * xy, yy + secant * (limit / n - yy)


@numba.njit(cache=True)
def energy(pos, anchors, s, plane_x, plane_y, limit):
    """sum_c H(s_c) [J], F_T frozen."""
    total = 0.0
    for c in range(s.tie_a.size):
        sx, sy = slip(pos, anchors, s, plane_x, plane_y, c)
        total += huber(sx, sy, limit[c], s.tie_friction_law[c, STICK])
    return total


@numba.njit(cache=True)
def hessians(pos, anchors, s, plane_x, plane_y, limit, out, secant=None):
    """(h_xx, h_xy, h_yy) of every tie into out (T, 3): the block on (x_a, y_b); `secant`
    (T,): each tie's weight of its secant (`huber_hessian`), None: 0 (the exact Hessian)."""
    for c in range(s.tie_a.size):
        sx, sy = slip(pos, anchors, s, plane_x, plane_y, c)
        weight = 0.0
        if secant is not None:
            weight = secant[c]
        out[c, 0], out[c, 1], out[c, 2] = huber_hessian(sx, sy, limit[c],
                                                        s.tie_friction_law[c, STICK], weight)


@numba.njit(cache=True)
def slips(pos, anchors, s, plane_x, plane_y, out):
    """Every tie's slip (s_x, s_y, 0) [m] into out (T, 3) (`slip`)."""
    for c in range(s.tie_a.size):
        out[c, 0], out[c, 1] = slip(pos, anchors, s, plane_x, plane_y, c)
        out[c, 2] = 0.0


@numba.njit(cache=True)
def return_map(pos, anchors, s, plane_x, plane_y, limit, sliding, friction_force):
    """Radial return of the sliding anchors, in place; returns the energy lost [J].

    Where k_t |s| > F_T: xi += (1 - F_T / (k_t |s|)) s, so that k_t |s| = F_T after it,
    dissipation F_T |delta xi|. Fills `sliding` (T,) and the friction force on the slip
    (T, 2) [N]: -k_t s sticking, -F_T s / |s| sliding.
    """
    lost = 0.0
    for c in range(s.tie_a.size):
        sx, sy = slip(pos, anchors, s, plane_x, plane_y, c)
        stick = s.tie_friction_law[c, STICK]
        n = np.hypot(sx, sy)
        F = limit[c]
        sliding[c] = huber_law.moves(n, F, stick)
        if sliding[c]:
            move = 1.0 - F / (stick * n)
            anchors[c, 0] += move * sx
            anchors[c, 1] += move * sy
            lost += F * move * n
            friction_force[c, 0], friction_force[c, 1] = -F * sx / n, -F * sy / n
        else:
            friction_force[c, 0], friction_force[c, 1] = -stick * sx, -stick * sy
    return lost
