"""The discrete yarn model: a scene's parameters as arrays, and the solver state.

`build_model(scene)` turns a validated scene into a `Model`: one `Yarn` of
arrays per simulated warp yarn (a `[sweep]` entry or one of `geometry.yarns`
adjacent yarns, docs/model.md section 1) and the list of the energy terms the scene
uses. Nothing in a Model changes during a run; what changes is a `State`.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from dynfab import geometry
from dynfab.scene import Scene, expand_sweep, yarn_count
from dynfab.terms import registry
from dynfab.terms.friction import law_constants


class Yarn(NamedTuple):
    """Arrays of one warp yarn (docs/model.md sections 1-4); passed whole to numba.

    N segments, C crossings. Contact and friction arrays are empty when C = 0.
    """

    rest_position: np.ndarray
    """As-woven node positions r0 (N+1, 2) [m]."""
    rest_length: np.ndarray
    """Segment rest lengths l0 (N,) [m]."""
    stretch_stiffness: np.ndarray
    """EA / l0 per segment (N,) [N/m]."""
    bend_stiffness: np.ndarray
    """EI / lbar per node (N+1,) [N m]; 0 at the end nodes."""
    rest_angle: np.ndarray
    """Rest turning angles phi0 (N+1,) [rad]: as-woven, or 0 when prestressed."""
    mass: np.ndarray
    """Physical lumped masses rho_l lbar (N+1,) [kg]."""
    crossing_node: np.ndarray
    """Node index n_j of each crossing (C,) [-], int64."""
    crossing_side: np.ndarray
    """Side s_j of the weft the warp lies on (C,) [-], +1 above."""
    gap_offset: np.ndarray
    """c_j in the closure g_j = c_j - s_j z_{n_j} (C,) [m] (docs/model.md section 3)."""
    contact_law: np.ndarray
    """(k_s [N/m], C_wa [m], a_wa [1/N], C_we [m], a_we [1/N]) of the series law; k_s is the
    weft spring k_we in series with the core stiffness k_c when given (docs/model.md section 3)."""
    friction_alpha: float
    """Gralen alpha [-]; 0 without friction."""
    friction_constant: float
    """Gralen beta ell r_f [N]; 0 without friction."""
    friction_onset: float
    """R_0 [N], the contact force over which the limit's constant term sets in
    (docs/model.md section 4); 0: the literal jump law."""
    stick_stiffness: float
    """k_t [N/m]; 0 without friction."""
    gravity: float
    """g [m/s^2]; 0 without gravity."""
    active: np.ndarray
    """Which terms of `dynfab.terms.registry.TERMS` the yarn has, (len(TERMS),) bool in registry
    order (`registry.active_mask`); `dynfab.assembly` skips the others."""


TERMS = registry.NAMES
"""Every energy term of the model, in the order of `dynfab.terms.registry.TERMS`."""


@dataclass(frozen=True)
class Model:
    """A scene's yarns and the terms it uses; shared by the static and dynamic solvers."""

    scene: Scene
    yarns: tuple[Yarn, ...]
    terms: tuple[str, ...]
    """The active energy terms, a subset of TERMS in that order."""
    control: str
    """"force" or "displacement"."""
    load_values: np.ndarray
    """The load path (steps,) [N or m]."""

    @property
    def segments(self) -> int:
        return self.scene.geometry.segments

    @property
    def crossings(self) -> int:
        return self.scene.geometry.crossings

    @property
    def yarn_count(self) -> int:
        return len(self.yarns)

    @property
    def rest_end_x(self) -> np.ndarray:
        """x0_N of every yarn (yarns,) [m]."""
        return np.array([y.rest_position[-1, 0] for y in self.yarns])

    def stacked(self, field: str) -> np.ndarray:
        """A Yarn field stacked over yarns, shape (yarns, ...)."""
        return np.stack([np.asarray(getattr(y, field)) for y in self.yarns])

    def fixed_dofs(self) -> np.ndarray:
        """Fixed dofs (2 (N+1),) bool: node 0 pinned, z_N fixed, x_N under displacement control."""
        fixed = np.zeros(2 * (self.segments + 1), dtype=np.bool_)
        fixed[[0, 1, -1]] = True
        fixed[-2] = self.control == "displacement"
        return fixed


@dataclass
class State:
    """What changes during a run, for every yarn."""

    positions: np.ndarray
    """Node positions (yarns, N+1, 2) [m]."""
    anchors: np.ndarray
    """Friction anchors xi (yarns, C) [m] (docs/model.md section 4)."""
    dissipated: np.ndarray
    """Cumulative friction dissipation (yarns,) [J]."""
    load: np.ndarray
    """The load last applied (yarns,) [N or m]; 0 at the as-woven start."""

    def copy(self) -> "State":
        return State(self.positions.copy(), self.anchors.copy(), self.dissipated.copy(),
                     self.load.copy())


def initial_state(model: Model) -> State:
    """The as-woven geometry, anchors at the as-woven crossing positions, nothing dissipated."""
    positions = model.stacked("rest_position").copy()
    nodes = model.yarns[0].crossing_node
    return State(positions=positions, anchors=positions[:, nodes, 0].copy(),
                 dissipated=np.zeros(model.yarn_count), load=np.zeros(model.yarn_count))


