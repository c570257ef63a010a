"""Linear algebra the models and solvers share, below both: the banded layout of a chain's
Hessian and its LU (`banded`), the banded LDL^T with its inertia (`ldlt`), MKL's PARDISO
through ctypes (`pardiso`)."""
