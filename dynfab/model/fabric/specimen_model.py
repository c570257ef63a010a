"""An in-plane shear specimen's model side (docs/model.md section 11): the bias extension and
the picture frame of a plain weave in three dimensions, as a run drives them
(`dynfab.solvers.contract.RunModel`).

The load path is the clamp (frame corner) displacement d [m], preceded by a step 0 at d = 0
that relaxes the woven-in preload: its state is the reference of every reported angle and
displacement. Each step prescribes the held nodes (`dynfab.model.specimen_layout.held_positions`)
and starts the free ones along the last step's path tangent (`start_of_step`; the first
step after step 0 by the test's affine map): a better Newton start than the previous
state; the static solver's sparse backend solves it on the spatial terms
(`dynfab.model.fabric.spatial`).

Record of one step (n nodes, C crossings, L lateral contacts):

- load, end_displacement (1,): d [m]; end_force (1,) and clamp_force (): the force on the
  moved clamp (frame corner) along d [N], sum over the held nodes of the reaction dV/dr
  times d(r)/dd; clamp_force_from_step_0 (): the same less step 0's, the reaction of the
  relaxed woven state (what a load cell zeroed at the start of the test reads) [N];
  shear_force (): picture frame, F / (2 cos theta) [N] (Cao et al. eq. 3);
  normalised_shear_force (): F_s L / L_fabric^2 [N/m] (frame, eq. 10), for the bias
  extension Harrison's F_sh [N/m] (`dynfab.model.shear_force`, over the path so far; NaN once the
  path has turned back: it is defined on a curve in increasing d);
- positions (n, 3) [m]; crossing_positions (C, 3) [m] (the warp node's);
- shear_angle (C,) [rad]: gamma = asin(t_wa . t_we) - its value at step 0, t the unit
  in-plane chords over each crossing node's neighbours (`specimen_layout.shear_angles`);
  reference_angle (C,) [rad]: step 0's angle from the as-woven state;
- contact_force, friction_limit, sliding (C,); friction_force, anchors (C, 3) [N], [m, m,
  rad]; slip_ratio: the largest in-plane slip over the segment length [-];
- lateral_gap (L,) [m]: w - d of each lateral contact (positive where the yarns press);
  yarn_width (L,) [m]: the width the two yarns narrow to there, min(d, w); and
  fibre_volume_fraction (L,) [-]: their fibres' V0 w / min(d, w) (NaN for a family without
  Gutowski's compaction, docs/model.md 11.5);
- max_slope: the largest |e_z| / |e_xy| of any segment [-] (the small-slope model's check);
- dissipated, work [J]; energy/<term> [J]; the solver's fields.

A transient's frame (`frame`, docs/model.md section 11.12) holds time [s], positions,
velocities, force (n, 3), anchors (C, 3), contact_force (C,), load and end_displacement (1,),
clamp_force, shear_angle (C,) from the as-woven state, crossing_slip_ratio (C,), slip_ratio,
dissipated, energy/<term> and energy/kinetic.
"""

from __future__ import annotations

import functools

import numpy as np

from dynfab.model import specimen_layout
from dynfab.model.builders import woven_rest
from dynfab.model.builders.specimen import layout_of, specimen_structure
from dynfab.errors import SolverError
from dynfab.model.fabric import spatial
from dynfab.model.fabric.structure_now import StructureNow
from dynfab.model.loading import RELAXATION_STEPS, Drive, load_at_time
from dynfab.model.record_layout import RecordLayout
from dynfab.scene import Scene
from dynfab.model.shear_force import (bias_normalised_shear_force, frame_normalised_shear_force,
                                frame_shear_force)
from dynfab.model.state import State
from dynfab.model.step import StepSolution, StepStart
from dynfab.model.structure import chain_count, chain_of_node
from dynfab.model.terms.kinematics import physical_positions, woven_state

TRANSIENT_KNOTS = 64
"""Knots per interval of the load path at which a transient samples the held nodes'
positions (`SpecimenModel.transient_drive`): between knots the frame's turn is taken linear,
off its arc by at most h^2 / 8 max |x''| (h the knots' spacing), 1.6e-9 m for the 60 mm frame
sheared to 40 degrees (d = 23.9 mm) over 20 intervals (docs/model.md section 11.12)."""
SLIP_LIMIT = 0.5
"""The largest slip of a crossing over its segment length a step may end with
(docs/model.md section 11, slip bounds): a crossing is a fixed pair of nodes."""


