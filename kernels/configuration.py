"""What selects a kernel variant, and the per-process cache of compiled variants.

A variant is one `Configuration`: terms (friction, gravity), load control,
precision, integrator and damping, mode. Kernels are built by factories with
`module="unique"` and `wp.static` branches, so a variant holds only the code it
uses; `cached` builds each (factory, configuration) once per process, and Warp's
kernel cache (~/.cache/warp) reloads its binary in milliseconds in later processes.
"""

import functools
from dataclasses import dataclass

from dynfab.kernels.precision import SCALARS

MODULE_OPTIONS = {"enable_backward": False}
"""Every kernel is forward-only: no adjoint code (compiles about 3x faster)."""


@dataclass(frozen=True, kw_only=True)
class Configuration:
    """One kernel variant (MODEL.md 5)."""

    precision: str = "float64"
    """"float64" or "float32"."""
    friction: bool = False
    """The scene has a [friction] table (Huber friction terms compiled in)."""
    gravity: bool = False
    """The scene has a [gravity] table."""
    control: str = "force"
    """"force" (end load compiled in) or "displacement" (x_N fixed)."""
    method: str = "explicit"
    """"explicit" (symplectic Euler) or "semi_implicit" (linearly implicit Euler)."""
    damping: str | None = "kinetic"
    """"kinetic", "viscous" or "fire" (explicit); None for semi_implicit, which has its own rule."""
    mode: str = "quasi_static"
    """"quasi_static" (relax each load step) or "transient"."""

    @property
    def scalar(self):
        """The Warp scalar type."""
        return SCALARS[self.precision]

    @property
    def force_control(self) -> bool:
        return self.control == "force"

    @property
    def terms(self) -> tuple:
        """Arguments of `dynfab.kernels.forces.functions` for this variant."""
        return (self.scalar, self.friction, self.gravity, self.force_control)


_COMPILED: dict = {}
"""(factory name, Configuration) -> kernel: every variant built in this process."""


def cached(factory):
    """Decorate a kernel factory `factory(configuration) -> wp.Kernel` to build each variant once."""

    @functools.wraps(factory)
    def kernel_for(configuration: Configuration):
        key = (f"{factory.__module__}.{factory.__qualname__}", configuration)
        if key not in _COMPILED:
            _COMPILED[key] = factory(configuration)
        return _COMPILED[key]

    return kernel_for


def built_variants() -> list:
    """The (factory name, Configuration) of every kernel variant built in this process."""
    return list(_COMPILED)
