"""Weft contact in a kernel: the weft spring in series with both Kawabata laws (MODEL.md 3; eqs. 4-9).

Warp twin of `dynfab.terms.contact`. At crossing j the closure is
g_j = c_j - s_j z_{n_j}; the contact force R_j >= 0 solves

    R / k_we + C_wa (1 - exp(-a_wa R)) + C_we (1 - exp(-a_we R)) = g_j   (g_j > 0),

R_j = 0 for g_j <= 0, by the same monotone Newton iteration as
`dynfab.terms.contact.force_from_closure`. The force on the warp is +s_j R_j in z;
the tangent dR/dg = 1 / (1/k_we + sum_m C_m a_m exp(-a_m R)) is bounded by k_we.
`law` rows are (k_we [N/m], C_wa [m], a_wa [1/N], C_we [m], a_we [1/N]).
"""

import functools
from types import SimpleNamespace

import warp as wp

from dynfab.kernels import banded
from dynfab.kernels.precision import VECTORS, epsilon
from dynfab.terms.contact import MAX_NEWTON

NEWTON_STOP_EPS = 4e-16 / 2.220446049250313e-16
"""`force_from_closure` stops when a Newton step is below this many epsilons of R
(4e-16 R in float64, as `dynfab.terms.contact`)."""


@functools.cache
def functions(scalar) -> SimpleNamespace:
    """The contact `wp.func`s for one scalar type."""
    vec = VECTORS[scalar]
    band_ops = banded.functions(scalar)
    newton_stop = NEWTON_STOP_EPS * epsilon(scalar)

    @wp.func
    def expm1(x: scalar, u: scalar) -> scalar:
        """exp(x) - 1 to a few ulps near 0, from u = exp(x) (Kahan: (u - 1) x / log u)."""
        result = x
        if u != scalar(1.0):
            result = (u - scalar(1.0)) * x / wp.log(u)
            if u - scalar(1.0) == scalar(-1.0):
                result = scalar(-1.0)
        return result

    @wp.func
    def series_law(R: scalar, law: wp.array2d(dtype=scalar), y: int) -> vec:
        """(g(R) [m], dR/dg [N/m]) at force R, sharing the two exponentials.

        g(R) = R / k_we - C_wa expm1(-a_wa R) - C_we expm1(-a_we R), increasing and concave;
        dR/dg = 1 / (1/k_we + C_wa a_wa exp(-a_wa R) + C_we a_we exp(-a_we R)).
        """
        decay_warp = wp.exp(-law[y, 2] * R)
        decay_weft = wp.exp(-law[y, 4] * R)
        g = R / law[y, 0] - law[y, 1] * expm1(-law[y, 2] * R, decay_warp) \
            - law[y, 3] * expm1(-law[y, 4] * R, decay_weft)
        tangent = scalar(1.0) / (scalar(1.0) / law[y, 0] + law[y, 1] * law[y, 2] * decay_warp
                                 + law[y, 3] * law[y, 4] * decay_weft)
        return vec(g, tangent)

    @wp.func
    def force_from_closure(g: scalar, law: wp.array2d(dtype=scalar), y: int) -> vec:
        """(R(g) [N], dR/dg [N/m] at R); (0, 0) where open (g <= 0).

        Newton from the lower bound k_we (g - C_wa - C_we) increases monotonically and
        stops when a step no longer increases R; the last tangent is the one at R.
        """
        R = scalar(0.0)
        tangent = scalar(0.0)
        if g > scalar(0.0):
            R = wp.max(scalar(0.0), law[y, 0] * (g - law[y, 1] - law[y, 3]))
            for _ in range(MAX_NEWTON):
                law_at_R = series_law(R, law, y)
                tangent = law_at_R[1]
                step = (g - law_at_R[0]) * tangent
                if not step > scalar(newton_stop) * R:
                    break
                R += step
        return vec(R, tangent)

    @wp.func
    def closure(pos: wp.array2d(dtype=vec), y: int, node: int, side: scalar, offset: scalar) -> scalar:
        """g_j = c_j - s_j z_{n_j} [m]."""
        return offset - side * pos[y, node][1]

    @wp.func
    def add_forces(y: int, pos: wp.array2d(dtype=vec), nodes: wp.array(dtype=wp.int32),
                   sides: wp.array2d(dtype=scalar), offsets: wp.array2d(dtype=scalar),
                   law: wp.array2d(dtype=scalar), contact_force: wp.array2d(dtype=scalar),
                   contact_tangent: wp.array2d(dtype=scalar), force: wp.array2d(dtype=vec)):
        """force_z += s_j R_j [N]; stores R_j [N] and dR/dg [N/m] (0 where open) per crossing."""
        for j in range(nodes.shape[0]):
            node = nodes[j]
            state = force_from_closure(closure(pos, y, node, sides[y, j], offsets[y, j]), law, y)
            R = state[0]
            contact_force[y, j] = R
            contact_tangent[y, j] = state[1]
            force[y, node] = force[y, node] + vec(scalar(0.0), sides[y, j] * R)

    @wp.func
    def add_band(y: int, nodes: wp.array(dtype=wp.int32), law: wp.array2d(dtype=scalar),
                 contact_tangent: wp.array2d(dtype=scalar), stiffest: bool,
                 band: wp.array3d(dtype=scalar)):
        """band_zz += dR/dg [N/m] (s_j^2 = 1); with `stiffest`, its bound k_we on every crossing."""
        for j in range(nodes.shape[0]):
            dof = 2 * nodes[j] + 1
            stiffness = contact_tangent[y, j]
            if stiffest:
                stiffness = law[y, 0]
            band_ops.add(band, y, dof, dof, stiffness)

    return SimpleNamespace(expm1=expm1, add_forces=add_forces, add_band=add_band)