def build_model(scene: Scene) -> Model:
    """The model of a validated scene: one Yarn per simulated warp yarn."""
    if scene.sweep:
        yarns = tuple(_build_yarn(s, phase=1.0) for s in expand_sweep(scene))
    else:
        yarns = tuple(_build_yarn(scene, phase=(-1.0) ** k) for k in range(yarn_count(scene)))
    return Model(scene=scene, yarns=yarns, terms=registry.active_terms(scene),
                 control=scene.load.control, load_values=np.asarray(scene.load.values, float))


def _build_yarn(scene: Scene, phase: float) -> Yarn:
    """Arrays of one yarn of phase s_k = +-1 (docs/model.md sections 1-4)."""
    geo, warp = scene.geometry, scene.warp
    rest = geometry.as_woven_positions(geo.length, geo.segments, geo.crossings, geo.amplitude, phase)
    rest_length = geometry.segment_lengths(rest)
    lbar = geometry.voronoi_lengths(rest_length)
    bend_stiffness = warp.EI / lbar
    bend_stiffness[[0, -1]] = 0.0
    if geo.reference == "prestressed":
        rest_angle = np.zeros(geo.segments + 1)
    else:
        rest_angle = geometry.turning_angles(rest)
    nodes = geometry.crossing_nodes(geo.segments, geo.crossings).astype(np.int64)
    sides = geometry.crossing_sides(geo.crossings, phase)
    friction = scene.friction
    stick = 0.0
    if friction is not None:
        stick = friction.stick_stiffness or warp.EA / (geo.length / geo.segments)
    alpha, constant, onset = law_constants(friction)  # Gralen, docs/model.md section 4
    return Yarn(
        rest_position=rest,
        rest_length=rest_length,
        stretch_stiffness=warp.EA / rest_length,
        bend_stiffness=bend_stiffness,
        rest_angle=rest_angle,
        mass=warp.linear_density * lbar,
        crossing_node=nodes,
        crossing_side=sides,
        gap_offset=_gap_offset(scene, rest, nodes, sides),
        contact_law=_contact_law(scene),
        friction_alpha=alpha, friction_constant=constant, friction_onset=onset,
        stick_stiffness=float(stick),
        gravity=float(scene.gravity.g) if scene.gravity else 0.0,
        active=registry.active_mask(scene),
    )


def _gap_offset(scene: Scene, rest: np.ndarray, nodes: np.ndarray, sides: np.ndarray) -> np.ndarray:
    """c_j of g_j = c_j - s_j z_{n_j} (docs/model.md section 3).

    as_woven: g_j = s_j (z0 - z), so c_j = s_j z0_{n_j} and every contact starts at g = 0;
    prestressed: g_j = A_wa + A_we - s_j z, the weft pre-deflected by its own amplitude.
    """
    if scene.geometry.crossings == 0:
        return np.zeros(0)
    if scene.geometry.reference == "prestressed":
        return np.full(nodes.size, scene.geometry.amplitude + scene.weft.amplitude)
    return sides * rest[nodes, 1]


def _contact_law(scene: Scene) -> np.ndarray:
    """(k_s, C_wa, a_wa, C_we, a_we), a_m = K_m / Lc_m (docs/model.md section 3, paper eqs. 4, 6-7).

    k_s = 1 / (1/k_we + 1/k_c): the weft spring in series with the core stiffness
    `contact.core_stiffness` when the scene gives one (else k_we). One more linear spring
    in series adds R/k_c to the law's left side and R^2/(2 k_c) to the energy, exactly
    what k_s does, so both solvers take it with no term of its own.
    """
    geo, weft = scene.geometry, scene.weft
    if geo.crossings == 0:
        return np.zeros(5)
    k_we = geometry.weft_stiffness(weft.EI, weft.length, weft.count, weft.tension)
    core = scene.contact.core_stiffness if scene.contact is not None else None
    if core is not None:
        k_we = 1.0 / (1.0 / k_we + 1.0 / core)
    lc_warp = geometry.half_wave_arc_length(geo.length / geo.crossings, geo.amplitude)
    lc_weft = geometry.half_wave_arc_length(weft.length / weft.count, weft.amplitude)
    return np.array([k_we, scene.warp.kawabata_C, scene.warp.kawabata_K / lc_warp,
                     weft.kawabata_C, weft.kawabata_K / lc_weft])


def crimp(positions: np.ndarray) -> np.ndarray:
    """(arc length - projected length) / projected length [-] of each yarn (yarns, N+1, 2)."""
    arc = np.hypot(*np.moveaxis(np.diff(positions, axis=-2), -1, 0)).sum(axis=-1)
    projected = positions[..., -1, 0] - positions[..., 0, 0]
    return (arc - projected) / projected


def width_per_yarn(scene: Scene) -> float | None:
    """Fabric width per warp yarn L_we / N_wa [m] (force per unit width is P / this); None for a rod."""
    if scene.weft is None:
        return None
    return scene.weft.length / scene.weft.count
