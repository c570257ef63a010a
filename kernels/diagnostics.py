"""Each term's energy, gradient and tangent stiffness at given positions, for tests and debugging.

The solvers call `dynfab.kernels.forces.evaluate` (the force of all active terms at
once); here each active term (`Configuration.terms`, from the registry
`dynfab.terms.registry`) can be evaluated alone, in the sign convention of its numba
twin in `dynfab.terms` (grad += dV/dr), so one test can check both twins the same
way, and the energy of every active term per yarn is computed as `dynfab.assembly.energies`
does it.
"""

import warp as wp

from dynfab.kernels import banded, forces, yarn_arrays
from dynfab.kernels.configuration import MODULE_OPTIONS, Configuration, cached
from dynfab.kernels.precision import VECTORS
from dynfab.terms import registry

ALL_TERMS = -1
"""`term` value asking for every active term: their summed gradient and K, each one's energy."""
TERM_INDEX = {name: k for k, name in enumerate(registry.NAMES)}
"""Term name -> its `term` value: its index in `registry.TERMS` (and in the energy rows)."""


@cached
def term_kernel(configuration: Configuration):
    """Kernel evaluate_term(yarn, pos, anchors, P, term, refresh, force, grad, band, energy,
    contact_force, contact_tangent, friction_limit), one thread per yarn.

    With `refresh`, first the solver's evaluation at `pos` (`forces.evaluate`: the
    force [N] on the free dofs, and R, dR/dg, F_T of every crossing); otherwise R,
    dR/dg and F_T are inputs, as given (friction then takes its F_T from the given R:
    frozen). Then term `term` (an index in `registry.TERMS`, or ALL_TERMS) alone, if
    active: grad = its dV/dr [N], band = its banded Hessian [N/m] (F_T frozen, none for
    the linear terms), energy[y, term] = its energy [J] (the other rows left as given).
    """
    scalar = configuration.scalar
    vec = VECTORS[scalar]
    YarnArrays = yarn_arrays.struct(scalar)
    total = forces.functions(scalar, configuration.terms)
    band_ops = banded.functions(scalar)
    ops = [forces.term_functions(scalar, name) for name in configuration.terms]
    indices = [TERM_INDEX[name] for name in configuration.terms]
    gradients = [o.add_gradient for o in ops]
    energies = [o.energy for o in ops]
    stiff = [k for k, o in enumerate(ops) if hasattr(o, "add_hessian")]
    hessians = [ops[k].add_hessian for k in stiff]
    stiff_indices = [indices[k] for k in stiff]

    @wp.kernel(module="unique", module_options=MODULE_OPTIONS)
    def evaluate_term(yarn: YarnArrays, pos: wp.array2d(dtype=vec), anchors: wp.array2d(dtype=scalar),
                      P: scalar, term: int, refresh: int, force: wp.array2d(dtype=vec),
                      grad: wp.array2d(dtype=vec), band: wp.array3d(dtype=scalar),
                      energy: wp.array2d(dtype=scalar), contact_force: wp.array2d(dtype=scalar),
                      contact_tangent: wp.array2d(dtype=scalar),
                      friction_limit: wp.array2d(dtype=scalar)):
        y = wp.tid()
        if refresh != 0:
            total.evaluate(y, pos, yarn, anchors, P, force, contact_force, contact_tangent,
                           friction_limit)
        for i in range(grad.shape[1]):
            grad[y, i] = vec(scalar(0.0), scalar(0.0))
        band_ops.clear(band, y)
        for k in range(wp.static(len(gradients))):
            if term == ALL_TERMS or term == wp.static(indices[k]):
                wp.static(gradients[k])(y, pos, yarn, anchors, P, contact_force, contact_tangent,
                                        friction_limit, grad)
                energy[y, wp.static(indices[k])] = wp.static(energies[k])(y, pos, yarn, anchors, P,
                                                                         contact_force)
        for k in range(wp.static(len(hessians))):
            if term == ALL_TERMS or term == wp.static(stiff_indices[k]):
                wp.static(hessians[k])(y, pos, yarn, anchors, contact_tangent, friction_limit, False,
                                       False, band)

    return evaluate_term
