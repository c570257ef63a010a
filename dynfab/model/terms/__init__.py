"""The model's energy terms, one concept a module (docs/model.md sections 2-4).

Each module holds numba functions on plain arrays: `energy(...)`, `add_gradient(...,
grad)` and `add_hessian(..., band)`, accumulating into a gradient of shape
(N+1, 2) [N] and a banded Hessian (`dynfab.linalg.banded`) [N/m]; and the term's entry
points, with the same arguments for every term:

    yarn_energy(pos, yarn, frozen) -> E [J]
    add_yarn_gradient(pos, yarn, frozen, grad)    grad += dE/dr
    add_yarn_hessian(pos, yarn, frozen, band)     band += d2E/dr2 (nothing for a linear term)

`yarn` is a `dynfab.model.yarn.Yarn`, `frozen` a `dynfab.model.assembly.Frozen` (what a Newton
solve holds fixed: end load, friction anchors and limits, contact branches). The
registry (`dynfab.model.terms.registry`) lists the terms; `dynfab.model.assembly` calls the entry
points of the terms a yarn has (`Yarn.active`), in registry order.
"""
