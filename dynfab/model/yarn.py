"""The discrete yarn model: a scene's parameters as arrays, and the solver state.

`build_model(scene)` turns a validated scene into a `Model`: one `Yarn` of
arrays per simulated warp yarn (a `[sweep]` entry or one of `geometry.yarns`
adjacent yarns, docs/model.md section 1) and the list of the energy terms the scene
uses. Nothing in a Model changes during a run; what changes is a `State`.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property
from typing import NamedTuple

import numpy as np

from dynfab.model.builders.yarn import width_per_yarn, yarn_structure
from dynfab.model.domain import check_not_folded
from dynfab.scene import Scene
from dynfab.model.loading import RELAXATION_STEPS, family_drive, prescribe_ends
from dynfab.model.observables import finish_step as observe_step
from dynfab.model.record_layout import RecordLayout
from dynfab.model.state import State, initial_state
from dynfab.model.step import StepSolution, StepStart
from dynfab.model.structure import Structure, chain_nodes, chain_segments, tie_layout, uniform
from dynfab.model.terms import registry


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
    """Which terms of `dynfab.model.terms.registry.TERMS` the yarn has, (len(TERMS),) bool in
    registry order (`registry.active_mask`); `dynfab.model.assembly` skips the others."""
    node_parameters: np.ndarray
    """The node terms' parameters of each node (N+1, P) (`Structure.node_parameters`)."""
    node_term_active: np.ndarray
    """Which node terms the yarn has (K,) bool (`Structure.node_term_active`)."""


TERMS = registry.NAMES
"""Every energy term of the model, in the order of `dynfab.model.terms.registry.TERMS`."""


