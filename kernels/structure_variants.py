"""The kernel variants of the structure layer this process has built (docs/model.md, "The dynamic
solver (decisions)").

Every kernel factory of the layer is cached (one variant per key, built once per process) and
registered here by `variant`: its kind ("explicit", "semi_implicit", "transient", "passes"),
layout ("grouped", "node_parallel"; "-" for the passes), scalar type, whether friction and the
boundary couplings are compiled in, and the grouped layout's force order. `built_variants`
lists them in the order they were built, so a report or a test can count the variants a run
added (each one a compile on a cold cache).
"""

import functools
from dataclasses import dataclass

import warp as wp


@dataclass(frozen=True)
class Variant:
    """One kernel variant (module docstring)."""

    kind: str
    layout: str
    precision: str
    friction: bool
    boundary: bool
    order: str = "-"

    @property
    def name(self) -> str:
        """The variant as one line: kind/layout/order/precision/couplings."""
        couplings = "+".join(name for name, on in (("friction", self.friction),
                                                    ("boundary", self.boundary)) if on)
        return (f"{self.kind}/{self.layout}/{self.order}/{self.precision}/"
                f"{couplings or 'no friction'}")


_BUILT: list[Variant] = []


def describe(kind: str, layout: str, scalar, friction: bool, boundary: bool,
             order: str | None = None) -> Variant:
    """The Variant of a factory's key (`variant`)."""
    precision = "float64" if scalar is wp.float64 else "float32"
    return Variant(kind, layout, precision, bool(friction), bool(boundary), order or "-")


def variant(kind: str, layout: str):
    """Decorator of a kernel factory f(scalar, friction, boundary[, order]): cached
    (functools.cache), each new key recorded as a `Variant`."""
    def wrap(factory):
        cached = functools.cache(factory)

        @functools.wraps(factory)
        def build(*key):
            misses = cached.cache_info().misses
            kernel = cached(*key)
            if cached.cache_info().misses > misses:
                _BUILT.append(describe(kind, layout, *key))
            return kernel

        build.cache_info = cached.cache_info
        return build

    return wrap


def built_variants() -> list[Variant]:
    """Every kernel variant built in this process, in the order they were built."""
    return list(_BUILT)
