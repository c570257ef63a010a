"""Gralen friction as stick-slip, in the incremental Huber form (docs/model.md section 4; paper eqs.
20-27).

Friction limit (Gralen, eq. 20, with its onset regularised over R_0; docs/model.md section 4):

    F_T,j = alpha R_j + beta ell r_f (1 - exp(-R_j / R_0))   if R_j > 0,   else 0;

R_0 = 0 is the literal law, whose limit jumps by beta ell r_f as a crossing touches.
`limit_slope` is dF_T/dR, 0 where R <= 0. (A smooth continuation of F_T to R < 0
for the static solver's active set would make F_T negative: an anti-friction force
with no stick zone, discontinuous at zero slip; it was tried and dropped.)

Within a load step the anchors xi_j stay put and each crossing adds the convex
Huber potential of its slip s = x_{n_j} - xi_j (`dynfab.model.terms.huber`, the law every slip
dimension shares):

    H(s) = 1/2 k_t s^2                 for |s| < F_T / k_t   (sticking)
         = F_T |s| - F_T^2 / (2 k_t)   otherwise              (sliding; 0 where F_T = 0),

whose force on the warp is -k_t s or -F_T sign(s). After the step the anchors
are return-mapped, xi = x - sign(s) F_T / k_t where k_t |s| > F_T, and the
energy lost is F_T |delta xi|.
"""

import numba
import numpy as np

from dynfab.linalg.banded import band_add
from dynfab.model.terms import contact, registry
from dynfab.model.terms import huber as huber_law

INDEX = registry.index("friction")
"""The term's place in the registry: `yarn.active[INDEX]` says whether a yarn has friction."""


def law_constants(friction) -> tuple[float, float, float]:
    """(alpha [-], constant = beta ell r_f [N], onset R_0 [N]) of Gralen's law
    (docs/model.md section 4) from a friction table (a scene's [friction], a fabric's
    `Friction`: alpha, beta, contact_length, fiber_radius, onset_force); zeros for None."""
    if friction is None:
        return 0.0, 0.0, 0.0
    return (float(friction.alpha),
            float(friction.beta * friction.contact_length * friction.fiber_radius),
            float(friction.onset_force))


@numba.njit(cache=True)
def limit(R, alpha, constant, onset):
    """F_T [N] from Gralen's law; `constant` = beta ell r_f [N], `onset` = R_0 [N] (0: literal)."""
    if not R > 0.0:
        return 0.0
    if onset == 0.0:
        return alpha * R + constant
    return alpha * R - constant * np.expm1(-R / onset)


@numba.njit(cache=True)
def limit_slope(R, alpha, constant, onset):
    """dF_T/dR [-] of `limit`: alpha + (beta ell r_f / R_0) exp(-R / R_0) for R > 0."""
    if not R > 0.0:
        return 0.0
    if onset == 0.0:
        return alpha
    return alpha + constant / onset * np.exp(-R / onset)


@numba.njit(cache=True)
def tie_limits(contact_force, law, onset, out):
    """F_T [N] of every tie from its own law row (alpha, beta ell r_f, R_0, k_t) of a
    structure's `tie_friction_law` (T, 4); `onset` >= 0 replaces every tie's R_0 (a stage of the
    continuation in R_0, docs/model.md section 4), < 0 keeps them."""
    for j in range(contact_force.size):
        r0 = law[j, 2] if onset < 0.0 else onset
        out[j] = limit(contact_force[j], law[j, 0], law[j, 1], r0)


@numba.njit(cache=True)
def tie_limit_slope(R, law, onset, j):
    """dF_T/dR [-] of tie j at contact force R (`tie_limits`' law and `onset`)."""
    r0 = law[j, 2] if onset < 0.0 else onset
    return limit_slope(R, law[j, 0], law[j, 1], r0)


@numba.njit(cache=True)
def is_sliding(slip, friction_limit, stick_stiffness):
    """The sliding (or open) branch of the slip `slip` [m] (`dynfab.model.terms.huber.slides`)."""
    return huber_law.slides(abs(slip), friction_limit, stick_stiffness)


@numba.njit(cache=True)
def huber(slip, friction_limit, stick_stiffness):
    """H(s) [J] (`dynfab.model.terms.huber.energy`)."""
    return huber_law.energy(abs(slip), friction_limit, stick_stiffness)


@numba.njit(cache=True)
def huber_derivative(slip, friction_limit, stick_stiffness):
    """dH/ds [N]: minus the friction force on the warp; 0 on an open crossing."""
    return huber_law.force_per_slip(abs(slip), friction_limit, stick_stiffness) * slip


@numba.njit(cache=True)
def energy(pos, nodes, anchors, friction_limit, stick_stiffness):
    """sum_j H(x_{n_j} - xi_j) [J] with F_T frozen."""
    total = 0.0
    for j in range(nodes.size):
        total += huber(pos[nodes[j], 0] - anchors[j], friction_limit[j], stick_stiffness)
    return total


@numba.njit(cache=True)
def add_gradient(pos, nodes, anchors, friction_limit, stick_stiffness, grad):
    """grad_x += dH/ds."""
    for j in range(nodes.size):
        grad[nodes[j], 0] += huber_derivative(pos[nodes[j], 0] - anchors[j], friction_limit[j],
                                              stick_stiffness)


