"""The total gradient, force and tangent stiffness of one yarn: a loop over the active terms
(docs/model.md sections 2-4).

V = sum of the active terms' energies (`dynfab.terms.registry`, the scene switches
each on). Every term module `dynfab.kernels.<name>` has the same `wp.func`s with
the same arguments, so the totals here are loops over the variant's terms,
unrolled at code generation (`for i in range(wp.static(n))` with
`wp.static(funcs[i])`): a variant without a term compiles none of its code.

    energy(y, pos, yarn, anchors, P, contact_force) -> E [J]
    add_gradient(y, pos, yarn, anchors, P, contact_force, contact_tangent, friction_limit, grad)
    add_hessian(y, pos, yarn, anchors, contact_tangent, friction_limit, definite, stiffest, band)

(`add_hessian` only where the term has one: gravity and the load are linear; both are
forced inline, `wp.func(inline=True)`, since each receives the YarnArrays struct by value). The
terms run in registry order: contact writes R_j and dR/dg into contact_force and
contact_tangent, and friction, after it, its limit F_T(R_j) into friction_limit.
The solver's force is f = -dV/dr (+ the Huber terms' -dH/ds), 0 on the fixed dofs
(node 0, z_N, and x_N under displacement control; docs/model.md section 1).
"""

import functools
import importlib
from types import SimpleNamespace

import warp as wp

from dynfab.kernels import banded, yarn_arrays
from dynfab.kernels.precision import VECTORS
from dynfab.terms import registry


def term_functions(scalar, name: str) -> SimpleNamespace:
    """The `wp.func`s of term `name` (`dynfab.kernels.<name>.functions(scalar)`)."""
    return importlib.import_module(f"dynfab.kernels.{name}").functions(scalar)