@dataclass(frozen=True)
class Model:
    """A one-yarn scene's structure, its yarns as banded views, the terms it uses; shared by the
    static and dynamic solvers. It fulfils `dynfab.solvers.contract.RunModel`, as a fabric's model
    does."""

    relaxation_steps = RELAXATION_STEPS["yarn"]
    """Steps before the scene's load path: none."""
    history_keys = ()
    """No step dataset of the whole path is needed to resume (`state_from_step`)."""

    scene: Scene
    structure: Structure
    """The scene's chains and ties to ground (`dynfab.model.builders.yarn`)."""
    yarns: tuple[Yarn, ...]
    terms: tuple[str, ...]
    """The active energy terms, a subset of TERMS in that order."""
    control: str
    """"force" or "displacement"."""
    load_values: np.ndarray
    """The load path (steps,) [N or m]."""
    width_per_yarn: float | None
    """The fabric width per yarn [m] the stresses are per (`dynfab.model.builders.yarn`); None
    for a rod."""

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

    @cached_property
    def crossing_rest_x(self) -> np.ndarray:
        """(yarns, crossings) x0 [m] of each yarn's crossing nodes: where the weft's plane
        stays (the slip ratio's reference, `dynfab.model.observables`)."""
        return self.stacked("rest_position")[:, self.yarns[0].crossing_node, 0]

    @cached_property
    def record_layout(self) -> RecordLayout:
        """The result file's view of the flat arrays (`dynfab.model.record_layout`): nodes
        (yarns, N+1, 2), crossings (yarns, C), of each anchor its slip alone."""
        return RecordLayout(blocks=(("", self.yarn_count, self.segments + 1),),
                            crossings=(self.yarn_count, self.crossings), dim=2,
                            anchor_columns=1)

    def stacked(self, field: str) -> np.ndarray:
        """A Yarn field stacked over yarns, shape (yarns, ...)."""
        return np.stack([np.asarray(getattr(y, field)) for y in self.yarns])

    @property
    def labels(self) -> list[str]:
        """One label per simulated yarn: its sweep entry, or its index and phase s_k."""
        scene = self.scene
        if scene.sweep:
            return [", ".join(f"{key}={values[i]:g}" for key, values in scene.sweep)
                    for i in range(self.yarn_count)]
        return [f"yarn {k + 1} (s={'+' if k % 2 == 0 else '-'}1)" for k in range(self.yarn_count)]

    def step_load(self, index: int) -> float:
        """The load of step `index` of the path [N or m]: what `Solver.step` takes."""
        return float(self.load_values[index])

    def attrs(self) -> dict:
        """Root attributes of the model's result file besides the run's and the solver's."""
        scene = self.scene
        attrs = {"projected_length": scene.geometry.length,
                 "reference_state": scene.geometry.reference, "yarn_labels": self.labels,
                 "terms": list(self.terms)}
        if self.width_per_yarn is not None:
            attrs["width_per_yarn"] = self.width_per_yarn
        return attrs

    def reference(self) -> dict:
        """The result file's `reference/`: the yarns as woven, the crossing nodes."""
        return {"positions": self.stacked("rest_position"),
                "crossing_nodes": self.yarns[0].crossing_node}

    def initial_state(self) -> "State":
        """The as-woven start (`initial_state`)."""
        return initial_state(self)

    def state_from_step(self, last: dict, history: dict | None = None) -> "State":
        """The state a finished step left (a resumed run continues from it)."""
        layout = self.record_layout
        return State(positions=layout.flat_nodes("positions", last),
                     anchors=layout.flat_anchors(last["anchors"], 2),
                     dissipated=np.array(last["dissipated"], float),
                     load=np.array(last["load"], float),
                     end_force=np.array(last["end_force"], float))

    def per_yarn(self, values) -> np.ndarray:
        """The structure's per-node `values` (n, ...) as the yarns' (yarns, N+1, ...): a view."""
        return self.record_layout.blocks_of(values)[0]

    def per_crossing(self, anchors) -> np.ndarray:
        """A state's anchors (T, 2) as the yarns' slip anchors (yarns, C) [m], a contiguous
        copy of column 0 (tie t is crossing t mod C of yarn t // C, `crossing_name`)."""
        return self.record_layout.anchors(anchors)

    def point_data(self, entry: dict) -> dict:
        """A step's (or frame's) point data of the XDMF view (`dynfab.results.xdmf`) on every
        node: R [N] and slip x - anchor [m] at the crossing nodes, 0 elsewhere; keys
        ``xdmf/contact_force``, ``xdmf/slip``, (yarns, N+1)."""
        positions = np.asarray(entry["positions"])
        crossing_nodes = self.yarns[0].crossing_node
        force, slip = np.zeros(positions.shape[:2]), np.zeros(positions.shape[:2])
        if len(crossing_nodes):
            force[:, crossing_nodes] = np.asarray(entry["contact_force"])
            slip[:, crossing_nodes] = positions[:, crossing_nodes, 0] - np.asarray(entry["anchors"])
        return {"xdmf/contact_force": force, "xdmf/slip": slip}

    @property
    def groups(self) -> list[np.ndarray]:
        """The structure's independent groups of chains: each yarn is one."""
        return [np.array([k]) for k in range(self.yarn_count)]

    def group_name(self, k: int) -> str:
        """Group k (0-based) as messages name it: "yarn k+1"."""
        return f"yarn {k + 1}"

    def frame(self, time: float, arrays: dict) -> dict:
        """A transient frame (`dynfab.solvers.contract.FRAME_KEYS`) at `time` [s] from the
        structure's flat arrays (`StructureRelaxation.transient`'s: positions, velocities,
        force (n, 2), anchors (T, 2), kinetic_energy per group): per yarn, the contact forces
        and the energies of every reported term at the load of that time
        (`dynfab.model.loading.load_at_time`), and the kinetic energy (docs/model.md section 5)."""
        from dynfab.model.loading import load_at_time
        from dynfab.model.observables import frame_observables

        layout = self.record_layout
        frame = {"time": float(time), **layout.frame_nodes(arrays)}
        frame["anchors"] = layout.anchors(arrays["anchors"])
        positions, anchors = frame["positions"], frame["anchors"]
        frame.update(frame_observables(self, positions, anchors, load_at_time(self, time)))
        frame["energy/kinetic"] = np.asarray(arrays["kinetic_energy"], float)
        return frame

    def transient_drive(self):
        """The transient's drive (`dynfab.model.loading.family_drive`): one row per family."""
        return family_drive(self)

    def frame_arrays(self, frame: dict) -> dict:
        """A frame's (`frame`) positions, velocities, force (n, 2) and anchors (T, 2) as the
        structure's flat arrays: what a resumed transient restores."""
        return self.record_layout.frame_arrays(frame, 2)

    def crossing_name(self, t: int) -> str:
        """Tie t of the structure as a message names it: "j (node n)", its crossing's number
        along its yarn (1-based) and node, with "of yarn k" where there are several."""
        crossings = self.yarns[0].crossing_node.size
        k, j = divmod(int(t), crossings)
        node = int(self.yarns[k].crossing_node[j])
        return f"{j + 1} (node {node})" + (f" of yarn {k + 1}" if self.yarn_count > 1 else "")

    def start_of_step(self, state: "State", load) -> StepStart:
        """Where the step to `load` [N or m] starts (`dynfab.model.loading.prescribe_ends`), as the
        structure's flat arrays (`dynfab.model.step.StepStart`): the anchors are the slips' (column
        0; a tie to ground has no second), the end forces the load under force control."""
        value = float(load)
        positions, loads = state.positions.copy(), np.full(self.yarn_count, value)
        if self.control != "force":
            prescribe_ends(self.structure, positions, loads)
            loads = np.zeros(self.yarn_count)
        return StepStart(np.asarray(value), positions, state.anchors.copy(), loads)

    def finish_step(self, state: "State", start: StepStart, solution: StepSolution):
        """(new state, record) of the step `start` began, from the solver's `solution`
        (`dynfab.solvers.contract.RunModel.finish_step`): the return map and the observables of
        `dynfab.model.observables.finish_step`, and the solver's fields, one per yarn."""
        positions = self.per_yarn(solution.positions)
        fields = solution.fields
        new_state, record = observe_step(self, state, positions, float(start.load),
                                        fields["residual"], fields["iterations"])
        record.update({name: np.asarray(value) for name, value in fields.items()
                       if name not in ("residual", "iterations")})
        return new_state, record

    def check_step(self, record: dict) -> None:
        """SolverError if the step left the model's domain: a yarn folded back
        (`dynfab.model.domain.check_not_folded`)."""
        check_not_folded([record["positions"]], lambda: self.labels)  # labels made on a fold

    def fixed_dofs(self) -> np.ndarray:
        """Fixed dofs (2 (N+1),) bool: node 0 pinned, z_N fixed, x_N under displacement control."""
        fixed = np.zeros(2 * (self.segments + 1), dtype=np.bool_)
        fixed[[0, 1, -1]] = True
        fixed[-2] = self.control == "displacement"
        return fixed