class SpecimenModel(StructureNow):
    """A specimen scene as the solvers see it (module docstring)."""

    relaxation_steps = RELAXATION_STEPS["specimen"]
    """Steps before the scene's load path: step 0, the preload relaxed at d = 0."""
    @property
    def history_keys(self) -> tuple:
        """The columns of every finished step a resumed run gives `state_from_step` (`path`,
        and the last step's path tangent from the last two steps' positions; where the
        crossings slide, the departures to replay, `StructureNow`)."""
        return ("load", "clamp_force", "positions", *self.sliding_history)

    @property
    def singular_advice(self) -> str | None:
        """What a singular stiffness matrix's message advises (`dynfab.solvers.certificate`), None
        for the solver's own advice."""
        if not self.structure.has_friction:
            return ("without friction (alpha = beta = 0) nothing holds the specimen's two yarn "
                    "families together in its plane: give [friction] a law (docs/model.md "
                    "section 11)")
        return None  # the solver's own advice

    def __init__(self, scene: Scene):
        self.scene = scene
        self.layout = layout_of(scene)
        self.structure = specimen_structure(scene, self.layout)
        self._start_structures()
        self.control = "displacement"
        self.load_values = np.concatenate([[0.0], np.asarray(scene.load.values, float)])
        family = self.structure.chain_family[chain_of_node(self.structure)][
            self.structure.lateral_stencil[:, 2]]
        fractions = [getattr(t, "fibre_volume_fraction", None) for t in (scene.warp, scene.weft)]
        self._woven_fibre_fraction = np.array([np.nan if v is None else v
                                               for v in fractions])[family]
        """V0 of each lateral contact's family (L,), NaN without Gutowski's compaction."""
        self._held = np.flatnonzero(self.layout.held)

    @classmethod
    def from_scene(cls, scene: Scene) -> "SpecimenModel":
        return cls(scene)

    @functools.cached_property
    def record_layout(self) -> RecordLayout:
        """The result file's view of the flat arrays (`dynfab.model.record_layout`): the
        arrays themselves, nodes (n, 3) and crossings (C,)."""
        return RecordLayout(blocks=(), crossings=(self.woven_structure.tie_a.size,), dim=3,
                            anchor_columns=3)

    # ------------------------------------------------------------------ the run's view

    @property
    def test(self) -> str:
        return self.scene.specimen.test

    @property
    def groups(self) -> list[np.ndarray]:
        return [np.arange(chain_count(self.structure))]

    def group_name(self, k: int) -> str:
        return "specimen"

    def crossing_name(self, c: int) -> str:
        """Crossing c as "(warp k, weft j)" in lattice indices from the centre crossing."""
        k, j = self.layout.crossing_lattice[c]
        return f"(warp {int(k):+d}, weft {int(j):+d})"

    def yarn_name(self, y: int) -> str:
        family = "warp" if self.structure.chain_family[y] == 0 else "weft"
        return f"{family} {int(self.layout.chain_index[y]):+d}"

    @property
    def labels(self) -> list[str]:
        return [self.yarn_name(y) for y in range(chain_count(self.structure))]

    def step_load(self, index: int) -> float:
        """d of step `index` [m] (step 0: d = 0, the preload relaxed)."""
        return float(self.load_values[index])

    def attrs(self) -> dict:
        s = self.scene.specimen
        dims = ({"specimen_width": s.width, "specimen_height": s.height}
                if s.test == "bias_extension"
                else {"specimen_side": s.side, "fabric_side": s.fabric_side or s.side})
        return {"model": "specimen", "specimen_test": s.test, "kinematics": "spatial",
                "load_control": self.control, "yarn_labels": self.labels,
                "terms": list(self.terms.TERMS), "preload": self.scene.crossing.preload,
                "yarns_meet_at": self.yarns_meet_at, **dims}

    @property
    def yarns_meet_at(self) -> float:
        """The nominal shear angle [rad] at which neighbouring yarns first meet
        (`specimen_layout.yarns_meet_at`)."""
        return specimen_layout.yarns_meet_at(self.scene.warp, self.scene.weft)

    def reference(self) -> dict:
        """The as-woven nodes, the chains, the crossings, their zones and their rank from a
        free yarn end (`woven_rest.crossings_from_free_end`)."""
        L = self.layout
        rest = self.structure.rest_position
        return {"positions": rest, "chain_start": L.chain_start, "chain_family": L.chain_family,
                "crossing_nodes": L.crossing_nodes, "crossing_lattice": L.crossing_lattice,
                "crossing_positions": rest[L.crossing_nodes[:, 0], :2], "zone": L.zone,
                "interior": L.interior, "held": L.held,
                "free_end_rank": woven_rest.crossings_from_free_end(self.structure)}

    def initial_state(self) -> State:
        """As woven, every crossing in the structure: each slip anchor at zero slip (where the
        crossings slide, no slide), each rotation anchor at the woven angle."""
        self._set_structure(self.woven_structure, np.arange(self.woven_structure.tie_a.size))
        anchors = np.zeros((self.structure.tie_a.size, 3))
        anchors[:, 2] = self.structure.tie_rotation_law[:, spatial.PHI_REST]
        return State(woven_state(self.structure), anchors, dissipated=np.zeros(1),
                     load=np.zeros(1), end_force=np.zeros(1), path=np.zeros((0, 2)))

    def state_from_step(self, last: dict, history: dict) -> State:
        """The state after the last finished step; `history` the columns `history_keys` of
        every finished step."""
        path = np.column_stack([np.asarray(history["load"], float).reshape(-1),
                                np.asarray(history["clamp_force"], float).reshape(-1)])
        layout = self.record_layout
        positions, anchors = self.resumed(layout.flat_nodes("positions", last),
                                          layout.flat_anchors(last["anchors"], 3), last, history)
        return State(positions, anchors, np.array([last["dissipated"]], float),
                     np.array([np.ravel(last["load"])[0]], float),
                     np.array([last["clamp_force"]], float), float(last["work"]),
                     np.array(last["reference_angle"], float), path, self._last_tangent(history))

    def _last_tangent(self, history: dict) -> np.ndarray | None:
        """(r_n - r_n-1) / (d_n - d_n-1) of the last two finished steps' dofs, as
        `finish_step` computed it (the same bits: a resumed run starts its next step where the
        uninterrupted one did); None after step 0 alone or a step a yarn end left a crossing
        on, 0 where d did not move."""
        positions, d = history["positions"], np.asarray(history["load"], float).reshape(-1)
        if d.size < 2:
            return None
        last, before = (np.asarray(positions[k], float) for k in (-1, -2))
        if self.slides:
            present = np.asarray(history["crossing_present"], bool)
            if np.any(present[-1] != present[-2]):
                return None
            last, before = (self.with_slides(positions[k], history["slip"][k])
                            for k in (-1, -2))
        moved = d[-1] - d[-2]
        return (last - before) / moved if moved else np.zeros_like(last)

    def point_data(self, record: dict) -> dict:
        """The view's nodal data: the shear angle at each crossing's two nodes, 0 elsewhere."""
        angle = np.zeros(self.structure.rest_position.shape[0])
        gamma = np.asarray(record["shear_angle"])
        angle[self.layout.crossing_nodes[:, 0]] = gamma
        angle[self.layout.crossing_nodes[:, 1]] = gamma
        return {"xdmf/shear_angle": angle}

    def check_step(self, record: dict) -> None:
        """SolverError (exit 3) where a fixed crossing slid more than half a segment (a
        crossing that slides has no such bound)."""
        if self.slides:
            return
        ratio = np.asarray(record["crossing_slip_ratio"])
        if ratio.size and ratio.max() > SLIP_LIMIT:
            c = int(np.argmax(ratio))
            cause = self._slip_cause(record, c)
            raise SolverError(
                f"crossing {self.crossing_name(c)} slid {ratio[c]:.2f} of a segment (more than "
                f"{SLIP_LIMIT}): a crossing is a fixed pair of nodes, the model does not follow "
                f"a yarn through its crossings (docs/model.md section 11){cause}")

    def _slip_cause(self, record: dict, c: int) -> str:
        """What held crossing c: its friction limit F_T at its contact force and, with a
        rotation spring K, the in-plane force K |gamma| / p its couples need at a yarn's free
        end (|gamma| the largest shear angle, p the smaller spacing; docs/model.md 11.8)."""
        limit = float(np.asarray(record["friction_limit"])[c])
        text = (f"; its contact force {float(np.asarray(record['contact_force'])[c]):.3g} N "
                f"gives a friction limit F_T = {limit:.3g} N")
        crossing = self.scene.crossing
        K = (crossing.shear_stiffness or 0.0) if crossing is not None else 0.0
        gamma = float(np.max(np.abs(record["shear_angle"]), initial=0.0))
        p = min(self.scene.warp.spacing, self.scene.weft.spacing)
        if K > 0.0 and K * gamma / p > limit:
            text += (f", below the {K * gamma / p:.3g} N that the rotation springs' couples "
                     f"need at a free yarn end (shear_stiffness K = {K:g} N m/rad at "
                     f"{np.degrees(gamma):.1f} degrees: K gamma / p; docs/model.md 11.8): a "
                     "larger [friction] limit or a smaller K holds the specimen")
        return text

    def transient_drive(self) -> Drive:
        """The held nodes' displacements from the as-woven state along the transient's ramp of
        d (`dynfab.model.loading.Drive`, three rows per held node): d(t) through (0, 0) and
        the load values (step 0's d = 0 first: the preload relaxes at d = 0 for T / n),
        sampled at TRANSIENT_KNOTS knots per interval, the held nodes' positions exact there
        (`specimen_layout.held_positions`) and linear between (docs/model.md section 11.12)."""
        rest = self.structure.rest_position
        intervals = self.load_values.size
        knots = intervals * TRANSIENT_KNOTS
        d = np.interp(np.arange(1, knots + 1) / knots, np.linspace(0.0, 1.0, intervals + 1),
                      np.append(0.0, self.load_values))
        moved = np.stack([specimen_layout.held_positions(self.layout, rest, value)
                          - rest[self._held] for value in d], axis=-1)  # (H, 3, knots)
        first = np.full(rest.shape[0], -1)
        first[self._held] = 3 * np.arange(self._held.size)
        direction = np.zeros_like(rest)
        direction[self._held] = 1.0
        return Drive(moved.reshape(-1, knots), (first, direction))

    def frame(self, time: float, arrays: dict) -> dict:
        """A transient frame (`dynfab.solvers.contract.FRAME_KEYS`) at `time` [s] from the
        structure's flat arrays: positions, velocities, force (n, 3), anchors (C, 3), the
        contact forces (C,), d (`load`, `end_displacement`) of the ramp at `time`, the clamp
        force along d [N] (the held nodes' reaction, as a step's), each crossing's shear
        angle from the as-woven state [rad] and slip ratio [-], the energy of every reported
        term and the kinetic energy [J], and the dissipation so far [J] (docs/model.md
        section 11.12)."""
        f = self.structure
        pos = np.asarray(arrays["positions"], float)
        anchors = np.asarray(arrays["anchors"], float)
        d = load_at_time(self, time)
        limit = self.friction_limits(pos)
        R, clamp_force = self._forces(pos, anchors, limit, d)
        angle = (specimen_layout.shear_angles(self.layout, f.rest_position, pos)
                 - self._woven_angle)
        ratios = self.slip_ratios(pos)
        frame = {"time": float(time), **self.record_layout.frame_nodes(arrays), "anchors": anchors,
                 "contact_force": R, "load": np.array([d]), "end_displacement": np.array([d]),
                 "clamp_force": clamp_force,
                 "shear_angle": angle, "crossing_slip_ratio": ratios,
                 "slip_ratio": float(np.max(ratios, initial=0.0)),
                 "dissipated": float(np.sum(arrays["dissipated"]))}
        frame.update(self.energy_records(pos, np.zeros(chain_count(f)), anchors, limit))
        frame["energy/kinetic"] = float(np.sum(arrays["kinetic_energy"]))
        return {name: np.asarray(value) for name, value in frame.items()}

    def frame_arrays(self, frame: dict) -> dict:
        """A frame's positions, velocities, force (n, 3) and anchors (C, 3) as the structure's
        flat arrays, and its time: what a resumed transient restores."""
        return self.record_layout.frame_arrays(frame, 3)

    # ------------------------------------------------------------------ a load step

    def start_of_step(self, state: State, load) -> StepStart:
        """The held nodes at d = `load`; the free ones extrapolated from the previous state
        along the last step's path tangent (`State.path_tangent`), or where there is
        none (the step after step 0) moved by the test's affine map: a start near the
        solution. The secant halves the first Newton residual's and the line search's cuts
        on the bias specimens (docs/model.md section 11.10); the equilibrium reached is the
        step's whatever the start."""
        d, d_before = float(np.ravel(load)[0]), float(state.load[0])
        pos = state.positions.copy()
        rest = self.structure.rest_position
        tangent = state.path_tangent
        material = self.structure.tie_material.ravel()  # empty where crossings are fixed
        before = pos.reshape(-1)[material]
        if d != d_before and tangent is not None and np.any(tangent):
            pos += (d - d_before) * tangent
        elif d != d_before:
            pos += self._affine_increment(pos, d_before, d)
            pos.reshape(-1)[material] = before  # the map moves positions, not material
        pos[self._held] = specimen_layout.held_positions(self.layout, rest, d)
        held = self.structure.fixed[material]  # a held crossing's material stays
        pos.reshape(-1)[material[held]] = before[held]
        anchors = state.anchors.copy()
        if self.slides:
            anchors = self.terms.with_stretches(pos, self.structure, anchors)
        return StepStart(np.array([d]), pos, anchors, np.zeros(chain_count(self.structure)))

    def _affine_increment(self, pos, d_old: float, d_new: float) -> np.ndarray:
        """The displacement of every node from d_old to d_new under the test's homogeneous map:
        the frame's (bars' map applied to all), the bias extension's stretch along y."""
        L = self.layout
        if L.test == "picture_frame":
            side = self.scene.specimen.side
            old, new = (specimen_layout.frame_map(specimen_layout.frame_angle(side, d))
                        for d in (d_old, d_new))
            planar = pos[:, :2] @ np.linalg.inv(old).T @ new.T
            out = np.zeros_like(pos)
            out[:, :2] = planar - pos[:, :2]
            return out
        height = self.scene.specimen.height
        out = np.zeros_like(pos)
        out[:, 1] = (d_new - d_old) * self.structure.rest_position[:, 1] / height
        return out

    @functools.cached_property
    def _woven_angle(self) -> np.ndarray:
        """Each crossing's shear angle as woven (C,) [rad]: a frame's reference."""
        rest = self.structure.rest_position
        return specimen_layout.shear_angles(self.layout, rest, rest)

    def _forces(self, pos, anchors, limit, d: float) -> tuple[np.ndarray, float]:
        """(contact force R (C,) [N], the clamp force along d [N]) at `pos`, F_T = `limit`
        frozen: the held nodes' reaction dV/dr dotted with d(r)/dd, what a step and a frame
        record."""
        f = self.structure
        R = self.contact_forces(pos)
        grad = np.zeros_like(pos)
        self.terms.gradient(pos, f, np.zeros(chain_count(f)), anchors, limit, grad)
        velocity = specimen_layout.held_velocity(self.layout, f.rest_position, d)
        # a material coordinate's slot holds no position: its node moves as the one whose
        # coordinates it shares, whose dofs carry both nodes' reactions
        slots = np.zeros(pos.shape, bool)
        slots.reshape(-1)[f.tie_material.ravel()] = True
        velocity[slots[self._held]] = 0.0
        return R, float(np.sum(grad[self._held] * velocity))

    def finish_step(self, state: State, start: StepStart, solution: StepSolution):
        f, dofs, limit, terms = self.structure, solution.positions, solution.limit, self.terms
        d = float(start.load[0])
        anchors = start.anchors.copy()
        R, clamp_force = self._forces(dofs, anchors, limit, d)
        sliding, friction_force, lost = self.return_map(dofs, anchors, limit)
        energies = self.energy_records(dofs, np.zeros(chain_count(f)), anchors, limit)
        if self.slides:
            anchors = terms.state_anchors(anchors)
        pos = physical_positions(f, dofs)
        # gamma from the as-woven state; step 0's is the reference of the reported angles
        absolute = specimen_layout.shear_angles(self.layout, f.rest_position, pos)
        reference = absolute if state.reference_angle is None else state.reference_angle
        d_before, force_before = float(state.load[0]), float(state.end_force[0])
        work = state.work + 0.5 * (force_before + clamp_force) * (d - d_before)
        path = np.vstack([state.path, [d, clamp_force]])
        moved = d - d_before
        tangent = (dofs - state.positions) / moved if moved else np.zeros_like(dofs)
        record = {
            "load": np.array([d]), "end_displacement": np.array([d]),
            "end_force": np.array([clamp_force]), "clamp_force": clamp_force,
            "clamp_force_from_step_0": clamp_force - path[0, 1],
            **self.shear_forces(path),
            "positions": pos, "crossing_positions": pos[self.layout.crossing_nodes[:, 0]],
            "shear_angle": absolute - reference, "reference_angle": reference,
            **self.crossing_records(R, limit, sliding, friction_force, anchors),
            "crossing_slip_ratio": self.per_crossing(self.slip_ratios(pos)),
            **self.narrowing(pos), "max_slope": self.max_slope(pos),
            "crimp": self.crimps(pos), "dissipated": state.dissipated[0] + lost, "work": work,
            **{name: np.asarray(value)[0] for name, value in solution.fields.items()},
        }
        record["slip_ratio"] = float(np.max(record["crossing_slip_ratio"], initial=0.0))
        record.update(energies)
        if self.slides:
            dofs, gone = self.record_slides(dofs, record)
            if gone:  # the path's tangent is the old structure's: the next step starts afresh
                anchors, tangent = np.delete(anchors, gone, 0), None
        new = State(dofs, anchors, state.dissipated + lost, np.array([d]),
                    np.array([clamp_force]), work, reference, path, tangent)
        return new, {name: np.asarray(value) for name, value in record.items()}

    # ------------------------------------------------------------------ observables

    def shear_forces(self, path: np.ndarray) -> dict:
        """At the path's last point (d, F): the frame's shear force F_s = F / (2 cos theta)
        (Cao et al. eq. 3) and its normalisation F_s L / L_fabric^2 (eq. 10) [N], [N/m]; the
        bias extension's Harrison normalisation of its curve so far [N/m] (NaN once the path
        has turned back) (`dynfab.model.shear_force`)."""
        s = self.scene.specimen
        d, force = path[-1]
        if s.test == "picture_frame":
            return {"shear_force": frame_shear_force(force, s.side, d),
                    "normalised_shear_force": frame_normalised_shear_force(
                        force, s.side, s.fabric_side or s.side, d)}
        if np.any(np.diff(path[:, 0]) <= 0.0):
            return {"shear_force": np.nan, "normalised_shear_force": np.nan}
        normalised = bias_normalised_shear_force(path[:, 0], path[:, 1], s.width, s.height)
        return {"shear_force": np.nan, "normalised_shear_force": normalised[-1]}

    def slip_ratios(self, pos) -> np.ndarray:
        """|in-plane offset of each crossing's two nodes| over the shorter family's segment
        length (spacing / segments_per_spacing) (C,) [-]."""
        f, s = self.structure, self.scene
        segment = min(s.warp.spacing, s.weft.spacing) / s.specimen.segments_per_spacing
        return np.hypot(*(pos[f.tie_b, :2] - pos[f.tie_a, :2]).T) / segment

    def lateral_gaps(self, pos) -> np.ndarray:
        """w - d of each lateral contact (L,) [m] (`spatial.lateral_gaps`)."""
        out = np.zeros(self.structure.lateral_stencil.shape[0])
        spatial.lateral_gaps(pos, self.structure, out)
        return out

    def narrowing(self, pos) -> dict:
        """lateral_gap, yarn_width and fibre_volume_fraction of each lateral contact (module
        docstring; docs/model.md 11.5: the yarns narrow at constant thickness)."""
        gap = self.lateral_gaps(pos)
        width = self.structure.lateral_law[:, spatial.WIDTH] - np.maximum(gap, 0.0)
        woven = self._woven_fibre_fraction * self.structure.lateral_law[:, spatial.WIDTH]
        return {"lateral_gap": gap, "yarn_width": width, "fibre_volume_fraction": woven / width}

    def max_slope(self, pos) -> float:
        """The largest |e_z| / |e_xy| over every segment [-]."""
        start = self.structure.chain_start
        e = np.diff(pos, axis=0)
        keep = np.ones(e.shape[0], bool)
        keep[start[1:-1] - 1] = False  # no segment across two chains
        e = e[keep]
        return float(np.max(np.abs(e[:, 2]) / np.hypot(e[:, 0], e[:, 1]), initial=0.0))

    def crimps(self, pos) -> np.ndarray:
        """Mean crimp (warp, weft) [-]: (arc length - in-plane chord) / in-plane chord."""
        f = self.structure
        out = np.zeros(2)
        for family in (0, 1):
            arc = chord = 0.0
            for y in np.flatnonzero(f.chain_family == family):
                p = pos[f.chain_start[y]:f.chain_start[y + 1]]
                arc += np.linalg.norm(np.diff(p, axis=0), axis=1).sum()
                chord += np.hypot(*(p[-1, :2] - p[0, :2]))
            out[family] = arc / chord - 1.0 if chord > 0 else 0.0
        return out
