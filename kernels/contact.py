"""Weft contact in a kernel: the weft spring in series with both Kawabata laws
(docs/model.md section 3; paper eqs. 4-9).

Warp twin of `dynfab.terms.contact`, in its sign convention (grad += dV/dr). At crossing j the closure is
g_j = c_j - s_j z_{n_j}; the contact force R_j >= 0 solves

    R / k_we + C_wa (1 - exp(-a_wa R)) + C_we (1 - exp(-a_we R)) = g_j   (g_j > 0),

R_j = 0 for g_j <= 0, by the same monotone Newton iteration as
`dynfab.terms.contact.force_from_closure`. The force on the warp is +s_j R_j in z;
the tangent dR/dg = 1 / (1/k_we + sum_m C_m a_m exp(-a_m R)) is bounded by k_we.
The energy is the three series springs at the common force,
E = R^2 / (2 k_we) + sum_m (C_m / a_m)(1 - exp(-a_m R)(1 + a_m R)), so dE/dg = R.
`law` rows are (k_we [N/m], C_wa [m], a_wa [1/N], C_we [m], a_we [1/N])
(`YarnArrays.contact_law`); `nodes`, `sides`, `offsets` are n_j, s_j and c_j.
"""

import functools
from types import SimpleNamespace

import warp as wp

from dynfab.kernels import banded, yarn_arrays
from dynfab.kernels.precision import VECTORS, epsilon
from dynfab.terms.contact import MAX_NEWTON

NEWTON_STOP_EPS = 4e-16 / 2.220446049250313e-16
"""`force_from_closure` stops when a Newton step is below this many epsilons of R
(4e-16 R in float64, as `dynfab.terms.contact`)."""


@functools.cache
def functions(scalar) -> SimpleNamespace:
    """The contact `wp.func`s for one scalar type."""
    vec = VECTORS[scalar]
    YarnArrays = yarn_arrays.struct(scalar)
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
    def kawabata_energy(C: scalar, a: scalar, R: scalar) -> scalar:
        """(C / a)(1 - exp(-x)(1 + x)), x = a R [J]; below x = 0.5 the series
        sum_{n>=2} (-1)^n (n - 1) x^n / n! against cancellation (as `dynfab.terms.contact`)."""
        x = a * R
        result = scalar(0.0)
        if x >= scalar(0.5):
            result = (C / a) * (scalar(1.0) - wp.exp(-x) * (scalar(1.0) + x))
        else:
            term = x * x / scalar(2.0)
            floor = scalar(1.0e-18) * term + scalar(1.0e-300)
            total = scalar(0.0)
            n = int(2)
            while n < 40 and wp.abs(term) * scalar(n - 1) > floor:
                total += scalar(n - 1) * term
                n += 1
                term *= -x / scalar(n)
            result = (C / a) * total
        return result

    @wp.func
    def energy_of_force(R: scalar, law: wp.array2d(dtype=scalar), y: int) -> scalar:
        """E [J] stored in the series springs at the common force R."""
        return (R * R / (scalar(2.0) * law[y, 0]) + kawabata_energy(law[y, 1], law[y, 2], R)
                + kawabata_energy(law[y, 3], law[y, 4], R))

    @wp.func
    def energy(y: int, pos: wp.array2d(dtype=vec), yarn: YarnArrays,
               anchors: wp.array2d(dtype=scalar), P: scalar,
               contact_force: wp.array2d(dtype=scalar)) -> scalar:
        """sum_j E_contact,j [J] at R_j(g_j) solved here (0 where open)."""
        nodes = yarn.crossing_node
        law = yarn.contact_law
        total = scalar(0.0)
        for j in range(nodes.shape[0]):
            g = closure(pos, y, nodes[j], yarn.crossing_side[y, j], yarn.gap_offset[y, j])
            total += energy_of_force(force_from_closure(g, law, y)[0], law, y)
        return total

    @wp.func(inline=True)
    def add_gradient(y: int, pos: wp.array2d(dtype=vec), yarn: YarnArrays,
                     anchors: wp.array2d(dtype=scalar), P: scalar,
                     contact_force: wp.array2d(dtype=scalar), contact_tangent: wp.array2d(dtype=scalar),
                     friction_limit: wp.array2d(dtype=scalar), grad: wp.array2d(dtype=vec)):
        """grad_z += dE/dg dg/dz = -s_j R_j [N]; stores R_j [N] and dR/dg [N/m] (0 where open)
        per crossing in contact_force and contact_tangent."""
        nodes = yarn.crossing_node
        sides = yarn.crossing_side
        offsets = yarn.gap_offset
        law = yarn.contact_law
        for j in range(nodes.shape[0]):
            node = nodes[j]
            state = force_from_closure(closure(pos, y, node, sides[y, j], offsets[y, j]), law, y)
            R = state[0]
            contact_force[y, j] = R
            contact_tangent[y, j] = state[1]
            grad[y, node] = grad[y, node] - vec(scalar(0.0), sides[y, j] * R)

    @wp.func(inline=True)
    def add_hessian(y: int, pos: wp.array2d(dtype=vec), yarn: YarnArrays,
                    anchors: wp.array2d(dtype=scalar), contact_tangent: wp.array2d(dtype=scalar),
                    friction_limit: wp.array2d(dtype=scalar), definite: bool, stiffest: bool,
                    band: wp.array3d(dtype=scalar)):
        """band_zz += dR/dg [N/m] (s_j^2 = 1), from contact_tangent of the same evaluation;
        with `stiffest`, its bound k_we on every crossing."""
        nodes = yarn.crossing_node
        for j in range(nodes.shape[0]):
            dof = 2 * nodes[j] + 1
            stiffness = contact_tangent[y, j]
            if stiffest:
                stiffness = yarn.contact_law[y, 0]
            band_ops.add(band, y, dof, dof, stiffness)

    return SimpleNamespace(expm1=expm1, energy=energy, add_gradient=add_gradient,
                           add_hessian=add_hessian)
