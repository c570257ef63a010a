"""The whole model's energy, gradient and banded Hessian for one yarn (MODEL.md 2-4).

Reads as the list of terms: each call below is one term of
V = E_stretch + E_bend + sum_j E_contact,j - W_load - W_gravity (+ sum_j H_j),
taken only when the yarn has it. `P` is the end load [N] (0 under
displacement control, where the load term is absent); `anchors` and
`friction_limit` (F_T, frozen) are per crossing. `branch` (optional, per crossing)
holds crossings open or closed (`dynfab.terms.contact`); without it the contact is
unilateral.
"""

import numba
import numpy as np

from dynfab import banded
from dynfab.terms import bending, contact, friction, gravity, load, stretch

STRETCH, BENDING, CONTACT, FRICTION, GRAVITY, LOAD = range(6)
"""Indices of the energy vector, in the order of `dynfab.model.TERMS`."""


@numba.njit(cache=True)
def energies(pos, yarn, P, anchors, friction_limit, out, branch=None):
    """Each term's energy [J] into out (6,); a term the yarn lacks is 0."""
    out[:] = 0.0
    out[STRETCH] = stretch.energy(pos, yarn.rest_length, yarn.stretch_stiffness)
    out[BENDING] = bending.energy(pos, yarn.bend_stiffness, yarn.rest_angle)
    if yarn.crossing_node.size > 0:
        out[CONTACT] = contact.energy(pos, yarn.crossing_node, yarn.crossing_side,
                                      yarn.gap_offset, yarn.contact_law, branch)
    if yarn.has_friction:
        out[FRICTION] = friction.energy(pos, yarn.crossing_node, anchors, friction_limit,
                                        yarn.stick_stiffness)
    if yarn.has_gravity:
        out[GRAVITY] = gravity.energy(pos, yarn.rest_position, yarn.mass, yarn.gravity)
    out[LOAD] = load.energy(pos, yarn.rest_position, P)


@numba.njit(cache=True)
def gradient(pos, yarn, P, anchors, friction_limit, grad, branch=None):
    """grad = dV/dr (N+1, 2) [N], F_T frozen."""
    grad[:, :] = 0.0
    stretch.add_gradient(pos, yarn.rest_length, yarn.stretch_stiffness, grad)
    bending.add_gradient(pos, yarn.bend_stiffness, yarn.rest_angle, grad)
    if yarn.crossing_node.size > 0:
        contact.add_gradient(pos, yarn.crossing_node, yarn.crossing_side, yarn.gap_offset,
                             yarn.contact_law, grad, branch)
    if yarn.has_friction:
        friction.add_gradient(pos, yarn.crossing_node, anchors, friction_limit,
                              yarn.stick_stiffness, grad)
    if yarn.has_gravity:
        gravity.add_gradient(yarn.mass, yarn.gravity, grad)
    load.add_gradient(P, grad)


@numba.njit(cache=True)
def hessian(pos, yarn, anchors, friction_limit, contact_tangent, coupled, band, secant=False,
            branch=None):
    """band = d2V/dr2 [N/m], banded (`dynfab.banded`), F_T frozen.

    With `coupled`, adds the derivative of F_T through the contact force on
    sliding crossings (`friction.add_limit_coupling`): the Jacobian of the
    coupled friction problem, no longer symmetric. With `secant`, sliding
    crossings get the secant stiffness F_T / |s| (`friction.add_hessian`).
    """
    band[:, :] = 0.0
    stretch.add_hessian(pos, yarn.rest_length, yarn.stretch_stiffness, band)
    bending.add_hessian(pos, yarn.bend_stiffness, yarn.rest_angle, band)
    if yarn.crossing_node.size > 0:
        contact.add_hessian(pos, yarn.crossing_node, yarn.crossing_side, yarn.gap_offset,
                            yarn.contact_law, band, branch)
    if yarn.has_friction:
        friction.add_hessian(pos, yarn.crossing_node, anchors, friction_limit,
                             yarn.stick_stiffness, band, secant)
        if coupled:
            friction.add_limit_coupling(pos, yarn.crossing_node, yarn.crossing_side, anchors,
                                        friction_limit, yarn.stick_stiffness,
                                        limit_slopes(pos, yarn, branch), contact_tangent, band)


@numba.njit(cache=True)
def limit_slopes(pos, yarn, branch=None):
    """dF_T/dR [-] of every crossing at its current contact force."""
    slopes = np.zeros(yarn.crossing_node.size)
    for j in range(slopes.size):
        g = contact.closure(pos, yarn.crossing_node[j], yarn.crossing_side[j], yarn.gap_offset[j])
        R = contact.force_on_branch(g, yarn.contact_law, contact.branch_of(branch, j))
        slopes[j] = friction.limit_slope(R, yarn.friction_alpha, yarn.friction_constant,
                                         yarn.friction_onset)
    return slopes


@numba.njit(cache=True)
def contact_state(pos, yarn, contact_force, friction_limit, contact_tangent, branch=None):
    """R_j [N], F_T,j [N] (Gralen, 0 without friction) and dR/dg [N/m] of every crossing."""
    for j in range(yarn.crossing_node.size):
        g = contact.closure(pos, yarn.crossing_node[j], yarn.crossing_side[j], yarn.gap_offset[j])
        on = contact.branch_of(branch, j)
        R = contact.force_on_branch(g, yarn.contact_law, on)
        contact_force[j] = R
        contact_tangent[j] = contact.tangent_on_branch(g, R, yarn.contact_law, on)
        friction_limit[j] = 0.0
        if yarn.has_friction:
            friction_limit[j] = friction.limit(R, yarn.friction_alpha, yarn.friction_constant,
                                               yarn.friction_onset)


def tangent(pos, yarn, anchors, coupled: bool) -> np.ndarray:
    """The banded tangent [N/m] of one yarn at `pos` (`hessian`, `dynfab.banded` layout): F_T
    and dR/dg from the contact state there, the friction anchors of the step's start; with
    `coupled` the coupled friction Jacobian."""
    pos = np.ascontiguousarray(pos, dtype=np.float64)
    c = yarn.crossing_node.size
    contact_force, friction_limit, contact_tangent = np.zeros(c), np.zeros(c), np.zeros(c)
    contact_state(pos, yarn, contact_force, friction_limit, contact_tangent)
    band = banded.zeros_band(pos.size)
    hessian(pos, yarn, np.ascontiguousarray(anchors, dtype=np.float64), friction_limit,
            contact_tangent, coupled, band)
    return band
