"""Warp kernels of dynfab (installed as `dynfab.kernels`): nodal forces and time integrators."""
