"""The node terms in a kernel (`dynfab.model.terms.nodes`, docs/model.md "Node terms"): each
registry node term's Warp form, summed at a node over the terms the structure has.

A node term's module gives `warp(scalar, vec)`, a SimpleNamespace of three `wp.func`s on
(x: vec, rest: vec, p: wp.array2d(dtype=scalar), i: int, first: int), its parameters
p[i, first:first + P] (`StructureData.node_parameters`): `force` -de/dx [N], `energy` e [J]
and `stiffness`, a bound of the row sums of d2e/dx2 [N/m] (the Gershgorin masses of the
planar kernels; a spatial structure's come from the host's Hessian, which holds it).
`functions(scalar, dim)` chains them, each gated by its column (`node_term_first`, -1 where
the structure lacks it); `count` says how many are registered: with none, the kernels compile
nothing of them (`wp.static(count)`).
"""

import functools
from types import SimpleNamespace

import warp as wp

from dynfab.kernels import structure_arrays
from dynfab.kernels.precision import vector
from dynfab.model.terms import nodes


@functools.cache
def functions(scalar, dim: int) -> SimpleNamespace:
    """The summed node terms of every variant of (scalar, dim) (module docstring)."""
    vec = vector(scalar, dim)
    Data = structure_arrays.struct(scalar, dim)

    @wp.func(inline=True)
    def no_force(i: int, pos: wp.array(dtype=vec), data: Data) -> vec:
        return vec()

    @wp.func(inline=True)
    def no_value(i: int, pos: wp.array(dtype=vec), data: Data) -> scalar:
        return scalar(0.0)

    summed = SimpleNamespace(force=no_force, energy=no_value, stiffness=no_value)
    for k, module in enumerate(nodes.MODULES):
        summed = _with_term(k, module.warp(scalar, vec), summed, vec, scalar, Data)
    return SimpleNamespace(count=len(nodes.MODULES), **vars(summed))


def _with_term(k: int, form, before, vec, scalar, Data) -> SimpleNamespace:
    """`before`'s sums plus node term k's (`form`, its Warp form), where the structure has it."""
    return SimpleNamespace(force=_gated(k, before.force, form.force, vec, vec, Data),
                           energy=_gated(k, before.energy, form.energy, scalar, vec, Data),
                           stiffness=_gated(k, before.stiffness, form.stiffness, scalar, vec,
                                            Data))


def _gated(k: int, before, term, value, vec, Data):
    """before(i, pos, data) + term(x_i, X_i, parameters, i, first) [of type `value`] where
    node term k's column `first` is set (the structure has it), else `before` alone."""

    @wp.func(inline=True)
    def summed(i: int, pos: wp.array(dtype=vec), data: Data) -> value:
        total = before(i, pos, data)
        first = data.node_term_first[wp.static(k)]
        if first >= 0:
            total = total + term(pos[i], data.rest_position[i], data.node_parameters, i, first)
        return total

    return summed
