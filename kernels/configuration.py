"""What selects a kernel variant, and the per-process cache of compiled variants.

A variant is one `Configuration`: the active terms (`dynfab.model.Model.terms`,
from the registry `dynfab.terms.registry`), precision, integrator and damping, mode.
Kernels are built by factories with `module="unique"`, `wp.static` branches and
loops over the terms, so a variant holds only the code it uses; `cached` builds each
(factory, configuration) once per process, and Warp's kernel cache (~/.cache/warp)
reloads its binary in milliseconds in later processes.
"""

import functools
from dataclasses import dataclass

from dynfab.kernels.precision import SCALARS
from dynfab.terms import registry

MODULE_OPTIONS = {"enable_backward": False}
"""Every kernel is forward-only: no adjoint code to generate and compile."""
ALWAYS_COMPILED = ("contact",)
"""Terms compiled into every variant, active or not. A scene without crossings has no contact
term (`registry.TERMS`), but the contact code loops over its C = 0 crossings and does nothing;
a variant of its own would cost a compile (tens of seconds) to save nothing at run time."""


@dataclass(frozen=True, kw_only=True)
class Configuration:
    """One kernel variant (docs/model.md section 5)."""

    precision: str = "float64"
    """"float64" or "float32"."""
    terms: tuple[str, ...] = ("stretch", "bending", "contact", "load")
    """The active terms (`dynfab.model.Model.terms`): only their code is compiled (and that of
    ALWAYS_COMPILED). Kept in registry order whatever order they are given in, so equal
    selections are equal variants. "load" (the end load) is the term of force control;
    without it x_N is fixed (displacement control, docs/model.md section 1)."""
    method: str = "explicit"
    """"explicit" (symplectic Euler) or "semi_implicit" (linearly implicit Euler)."""
    damping: str | None = "kinetic"
    """"kinetic", "viscous" or "fire" (explicit); None for semi_implicit, which has its own rule."""
    mode: str = "quasi_static"
    """"quasi_static" (relax each load step) or "transient"."""

    def __post_init__(self):
        """Refuse an unknown term name; add ALWAYS_COMPILED; put the terms in registry order."""
        unknown = set(self.terms) - set(registry.NAMES)
        if unknown:
            raise ValueError(f"unknown terms {sorted(unknown)}; the terms are {registry.NAMES}")
        compiled = set(self.terms) | set(ALWAYS_COMPILED)
        object.__setattr__(self, "terms", tuple(n for n in registry.NAMES if n in compiled))

    @property
    def scalar(self):
        """The Warp scalar type."""
        return SCALARS[self.precision]

    @property
    def force_control(self) -> bool:
        """The end load is a term (force control); otherwise x_N is prescribed."""
        return "load" in self.terms

    @property
    def control(self) -> str:
        """"force" or "displacement"."""
        return "force" if self.force_control else "displacement"

    @property
    def friction(self) -> bool:
        """The Huber friction term is compiled in."""
        return "friction" in self.terms

    @property
    def gravity(self) -> bool:
        """The gravity term is compiled in."""
        return "gravity" in self.terms


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
