"""The kernel variants of the structure layer this process has built (docs/model.md, "The dynamic
solver (decisions)").

Every kernel factory of the layer is cached (one variant per key, built once per process) and
registered here by `variant`: its kind ("explicit", "semi_implicit", "transient", "passes"),
layout ("grouped", "node_parallel"; "-" for the passes), scalar type, whether friction and the
boundary couplings are compiled in, the grouped layout's force order and the kinematics
("planar", or "spatial": vec3 nodes and the spatial terms, docs/model.md section 11; the
element module it takes, `structure_forces.KINDS`). `built_variants` lists them in the order
they were built, so a report or a test can count the variants a run added (each one a compile
on a cold cache).
"""

import functools
from dataclasses import dataclass

import warp as wp

from dynfab.kernels import structure_arrays, structure_settings, structure_state


@dataclass(frozen=True)
class Variant:
    """One kernel variant (module docstring)."""

    kind: str
    layout: str
    precision: str
    friction: bool
    boundary: bool
    order: str = "-"
    kinematics: str = "planar"

    @property
    def name(self) -> str:
        """The variant as one line: kind/layout/order/precision/couplings/kinematics."""
        couplings = "+".join(name for name, on in (("friction", self.friction),
                                                    ("boundary", self.boundary)) if on)
        return (f"{self.kind}/{self.layout}/{self.order}/{self.precision}/"
                f"{couplings or 'no friction'}/{self.kinematics}")


_BUILT: list[Variant] = []


def describe(kind: str, layout: str, scalar, friction: bool, boundary: bool,
             order: str | None = None, kinematics: str = "planar") -> Variant:
    """The Variant of a factory's key (`variant`)."""
    precision = "float64" if scalar is wp.float64 else "float32"
    return Variant(kind, layout, precision, bool(friction), bool(boundary), order or "-",
                   kinematics)


def variant(kind: str, layout: str):
    """Decorator of a kernel factory f(scalar, friction, boundary[, order], kinematics=...):
    cached (functools.cache; `kinematics` always passed by keyword, so a default and an
    explicit "planar" are one key), each new key recorded as a `Variant` (every factory takes
    both kinematics)."""
    def wrap(factory):
        cached = functools.cache(factory)

        @functools.wraps(factory)
        def build(*key, kinematics: str = "planar"):
            misses = cached.cache_info().misses
            kernel = cached(*key, kinematics=kinematics)
            if cached.cache_info().misses > misses:
                _BUILT.append(describe(kind, layout, *key, kinematics=kinematics))
            return kernel

        build.cache_info = cached.cache_info
        return build

    return wrap


def built_variants() -> list[Variant]:
    """Every kernel variant built in this process, in the order they were built."""
    return list(_BUILT)


def structs(scalar, dim: int = 2) -> tuple:
    """The struct types a structure kernel takes, (`StructureData`, `StructureState`,
    `StructureSettings`), for `scalar` and `dim` coordinates per node."""
    return (structure_arrays.struct(scalar, dim), structure_state.struct(scalar, dim),
            structure_settings.struct(scalar))