@functools.cache
def functions(scalar, terms: tuple) -> SimpleNamespace:
    """The gradient, force, energy and stiffness `wp.func`s of one term selection and scalar type.

    `terms` are active term names in registry order (`Configuration.terms`); without
    "load", x_N is fixed (displacement control).
    """
    vec = VECTORS[scalar]
    YarnArrays = yarn_arrays.struct(scalar)
    band_ops = banded.functions(scalar)
    ops = [term_functions(scalar, name) for name in terms]
    gradients = [o.add_gradient for o in ops]
    energies = [o.energy for o in ops]
    energy_slots = [registry.NAMES.index(name) for name in terms]
    hessians = [o.add_hessian for o in ops if hasattr(o, "add_hessian")]
    force_control = "load" in terms

    @wp.func(inline=True)
    def add_gradient(y: int, pos: wp.array2d(dtype=vec), yarn: YarnArrays,
                     anchors: wp.array2d(dtype=scalar), P: scalar,
                     contact_force: wp.array2d(dtype=scalar), contact_tangent: wp.array2d(dtype=scalar),
                     friction_limit: wp.array2d(dtype=scalar), grad: wp.array2d(dtype=vec)):
        """grad += dV/dr [N] of every active term, F_T from this evaluation's R_j."""
        for k in range(wp.static(len(gradients))):
            wp.static(gradients[k])(y, pos, yarn, anchors, P, contact_force, contact_tangent,
                                    friction_limit, grad)

    @wp.func
    def worse(worst: scalar, value: scalar) -> scalar:
        """The larger of worst and |value|; a NaN, once met, stays (a non-finite force is never
        hidden behind the finite components compared after it)."""
        result = worst
        if worst == worst and not wp.abs(value) <= worst:
            result = wp.abs(value)
        return result

    @wp.func(inline=True)
    def force_from_gradient(y: int, force: wp.array2d(dtype=vec)) -> scalar:
        """force = -grad on the free dofs, 0 on the fixed ones (node 0, z_N, and x_N under
        displacement control); returns the residual, the largest |force component| [N],
        computed in the same pass with every component compared in node order (`worse`)."""
        last = force.shape[1] - 1
        force[y, 0] = vec(scalar(0.0), scalar(0.0))
        worst = scalar(0.0)
        for i in range(1, last):
            f = -force[y, i]
            force[y, i] = f
            worst = worse(worse(worst, f[0]), f[1])
        free_x = -force[y, last][0]
        if wp.static(not force_control):
            free_x = scalar(0.0)
        force[y, last] = vec(free_x, scalar(0.0))
        return worse(worse(worst, free_x), scalar(0.0))

    @wp.func
    def evaluate(y: int, pos: wp.array2d(dtype=vec), yarn: YarnArrays, anchors: wp.array2d(dtype=scalar),
                 end_load: scalar, force: wp.array2d(dtype=vec), contact_force: wp.array2d(dtype=scalar),
                 contact_tangent: wp.array2d(dtype=scalar),
                 friction_limit: wp.array2d(dtype=scalar)) -> scalar:
        """force = -dV/dr [N] on the free dofs (the Huber terms' F_T from this evaluation's
        R_j); R_j, dR/dg and F_T,j of every crossing. Returns the residual [N], the largest
        |force component| (`force_from_gradient`).

        `end_load` is P [N] (unused under displacement control); `anchors` xi_j [m] stay fixed.
        """
        for i in range(force.shape[1]):
            force[y, i] = vec(scalar(0.0), scalar(0.0))
        add_gradient(y, pos, yarn, anchors, end_load, contact_force, contact_tangent,
                     friction_limit, force)
        return force_from_gradient(y, force)

    @wp.func
    def energy(y: int, pos: wp.array2d(dtype=vec), yarn: YarnArrays, anchors: wp.array2d(dtype=scalar),
               P: scalar, contact_force: wp.array2d(dtype=scalar), out: wp.array2d(dtype=scalar)):
        """out[y, k] = E_k [J] of every active term k (its index in `registry.TERMS`); the
        others are left as they are. Friction's F_T from the given R_j."""
        for k in range(wp.static(len(energies))):
            out[y, wp.static(energy_slots[k])] = wp.static(energies[k])(y, pos, yarn, anchors, P,
                                                                        contact_force)

    @wp.func(inline=True)
    def add_hessian(y: int, pos: wp.array2d(dtype=vec), yarn: YarnArrays,
                    anchors: wp.array2d(dtype=scalar), contact_tangent: wp.array2d(dtype=scalar),
                    friction_limit: wp.array2d(dtype=scalar), definite: bool, stiffest: bool,
                    band: wp.array3d(dtype=scalar)):
        """band += d2V/dr2 [N/m] of every active term that has one (F_T frozen)."""
        for k in range(wp.static(len(hessians))):
            wp.static(hessians[k])(y, pos, yarn, anchors, contact_tangent, friction_limit, definite,
                                   stiffest, band)

    @wp.func
    def assemble_band(y: int, pos: wp.array2d(dtype=vec), yarn: YarnArrays,
                      anchors: wp.array2d(dtype=scalar), contact_tangent: wp.array2d(dtype=scalar),
                      friction_limit: wp.array2d(dtype=scalar), definite: bool, stiffest: bool,
                      band: wp.array3d(dtype=scalar)):
        """band = K [N/m], the tangent stiffness of V plus the Huber terms (F_T frozen).

        `definite` drops the negative parts of stretch and bending (semi_implicit);
        `stiffest` takes each contact at its bound k_we and every crossing as
        sticking, the stiffest K a load step can meet (Gershgorin masses, docs/model.md section 5).
        """
        band_ops.clear(band, y)
        add_hessian(y, pos, yarn, anchors, contact_tangent, friction_limit, definite, stiffest, band)

    @wp.func
    def gershgorin_row_sums(y: int, band: wp.array3d(dtype=scalar), node: int) -> scalar:
        """max over the node's two dofs of sum_j |K_ij| [N/m]."""
        return wp.max(band_ops.absolute_row_sum(band, y, 2 * node),
                      band_ops.absolute_row_sum(band, y, 2 * node + 1))

    return SimpleNamespace(add_gradient=add_gradient, evaluate=evaluate, energy=energy,
                           add_hessian=add_hessian, assemble_band=assemble_band,
                           gershgorin_row_sums=gershgorin_row_sums)
