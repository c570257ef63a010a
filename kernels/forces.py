"""The total nodal force and tangent stiffness of one yarn: the list of the active terms (MODEL.md 2-4).

f = -dV/dr + f_friction: stretch, bending and contact always, friction, gravity and
the end load only in the variants that have them (`wp.static`, so a variant
without a term compiles none of its code). The fixed dofs (node 0, z_N, and
x_N under displacement control; MODEL.md 1) carry no force.
"""

import functools
from types import SimpleNamespace

import warp as wp

from dynfab.kernels import banded, bending, contact, friction, gravity, load, stretch, yarn_arrays
from dynfab.kernels.precision import VECTORS


@functools.cache
def functions(scalar, has_friction: bool, has_gravity: bool, force_control: bool) -> SimpleNamespace:
    """The force and stiffness `wp.func`s of one term selection and scalar type."""
    vec = VECTORS[scalar]
    YarnArrays = yarn_arrays.struct(scalar)
    band_ops = banded.functions(scalar)
    stretch_ops, bending_ops = stretch.functions(scalar), bending.functions(scalar)
    contact_ops, friction_ops = contact.functions(scalar), friction.functions(scalar)
    gravity_ops, load_ops = gravity.functions(scalar), load.functions(scalar)

    @wp.func
    def fix_boundary(y: int, force: wp.array2d(dtype=vec)):
        """Zero the fixed components: node 0, z_N, and x_N under displacement control."""
        last = force.shape[1] - 1
        force[y, 0] = vec(scalar(0.0), scalar(0.0))
        free_x = force[y, last][0]
        if wp.static(not force_control):
            free_x = scalar(0.0)
        force[y, last] = vec(free_x, scalar(0.0))

    @wp.func
    def evaluate(y: int, pos: wp.array2d(dtype=vec), yarn: YarnArrays, anchors: wp.array2d(dtype=scalar),
                 end_load: scalar, force: wp.array2d(dtype=vec), contact_force: wp.array2d(dtype=scalar),
                 contact_tangent: wp.array2d(dtype=scalar), friction_limit: wp.array2d(dtype=scalar)):
        """force = -dV/dr + f_friction [N] on the free dofs; R_j, dR/dg and F_T,j of every crossing.

        `end_load` is P [N] (unused under displacement control); `anchors` xi_j [m] stay fixed.
        """
        for i in range(force.shape[1]):
            force[y, i] = vec(scalar(0.0), scalar(0.0))
        stretch_ops.add_forces(y, pos, yarn.rest_length, yarn.stretch_stiffness, force)
        bending_ops.add_forces(y, pos, yarn.bend_stiffness, yarn.rest_angle, force)
        contact_ops.add_forces(y, pos, yarn.crossing_node, yarn.crossing_side, yarn.gap_offset,
                               yarn.contact_law, contact_force, contact_tangent, force)
        if wp.static(has_friction):
            friction_ops.add_forces(y, pos, yarn.crossing_node, anchors, contact_force,
                                    yarn.friction_alpha, yarn.friction_constant,
                                    yarn.friction_onset,
                                    yarn.stick_stiffness, friction_limit, force)
        if wp.static(has_gravity):
            gravity_ops.add_forces(y, yarn.mass, yarn.gravity, force)
        if wp.static(force_control):
            load_ops.add_forces(y, end_load, force)
        fix_boundary(y, force)

    @wp.func
    def residual(y: int, force: wp.array2d(dtype=vec)) -> scalar:
        """Largest |force component| over the free dofs [N] (fixed ones are 0); NaN propagates."""
        worst = scalar(0.0)
        for i in range(force.shape[1]):
            for c in range(2):
                value = wp.abs(force[y, i][c])
                if not value <= worst:
                    worst = value
        return worst

    @wp.func
    def assemble_band(y: int, pos: wp.array2d(dtype=vec), yarn: YarnArrays,
                      anchors: wp.array2d(dtype=scalar), contact_tangent: wp.array2d(dtype=scalar),
                      friction_limit: wp.array2d(dtype=scalar), definite: bool, stiffest: bool,
                      band: wp.array3d(dtype=scalar)):
        """band = K [N/m], the tangent stiffness of V plus the Huber terms (F_T frozen).

        `definite` drops the negative parts of stretch and bending (semi_implicit);
        `stiffest` takes each contact at its bound k_we and every crossing as
        sticking, the stiffest K a load step can meet (Gershgorin masses, MODEL.md 5).
        """
        band_ops.clear(band, y)
        stretch_ops.add_band(y, pos, yarn.rest_length, yarn.stretch_stiffness, definite, band)
        bending_ops.add_band(y, pos, yarn.bend_stiffness, yarn.rest_angle, definite, band)
        contact_ops.add_band(y, yarn.crossing_node, yarn.contact_law, contact_tangent, stiffest, band)
        if wp.static(has_friction):
            friction_ops.add_band(y, pos, yarn.crossing_node, anchors, friction_limit,
                                  yarn.stick_stiffness, stiffest, band)

    @wp.func
    def gershgorin_row_sums(y: int, band: wp.array3d(dtype=scalar), node: int) -> scalar:
        """max over the node's two dofs of sum_j |K_ij| [N/m]."""
        return wp.max(band_ops.absolute_row_sum(band, y, 2 * node),
                      band_ops.absolute_row_sum(band, y, 2 * node + 1))

    return SimpleNamespace(evaluate=evaluate, residual=residual, assemble_band=assemble_band,
                           gershgorin_row_sums=gershgorin_row_sums)
