"""Gralen friction as stick-slip in the incremental Huber form, in a kernel
(docs/model.md section 4; paper eqs. 20-27).

Warp twin of `dynfab.terms.friction`, in its sign convention (grad += dV/dr). F_T,j = alpha R_j + beta ell r_f (1 - exp(-R_j/R_0))
if R_j > 0, else 0 (eq. 20 with its onset regularised over R_0; R_0 = 0 is the literal
law), from the contact force R_j in `contact_force` (written by the contact term earlier in
the same evaluation: the registry's order). With the anchor xi_j fixed, each crossing adds
the Huber potential of its slip s = x_{n_j} - xi_j,

    H(s) = 1/2 k_t s^2 (k_t |s| <= F_T, sticking),   F_T |s| - F_T^2 / (2 k_t) (sliding),

so dH/ds = k_t s while sticking, F_T sign(s) while sliding. `stick_stiffness` = k_t.
"""

import functools
from types import SimpleNamespace

import warp as wp

from dynfab.kernels import banded, contact, yarn_arrays
from dynfab.kernels.precision import VECTORS


@functools.cache
def functions(scalar) -> SimpleNamespace:
    """The friction `wp.func`s for one scalar type."""
    vec = VECTORS[scalar]
    YarnArrays = yarn_arrays.struct(scalar)
    band_ops = banded.functions(scalar)
    expm1 = contact.functions(scalar).expm1

    @wp.func
    def limit(R: scalar, alpha: scalar, constant: scalar, onset: scalar) -> scalar:
        """F_T [N] from Gralen's law; `constant` = beta ell r_f [N], `onset` = R_0 [N] (0: literal).

        1 - exp(-R/R_0) as -expm1(-R/R_0), accurate to a few ulps also for R << R_0.
        """
        value = scalar(0.0)
        if R > scalar(0.0):
            onset_factor = scalar(1.0)
            if onset > scalar(0.0):
                x = -R / onset
                onset_factor = -expm1(x, wp.exp(x))
            value = alpha * R + constant * onset_factor
        return value

    @wp.func
    def is_sliding(slip: scalar, friction_limit: scalar, stick_stiffness: scalar) -> bool:
        """True where the trial force k_t |s| exceeds F_T."""
        return stick_stiffness * wp.abs(slip) > friction_limit

    @wp.func
    def huber_derivative(slip: scalar, friction_limit: scalar, stick_stiffness: scalar) -> scalar:
        """dH/ds [N]: minus the friction force on the warp."""
        value = stick_stiffness * slip
        if is_sliding(slip, friction_limit, stick_stiffness):
            value = friction_limit * wp.sign(slip)
        return value

    @wp.func
    def huber(slip: scalar, friction_limit: scalar, stick_stiffness: scalar) -> scalar:
        """H(s) [J]."""
        value = scalar(0.5) * stick_stiffness * slip * slip
        if is_sliding(slip, friction_limit, stick_stiffness):
            value = friction_limit * wp.abs(slip) \
                - friction_limit * friction_limit / (scalar(2.0) * stick_stiffness)
        return value

    @wp.func
    def crossing_limit(y: int, yarn: YarnArrays, contact_force: wp.array2d(dtype=scalar),
                       j: int) -> scalar:
        """F_T,j [N] from R_j [N]."""
        return limit(contact_force[y, j], yarn.friction_alpha[y], yarn.friction_constant[y],
                     yarn.friction_onset[y])

    @wp.func
    def energy(y: int, pos: wp.array2d(dtype=vec), yarn: YarnArrays,
               anchors: wp.array2d(dtype=scalar), P: scalar,
               contact_force: wp.array2d(dtype=scalar)) -> scalar:
        """sum_j H(x_{n_j} - xi_j) [J] with F_T,j from the given R_j (frozen)."""
        nodes = yarn.crossing_node
        total = scalar(0.0)
        for j in range(nodes.shape[0]):
            total += huber(pos[y, nodes[j]][0] - anchors[y, j], crossing_limit(y, yarn, contact_force, j),
                           yarn.stick_stiffness[y])
        return total

    @wp.func(inline=True)
    def add_gradient(y: int, pos: wp.array2d(dtype=vec), yarn: YarnArrays,
                     anchors: wp.array2d(dtype=scalar), P: scalar,
                     contact_force: wp.array2d(dtype=scalar), contact_tangent: wp.array2d(dtype=scalar),
                     friction_limit: wp.array2d(dtype=scalar), grad: wp.array2d(dtype=vec)):
        """grad_x += dH/ds [N] with F_T from the current R_j; stores F_T,j [N] in friction_limit."""
        nodes = yarn.crossing_node
        stick_stiffness = yarn.stick_stiffness[y]
        for j in range(nodes.shape[0]):
            node = nodes[j]
            limit_j = crossing_limit(y, yarn, contact_force, j)
            friction_limit[y, j] = limit_j
            slip = pos[y, node][0] - anchors[y, j]
            grad[y, node] = grad[y, node] + vec(huber_derivative(slip, limit_j, stick_stiffness),
                                                scalar(0.0))

    @wp.func(inline=True)
    def add_hessian(y: int, pos: wp.array2d(dtype=vec), yarn: YarnArrays,
                    anchors: wp.array2d(dtype=scalar), contact_tangent: wp.array2d(dtype=scalar),
                    friction_limit: wp.array2d(dtype=scalar), definite: bool, stiffest: bool,
                    band: wp.array3d(dtype=scalar)):
        """band_xx += k_t [N/m] on sticking crossings (F_T frozen, from friction_limit);
        with `stiffest`, on every one."""
        nodes = yarn.crossing_node
        stick_stiffness = yarn.stick_stiffness[y]
        for j in range(nodes.shape[0]):
            node = nodes[j]
            slip = pos[y, node][0] - anchors[y, j]
            if stiffest or not is_sliding(slip, friction_limit[y, j], stick_stiffness):
                band_ops.add(band, y, 2 * node, 2 * node, stick_stiffness)

    @wp.func
    def return_map(y: int, pos: wp.array2d(dtype=vec), nodes: wp.array(dtype=wp.int32),
                   anchors: wp.array2d(dtype=scalar), friction_limit: wp.array2d(dtype=scalar),
                   stick_stiffness: wp.array(dtype=scalar)) -> scalar:
        """Move the anchors of sliding crossings onto the slip surface; the energy lost [J].

        xi = x - sign(x - xi) F_T / k_t where k_t |x - xi| > F_T, dissipating F_T |delta xi|
        (docs/model.md section 4). The friction force -dH/ds of the anchors before equals -k_t (x -
        xi) after.
        """
        lost = scalar(0.0)
        for j in range(nodes.shape[0]):
            x = pos[y, nodes[j]][0]
            slip = x - anchors[y, j]
            if is_sliding(slip, friction_limit[y, j], stick_stiffness[y]):
                moved = x - wp.sign(slip) * friction_limit[y, j] / stick_stiffness[y]
                lost += friction_limit[y, j] * wp.abs(moved - anchors[y, j])
                anchors[y, j] = moved
        return lost

    return SimpleNamespace(limit=limit, energy=energy, add_gradient=add_gradient,
                           add_hessian=add_hessian, return_map=return_map)
