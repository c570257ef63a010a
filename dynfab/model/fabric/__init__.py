"""The woven fabric: warp and weft yarns both as chains, coupled at every crossing
(docs/model.md section 10).

One concept per module: `spec` (the parameters), `layout` (as-woven geometry and the
arrays of the model), `contact` (the two-node crossing contact), `friction` (the
isotropic 2D Huber stick-slip), `assembly` (energy, gradient, sparse Hessian),
`inertia` (the stability check), `static` (the Newton solver on load steps).
"""
