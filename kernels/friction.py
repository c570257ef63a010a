"""Gralen friction as stick-slip in the incremental Huber form, in a kernel (MODEL.md 4; eqs. 20-27).

Warp twin of `dynfab.terms.friction`. F_T,j = alpha R_j + beta ell r_f (1 - exp(-R_j/R_0))
if R_j > 0, else 0 (eq. 20 with its onset regularised over R_0; R_0 = 0 is the literal
law), from the contact force of the same evaluation. With the anchor
xi_j fixed, the slip s = x_{n_j} - xi_j feels -dH/ds: -k_t s while sticking
(k_t |s| <= F_T), -F_T sign(s) while sliding.
"""

import functools
from types import SimpleNamespace

import warp as wp

from dynfab.kernels import banded, contact
from dynfab.kernels.precision import VECTORS


@functools.cache
def functions(scalar) -> SimpleNamespace:
    """The friction `wp.func`s for one scalar type."""
    vec = VECTORS[scalar]
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
    def add_forces(y: int, pos: wp.array2d(dtype=vec), nodes: wp.array(dtype=wp.int32),
                   anchors: wp.array2d(dtype=scalar), contact_force: wp.array2d(dtype=scalar),
                   alpha: wp.array(dtype=scalar), constant: wp.array(dtype=scalar),
                   onset: wp.array(dtype=scalar), stick_stiffness: wp.array(dtype=scalar),
                   friction_limit: wp.array2d(dtype=scalar), force: wp.array2d(dtype=vec)):
        """force_x -= dH/ds [N] with F_T from the current R_j; stores F_T,j [N]."""
        for j in range(nodes.shape[0]):
            node = nodes[j]
            limit_j = limit(contact_force[y, j], alpha[y], constant[y], onset[y])
            friction_limit[y, j] = limit_j
            slip = pos[y, node][0] - anchors[y, j]
            force[y, node] = force[y, node] - vec(huber_derivative(slip, limit_j, stick_stiffness[y]),
                                                  scalar(0.0))

    @wp.func
    def add_band(y: int, pos: wp.array2d(dtype=vec), nodes: wp.array(dtype=wp.int32),
                 anchors: wp.array2d(dtype=scalar), friction_limit: wp.array2d(dtype=scalar),
                 stick_stiffness: wp.array(dtype=scalar), stiffest: bool,
                 band: wp.array3d(dtype=scalar)):
        """band_xx += k_t [N/m] on sticking crossings (F_T frozen); with `stiffest`, on every one."""
        for j in range(nodes.shape[0]):
            node = nodes[j]
            slip = pos[y, node][0] - anchors[y, j]
            if stiffest or not is_sliding(slip, friction_limit[y, j], stick_stiffness[y]):
                band_ops.add(band, y, 2 * node, 2 * node, stick_stiffness[y])

    @wp.func
    def return_map(y: int, pos: wp.array2d(dtype=vec), nodes: wp.array(dtype=wp.int32),
                   anchors: wp.array2d(dtype=scalar), friction_limit: wp.array2d(dtype=scalar),
                   stick_stiffness: wp.array(dtype=scalar)) -> scalar:
        """Move the anchors of sliding crossings onto the slip surface; the energy lost [J].

        xi = x - sign(x - xi) F_T / k_t where k_t |x - xi| > F_T, dissipating F_T |delta xi|
        (MODEL.md 4). The friction force -dH/ds of the anchors before equals -k_t (x - xi) after.
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

    return SimpleNamespace(limit=limit, add_forces=add_forces, add_band=add_band,
                           return_map=return_map)