def yarn_model(scene: Scene) -> Model:
    """The one-yarn model of a validated scene: its structure (`dynfab.model.builders.yarn`)
    with one Yarn view per simulated warp yarn."""
    structure = yarn_structure(scene)
    yarns = tuple(chain_view(structure, k, registry.active_mask(scene))
                  for k in range(structure.chain_start.size - 1))
    return Model(scene=scene, structure=structure, yarns=yarns,
                 terms=registry.active_terms(scene),
                 control=scene.load.control, load_values=np.asarray(scene.load.values, float),
                 width_per_yarn=width_per_yarn(scene))


def chain_view(structure: Structure, y: int, active: np.ndarray) -> Yarn:
    """Chain y of a structure whose ties are grounded (`dynfab.model.structure.grounded`), as the
    banded solvers' Yarn: views of its arrays, its ties' laws (one per chain)."""
    nodes, segments = chain_nodes(structure, y), chain_segments(structure, y)
    ties, crossing_node = tie_layout(structure, y)
    friction = uniform(structure.tie_friction_law[ties])
    gravity = structure.gravity[nodes]
    return Yarn(
        rest_position=structure.rest_position[nodes],
        rest_length=structure.rest_length[segments],
        stretch_stiffness=structure.stretch_stiffness[segments],
        bend_stiffness=structure.bend_stiffness[nodes],
        rest_angle=structure.rest_angle[nodes],
        mass=structure.mass[nodes],
        crossing_node=crossing_node,
        crossing_side=structure.tie_side[ties],
        gap_offset=structure.tie_gap_offset[ties],
        contact_law=uniform(structure.tie_contact_law[ties]) if ties.size else np.zeros(5),
        friction_alpha=float(friction[0]), friction_constant=float(friction[1]),
        friction_onset=float(friction[2]), stick_stiffness=float(friction[3]),
        gravity=float(gravity[0]) if gravity.size else 0.0,
        active=active,
        node_parameters=structure.node_parameters[nodes] if structure.node_parameters.size
        else np.zeros((nodes.stop - nodes.start, 0)),
        node_term_active=structure.node_term_active,
    )
