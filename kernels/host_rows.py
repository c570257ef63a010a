"""The stiffest tangent's Gershgorin rows in a kernel where the host computes them
(docs/model.md (5.5); `dynfab.model.terms.kinematics.stiffest_rows` into `state.rows` and
`state.diagonal`): the spatial structure's (from its exact Hessian: its kernels' blocks are
Gauss-Newton's, which may not bound it) and the planar one's whose crossings slide (the
kernels' band knows no slide)."""

import functools
from types import SimpleNamespace

import warp as wp

from dynfab.kernels import structure_arrays, structure_state


@functools.cache
def functions(scalar, dim: int) -> SimpleNamespace:
    """`stiffest_tie` and `stiffest_chain` with nothing to assemble, `gershgorin_row` and
    `largest_diagonal` reading the host's rows (module docstring)."""
    Data = structure_arrays.struct(scalar, dim)
    State = structure_state.struct(scalar, dim)

    @wp.func(inline=True)
    def stiffest_tie(t: int, data: Data, state: State):
        """Nothing: the host gave the rows."""
        pass

    @wp.func(inline=True)
    def stiffest_chain(c: int, data: Data, state: State):
        """Nothing: the host gave the rows."""
        pass

    @wp.func(inline=True)
    def gershgorin_row(i: int, data: Data, state: State) -> scalar:
        """The largest over node i's dofs of sum_j |K_ij| [N/m], from the host."""
        return state.rows[i]

    @wp.func(inline=True)
    def largest_diagonal(i: int, data: Data, state: State) -> scalar:
        """max |K_ii| [N/m] over node i's dofs, from the host."""
        return state.diagonal[i]

    return SimpleNamespace(stiffest_tie=stiffest_tie, stiffest_chain=stiffest_chain,
                           gershgorin_row=gershgorin_row, largest_diagonal=largest_diagonal)
