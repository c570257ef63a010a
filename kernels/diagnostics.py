"""One term's force and tangent stiffness at given positions, for tests and debugging.

The solvers never call this: they use `dynfab.kernels.forces.evaluate` (all active
terms at once). Here each term of `dynfab.model.TERMS` can be evaluated alone,
so each can be checked against its numba twin in `dynfab.terms`.
"""

import warp as wp

from dynfab.kernels import banded, bending, contact, forces, friction, gravity, load, stretch
from dynfab.kernels import yarn_arrays
from dynfab.kernels.configuration import MODULE_OPTIONS, Configuration, cached
from dynfab.kernels.precision import VECTORS
from dynfab.model import TERMS

ALL_TERMS = -1
"""`term` value asking for the total force (free dofs only) and the whole K."""
STRETCH, BENDING, CONTACT, FRICTION, GRAVITY, LOAD = (TERMS.index(t) for t in
                                                      ("stretch", "bending", "contact",
                                                       "friction", "gravity", "load"))


@cached
def term_kernel(configuration: Configuration):
    """Kernel: force [N] and banded K [N/m] of term `term` (or of all), per yarn; also R, dR/dg, F_T."""
    scalar = configuration.scalar
    vec = VECTORS[scalar]
    YarnArrays = yarn_arrays.struct(scalar)
    total = forces.functions(*configuration.terms)
    band_ops = banded.functions(scalar)
    stretch_ops, bending_ops = stretch.functions(scalar), bending.functions(scalar)
    contact_ops, friction_ops = contact.functions(scalar), friction.functions(scalar)
    gravity_ops, load_ops = gravity.functions(scalar), load.functions(scalar)
    has_friction, has_gravity, force_control = configuration.terms[1:]

    @wp.kernel(module="unique", module_options=MODULE_OPTIONS)
    def evaluate_term(yarn: YarnArrays, pos: wp.array2d(dtype=vec), anchors: wp.array2d(dtype=scalar),
                      end_load: scalar, term: int, force: wp.array2d(dtype=vec),
                      band: wp.array3d(dtype=scalar), contact_force: wp.array2d(dtype=scalar),
                      contact_tangent: wp.array2d(dtype=scalar),
                      friction_limit: wp.array2d(dtype=scalar)):
        y = wp.tid()
        total.evaluate(y, pos, yarn, anchors, end_load, force, contact_force, contact_tangent,
                       friction_limit)
        total.assemble_band(y, pos, yarn, anchors, contact_tangent, friction_limit, False, False, band)
        if term != ALL_TERMS:
            for i in range(force.shape[1]):
                force[y, i] = vec(scalar(0.0), scalar(0.0))
            band_ops.clear(band, y)
        if term == STRETCH:
            stretch_ops.add_forces(y, pos, yarn.rest_length, yarn.stretch_stiffness, force)
            stretch_ops.add_band(y, pos, yarn.rest_length, yarn.stretch_stiffness, False, band)
        if term == BENDING:
            bending_ops.add_forces(y, pos, yarn.bend_stiffness, yarn.rest_angle, force)
            bending_ops.add_band(y, pos, yarn.bend_stiffness, yarn.rest_angle, False, band)
        if term == CONTACT:
            contact_ops.add_forces(y, pos, yarn.crossing_node, yarn.crossing_side, yarn.gap_offset,
                                   yarn.contact_law, contact_force, contact_tangent, force)
            contact_ops.add_band(y, yarn.crossing_node, yarn.contact_law, contact_tangent, False, band)
        if wp.static(has_friction):
            if term == FRICTION:
                friction_ops.add_forces(y, pos, yarn.crossing_node, anchors, contact_force,
                                        yarn.friction_alpha, yarn.friction_constant,
                                        yarn.friction_onset,
                                        yarn.stick_stiffness, friction_limit, force)
                friction_ops.add_band(y, pos, yarn.crossing_node, anchors, friction_limit,
                                      yarn.stick_stiffness, False, band)
        if wp.static(has_gravity):
            if term == GRAVITY:
                gravity_ops.add_forces(y, yarn.mass, yarn.gravity, force)
        if wp.static(force_control):
            if term == LOAD:
                load_ops.add_forces(y, end_load, force)

    return evaluate_term