@numba.njit(cache=True)
def add_hessian(pos, nodes, anchors, friction_limit, stick_stiffness, band, secant=False):
    """band_xx += k_t on sticking crossings, 0 on sliding ones (F_T frozen).

    With `secant`, a sliding crossing gets F_T / |s| instead of 0: the curvature
    of the quadratic that touches H at s and lies above it everywhere
    (|s| <= s^2 / (2 |s0|) + |s0| / 2), so a Newton step on that model cannot
    overshoot a crossing that is about to stick again.
    """
    for j in range(nodes.size):
        slip = pos[nodes[j], 0] - anchors[j]
        if not is_sliding(slip, friction_limit[j], stick_stiffness):
            band_add(band, 2 * nodes[j], 2 * nodes[j], stick_stiffness)
        elif secant and friction_limit[j] > 0.0:
            band_add(band, 2 * nodes[j], 2 * nodes[j], friction_limit[j] / abs(slip))


@numba.njit(cache=True)
def add_limit_coupling(pos, nodes, sides, anchors, friction_limit, stick_stiffness, limit_slope,
                       contact_tangent, band):
    """band_xz += d(dH/ds)/dz = sign(s) dF_T/dR dR/dg dg/dz on sliding, closed crossings.

    The derivative of F_T through R(g), g = c - s_j z: what makes Newton on the
    coupled (non-symmetric) problem quadratic. `limit_slope` is dF_T/dR and
    `contact_tangent` dR/dg per crossing (0 where open).
    """
    for j in range(nodes.size):
        slip = pos[nodes[j], 0] - anchors[j]
        if contact_tangent[j] > 0.0 and is_sliding(slip, friction_limit[j], stick_stiffness):
            band_add(band, 2 * nodes[j], 2 * nodes[j] + 1,
                     np.sign(slip) * limit_slope[j] * contact_tangent[j] * (-sides[j]))


@numba.njit(cache=True)
def return_map(pos, nodes, anchors, friction_limit, stick_stiffness, sliding, friction_force):
    """Move the anchors of sliding crossings onto the slip surface; return the energy lost [J].

    xi = x - sign(x - xi) F_T / k_t where k_t |x - xi| > F_T; dissipation F_T |delta xi|.
    Fills `sliding` (bool) and the signed friction force on the warp [N]: -k_t (x - xi)
    while sticking, exactly -sign(s) F_T while sliding (not -k_t (x - xi), whose
    rounding grows with k_t).
    """
    lost = 0.0
    for j in range(nodes.size):
        x = pos[nodes[j], 0]
        slip = x - anchors[j]
        sliding[j] = huber_law.moves(abs(slip), friction_limit[j], stick_stiffness)
        if sliding[j]:
            f_t = max(friction_limit[j], 0.0)
            moved = x - np.sign(slip) * f_t / stick_stiffness
            lost += f_t * abs(moved - anchors[j])
            anchors[j] = moved
            friction_force[j] = -np.sign(slip) * f_t
        else:
            friction_force[j] = -stick_stiffness * slip
    return lost


# The term's entry points (`dynfab.model.terms`): anchors and F_T frozen (`frozen.anchors`,
# `frozen.friction_limit`).


@numba.njit(cache=True)
def yarn_energy(pos, yarn, frozen):
    """sum_j H_j [J] of a `dynfab.model.yarn.Yarn`."""
    return energy(pos, yarn.crossing_node, frozen.anchors, frozen.friction_limit,
                  yarn.stick_stiffness)


@numba.njit(cache=True)
def add_yarn_gradient(pos, yarn, frozen, grad):
    """grad_x += dH/ds."""
    add_gradient(pos, yarn.crossing_node, frozen.anchors, frozen.friction_limit,
                 yarn.stick_stiffness, grad)


@numba.njit(cache=True)
def add_yarn_hessian(pos, yarn, frozen, band):
    """band_xx += d2H/ds2 (the secant on sliding crossings with `frozen.secant`); with
    `frozen.coupled`, also the derivative of F_T through the contact force
    (`add_limit_coupling`, dR/dg from `frozen.contact_tangent`)."""
    add_hessian(pos, yarn.crossing_node, frozen.anchors, frozen.friction_limit,
                yarn.stick_stiffness, band, frozen.secant)
    if frozen.coupled:
        add_limit_coupling(pos, yarn.crossing_node, yarn.crossing_side, frozen.anchors,
                           frozen.friction_limit, yarn.stick_stiffness,
                           limit_slopes(pos, yarn, frozen.branch), frozen.contact_tangent, band)


@numba.njit(cache=True)
def limit_slopes(pos, yarn, branch=None):
    """dF_T/dR [-] of every crossing of a `dynfab.model.yarn.Yarn` at its current contact force."""
    slopes = np.zeros(yarn.crossing_node.size)
    for j in range(slopes.size):
        g = contact.closure(pos, yarn.crossing_node[j], yarn.crossing_side[j], yarn.gap_offset[j])
        R = contact.force_on_branch(g, yarn.contact_law, contact.branch_of(branch, j))
        slopes[j] = limit_slope(R, yarn.friction_alpha, yarn.friction_constant, yarn.friction_onset)
    return slopes
