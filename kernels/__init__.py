"""Warp kernels of the dynamic solver (docs/model.md section 5), installed as `dynfab.kernels`.

One module per concept, mirroring `dynfab.terms` for the physics:

- `precision`: the scalar types (float64 by default, float32 on request);
- `yarn_arrays`, `motion`, `settings`: the Warp structs a kernel reads (a batch
  of yarns' Model arrays; the per-yarn time-integration state; the options);
- `stretch`, `bending`, `contact`, `friction`, `gravity`, `load`: each term's
  energy, gradient and banded Hessian (`wp.func`s with the same arguments in every
  term, in the sign convention of the numba twins in `dynfab.terms`: grad += dV/dr);
- `forces`: the totals, loops over the active terms (`Configuration.terms`, from the
  registry `dynfab.terms.registry`) unrolled with `wp.static`;
- `banded`: one yarn's banded matrix and its O(N) LU factorisation;
- `stability`: Gershgorin masses and stable time step;
- `relaxation`: start and convergence checks shared by the relaxation kernels;
- `kinetic_damping`, `viscous_damping`, `fire`: the explicit integrator's dampings;
- `explicit`, `semi_implicit`, `transient`: the time-stepping kernels, one
  thread per yarn with the time loop inside the kernel;
- `configuration`: what selects a kernel variant, and the per-process cache;
- `status`: the per-yarn outcome codes the kernels write;
- `diagnostics`: one term's energy, gradient and stiffness alone, for tests.

Every `wp.func` is built per scalar type by a cached factory `functions(scalar, ...)`,
because Warp refuses to mix float32 literals with float64 values.

The kernel layer for any `dynfab.structure.Structure`, meant to replace the one-yarn stack
above and the fabric's (`fabric_*`) once both solvers drive it (docs/model.md, the dynamic
solver's decisions):

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
- `structure_relaxation`: the host side, `StructureRelaxation`.
"""
