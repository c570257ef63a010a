"""Warp kernels of the dynamic solver (docs/model.md section 5), installed as `dynfab.kernels`:
one kernel layer for any `dynfab.model.structure.Structure`, which
`dynfab.solvers.dynamic.DynamicSolver` drives for every model
(docs/model.md, "The dynamic solver (decisions)").

One module per concept:

- `precision`: the scalar types (float64 by default, float32 on request); `runtime`: starting
  Warp on a device that exists; `status`: the per-group outcome codes the kernels write;
- `structure_arrays`, `structure_state`, `structure_settings`: the structure's flat arrays
  with its groups and blocks, the state the kernels update, the options of a launch;
- `tie_law`: the series contact law, Gralen's limit and the Huber term, written once;
  `structure_forces`: every term's force and energy (gather and scatter orders);
  `structure_tangent`: the chains' bands and the couplings outside them; `band_lu`: the
  banded LU of a chain's dofs;
- `structure_checks`: masses, time step, group sums and the convergence tests;
  `structure_explicit`, `structure_semi_implicit`, `structure_transient`: the integrators'
  stages in the grouped (CPU) and node-parallel (GPU) layouts; `structure_passes`: one-pass
  kernels (tie forces, gathered forces, energy, return map);
- `structure_variants`: the kernel variants built in this process (a cache per factory);
- `structure_relaxation`: the host side, `StructureRelaxation`.

Every `wp.func` is built per scalar type by a cached factory `functions(scalar, ...)`,
because Warp refuses to mix float32 literals with float64 values; friction and the boundary
couplings are compiled in only where the structure has them (`wp.static`).
"""
