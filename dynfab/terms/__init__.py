"""The model's energy terms, one concept a module (MODEL.md sections 2-4).

Each module holds numba functions on plain arrays: `energy(...)`, `add_gradient(...,
grad)` and `add_hessian(..., band)`, accumulating into a gradient of shape
(N+1, 2) [N] and a banded Hessian (`dynfab.banded`) [N/m]. `dynfab.model`
assembles them, using only the terms a scene has.
"""
