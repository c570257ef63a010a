"""The woven fabric's model side (docs/model.md section 10): what both fabric solvers share
and neither owns.

- `FabricModel`: a fabric scene as the solvers see it, its structure
  (`dynfab.model.builders.fabric`), yarn families and load path, and the model's own functions of a
  state: the sparse Hessian with F_T frozen (`dynfab.model.fabric.assembly`, on the unknowns of its
  `Pattern`) that the Newton solve and the certificate (`dynfab.solvers.certificate`) both factor;
  the load a step prescribes at its start (`start_of_step`) and the state it ends in (`end_of_step`:
  the end displacements, the loads' work, the dissipation); and the observables of a record:
  strains, crimps, stresses per unit width, the loaded families, the widths per yarn, the
  planes, the energy terms.

The static solver (`dynfab.solvers.static`, its sparse backend) and the dynamic one of every model
(`dynfab.solvers.dynamic`) import this module, never each other (`dynfab.solvers.contract`); each
solves a step from `FabricModel.start_of_step` and hands its solution to `FabricModel.finish_step`,
which makes the state and the record (`dynfab.model.step`).

Record of one fabric step (n_wa warps of N+1 nodes, n_we wefts of M+1 nodes; Y = n_wa
+ n_we yarns, warps first):

- load (2,): (warp, weft) value [N or m]; end_force, end_displacement (Y,) [N], [m];
- positions (n_wa, N+1, 2): the warps' (x, z); weft_positions (n_we, M+1, 2): the
  wefts' (y, z) [m];
- strain, crimp (2,): (warp, weft) nominal strain and mean crimp [-]; stress (2,):
  (warp, weft) load per unit width [N/m] (`FabricModel.stresses`);
- slip_ratio: the largest slip ratio of the step's crossing nodes [-]
  (`dynfab.model.domain.slip_ratios`; a run stops a step above 1/2, docs/model.md section 10;
  0 where the crossings slide, their nodes staying on the planes);
- where the crossings slide (`crossing.motion = "sliding"`, docs/model.md 11.13): slip
  (n_wa, n_we, 2): each crossing's total slide along the warp and along the weft [m], its
  material coordinates' change since the as-woven state (what its slots hold); material
  (n_wa, n_we, 2): those material coordinates [m]; the anchors are then slides [m];
- contact_force, friction_limit, sliding (n_wa, n_we); friction_force, anchors
  (n_wa, n_we, 2) [N], [m] (in-plane: warp x, weft y; the anchors relative to the planes);
- warp_planes (n_wa,): the plane y = Y_k of each warp, weft_planes (n_we,): x = X_j of each
  weft [m], where they are at the step's end (they move with "affine" planes and on the
  periodic cell, docs/model.md section 10);
- dissipated, work [J]; energy/<term> [J] per active term of the registry
  (`dynfab.model.terms.registry`, its dataset names and order, as the one-yarn model's);
- residual [N], iterations, friction_solves, rounding_floor; the certificate
  (`dynfab.solvers.certificate.StepStability`, docs/model.md section 6): stable, buckled (an escape
  from a saddle was taken), lowest_eigenvalue [N/m] (the lowest eigenvalue of the
  frozen-F_T Hessian on the unknowns), lowest_eigenvalue_error [N/m] (lambda_min lies in
  [lowest_eigenvalue - error, lowest_eigenvalue]), error_estimate [m] (residual x est
  ||H^-1||_inf, the position error bound the accuracy check holds to static.accuracy or
  dynamic.accuracy of the step's largest displacement), negative_eigenvalues; scalars;
- with the dynamic solver, time_steps (the time steps of the step's relaxations, also its
  iterations), and with the semi-implicit method cg_iterations (their CG iterations).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np

from dynfab.model.builders.fabric import Family, families, fabric_structure
from dynfab.model.domain import check_crossings_held, check_not_folded, fabric_slip_ratios
from dynfab.model.fabric.assembly import planes as plane_positions
from dynfab.model.geometry import crimp
from dynfab.model.loading import RELAXATION_STEPS, family_drive, load_at_time, prescribe_ends
from dynfab.model.record_layout import RecordLayout
from dynfab.scene import Scene
from dynfab.model.state import State, as_woven_state
from dynfab.model.step import StepSolution, StepStart
from dynfab.model.structure import Structure, chain_count
from dynfab.model.terms import registry
from dynfab.model.fabric.structure_now import StructureNow
from dynfab.model.terms.kinematics import physical_positions


@dataclass
class FabricModel(StructureNow):
    """A fabric scene as the solvers see it: its structure (`dynfab.model.builders.fabric`), its
    yarn families and its load path (docs/model.md section 10)."""

    relaxation_steps = RELAXATION_STEPS["fabric"]
    """Steps before the scene's load path: none."""

    scene: Scene
    structure: Structure
    """The structure now: where a yarn end leaves a sliding crossing, without that crossing's
    tie from the step it left on (`woven_structure` the one the scene made)."""
    warp: Family
    weft: Family

    def __post_init__(self):
        self._start_structures()  # the crossing of tie t is tie_crossing[t] = k n_we + j

    @property
    def history_keys(self) -> tuple:
        """The step datasets of the whole path `state_from_step` needs to resume: where the
        crossings slide, which were present and their slides at each step
        (the steps a yarn end left one, replayed); none otherwise."""
        return self.sliding_history

    @classmethod
    def from_scene(cls, scene: Scene, structure: Structure | None = None) -> "FabricModel":
        """The model of a validated fabric scene; `structure` replaces the scene's own (a test
        holding more dofs, say)."""
        warp, weft = families(scene)
        return cls(scene, fabric_structure(scene) if structure is None else structure, warp,
                   weft)

    @property
    def warps(self) -> int:
        return self.warp.count

    @property
    def wefts(self) -> int:
        return self.weft.count

    @property
    def control(self) -> str:
        return self.scene.load.control

    @property
    def pullout(self) -> int | None:
        """The pulled warp (1-based), or None."""
        return None if self.scene.pullout is None else self.scene.pullout.warp

    @property
    def load_values(self) -> np.ndarray:
        """The load path (steps, 2): (warp value, weft value) per step [N or m]."""
        load = self.scene.load
        weft = load.weft_values if load.weft_values is not None else (0.0,) * len(load.values)
        return np.column_stack([load.values, weft]).astype(float)

    @cached_property
    def record_layout(self) -> RecordLayout:
        """The result file's view of the flat arrays (`dynfab.model.record_layout`): the
        warps' nodes (n_wa, N+1, 2), the wefts' as weft_<name> (n_we, M+1, 2), the crossings
        (n_wa, n_we)."""
        return RecordLayout(blocks=(("", self.warps, self.warp.segments + 1),
                                    ("weft_", self.wefts, self.weft.segments + 1)),
                            crossings=(self.warps, self.wefts), dim=2, anchor_columns=2)

    def reference(self) -> dict:
        """The result file's `reference/`: both families as woven, the crossing nodes."""
        nodes, weft_nodes = self.crossing_nodes()
        return {**self.record_layout.nodes("positions", self.structure.rest_position),
                "crossing_nodes": nodes, "weft_crossing_nodes": weft_nodes}

    def crossing_nodes(self) -> tuple[np.ndarray, np.ndarray]:
        """(each warp's node of crossing j (n_we,), each weft's node of crossing k (n_wa,)):
        (2j-1) N / (2 n_we) and (2k-1) M / (2 n_wa) (docs/model.md section 10)."""
        return ((2 * np.arange(self.wefts) + 1) * self.warp.segments // (2 * self.wefts),
                (2 * np.arange(self.warps) + 1) * self.weft.segments // (2 * self.warps))

    @property
    def labels(self) -> list[str]:
        """One label per yarn, warps first."""
        return ([f"warp {k + 1}" for k in range(self.warps)]
                + [f"weft {j + 1}" for j in range(self.wefts)])

    def step_load(self, index: int) -> np.ndarray:
        """The load of step `index` of the path, (warp value, weft value) [N or m]: what
        the fabric solvers take."""
        return self.load_values[index]

    def check_step(self, record: dict) -> None:
        """SolverError if the step left the model's domain: a yarn folded back
        (`dynfab.model.domain.check_not_folded`), or a crossing node carried more than half a
        segment from its crossing (`dynfab.model.domain.check_crossings_held`); for every solver."""
        check_not_folded([record["positions"], record["weft_positions"]],
                         lambda: self.labels)  # labels made only for the message
        if self.slides:  # the crossings follow the yarns: no bound on their slips
            return
        g = self.scene.geometry
        check_crossings_held(record, *self.crossing_nodes(), suggest_affine=(
            g.boundary == "clamped" and g.planes == "fixed" and self.pullout is None))

    def attrs(self) -> dict:
        """Root attributes of a fabric's result file besides the solver's."""
        scene = self.scene
        return {"model": "fabric", "boundary": scene.geometry.boundary,
                "planes": scene.geometry.planes,
                "projected_length": self.warp.length, "weft_length": self.weft.length,
                "width_per_yarn": self.weft.length / self.warps,
                "length_per_weft": self.warp.length / self.wefts,
                "reference_state": scene.geometry.reference, "load_control": self.control,
                "yarn_labels": self.labels,
                "terms": list(registry.active_terms(scene)), **({} if self.pullout is None
                                          else {"pullout_warp": int(self.pullout)})}

    def initial_state(self) -> State:
        """As woven, anchors at zero slip, nothing dissipated (`as_woven_state`), every
        crossing in the structure, at zero load (so that a first step of crossings that slide
        can be solved in halves, `dynfab.solvers.contract.step_in_halves`)."""
        self._set_structure(self.woven_structure, np.arange(self.woven_structure.tie_a.size))
        return as_woven_state(self.structure, load=np.zeros_like(self.step_load(0)))

    def state_from_step(self, last: dict, history: dict | None = None) -> State:
        """The state a finished step left (a resumed run continues from it): its positions,
        where the crossings slide the structure after the departures of `history`
        (`replay_departures`) and the crossings' slides (`slip`) in their slots."""
        layout = self.record_layout
        nodes, anchors = self.resumed(layout.flat_nodes("positions", last),
                                      layout.flat_anchors(last["anchors"], 2), last, history)
        return State(nodes, anchors, np.array([last["dissipated"]], float),
                     np.array(last["load"], float), np.array(last["end_force"], float),
                     float(last["work"]))

    @property
    def planes_move(self) -> bool:
        """The planes X_j, Y_k follow the ends ("affine" planes, the periodic cell)."""
        return bool(self.structure.plane_nodes_a.size or self.structure.plane_nodes_b.size)

    def point_data(self, record: dict) -> dict:
        """The XDMF view's nodal point data of a step (`dynfab.results.xdmf`): contact force and
        the slip s (docs/model.md (10.7): in-plane coordinate - plane - anchor) at each
        family's crossing nodes, 0 elsewhere; where the planes move, each node's plane
        coordinate (`xdmf/plane`: the warps' y, `xdmf/weft_plane`: the wefts' x), which the
        view draws them at."""
        ref = self.reference()
        R = np.asarray(record["contact_force"])
        anchors = np.asarray(record["anchors"])
        warp_planes = np.asarray(record["warp_planes"])
        weft_planes = np.asarray(record["weft_planes"])
        out = {}
        for prefix, positions, nodes, force, anchor, crossed, own in (
                ("", record["positions"], ref["crossing_nodes"], R, anchors[..., 0],
                 weft_planes[None, :], warp_planes),
                ("weft_", record["weft_positions"], ref["weft_crossing_nodes"], R.T,
                 anchors[..., 1].T, warp_planes[None, :], weft_planes)):
            positions = np.asarray(positions)
            f, slip = np.zeros(positions.shape[:2]), np.zeros(positions.shape[:2])
            f[:, nodes] = force
            slip[:, nodes] = positions[:, nodes, 0] - crossed - anchor
            if self.slides:  # the slide of the material through the crossing
                slide = np.asarray(record["slip"])[..., 0 if prefix == "" else 1]
                slip[:, nodes] = slide if prefix == "" else slide.T
            out[f"xdmf/{prefix}contact_force"], out[f"xdmf/{prefix}slip"] = f, slip
            if self.planes_move:
                out[f"xdmf/{prefix}plane"] = np.repeat(own[:, None], positions.shape[1], axis=1)
        return out

    # ------------------------------------------------------------------ the Hessian

    # ------------------------------------------------------------------ a load step

    @property
    def yarns(self) -> int:
        """Warps and wefts, Y."""
        return chain_count(self.structure)

    def yarn_loads(self, warp_value: float, weft_value: float) -> np.ndarray:
        """The load of each yarn (Y,) [N or m]: the family's value times its factor."""
        f = self.structure
        return np.where(f.chain_family == 0, warp_value, weft_value) * f.load_factor

    def start_of_step(self, state: State, load) -> StepStart:
        """Where the step to `load` = (warp value, weft value) starts
        (`dynfab.model.step.StepStart`), copies of the state's arrays: under force control the end
        forces are each yarn's load; under displacement control they are 0 and the ends are moved to
        their prescribed displacements (`dynfab.model.loading.prescribe_ends`). Where the
        crossings slide the anchors carry the yarns' stretches at each crossing beside them,
        what the step's friction measures its slips with
        (`dynfab.model.fabric.sliding.with_stretches`)."""
        warp_value, weft_value = (float(v) for v in load)
        loads = self.yarn_loads(warp_value, weft_value)
        pos, anchors = state.positions.copy(), state.anchors.copy()
        if self.slides:
            anchors = self.terms.with_stretches(pos, self.structure, anchors)
        if self.control != "force":
            prescribe_ends(self.structure, pos, loads)
            loads = np.zeros(self.yarns)
        return StepStart(np.array([warp_value, weft_value]), pos, anchors, loads)

    @property
    def groups(self) -> list[np.ndarray]:
        """The structure's independent groups of chains: a patch or a cell is one."""
        return [np.arange(self.yarns)]

    def group_name(self, k: int) -> str:
        """The patch (the one group) as messages name it: "fabric"."""
        return "fabric"

    def frame(self, time: float, arrays: dict) -> dict:
        """A transient frame (`dynfab.solvers.contract.FRAME_KEYS` in the record's layout: the
        warps' positions, velocities and force, the wefts' as weft_positions, weft_velocities,
        weft_force; contact_force (n_wa, n_we), anchors (n_wa, n_we, 2), the planes, the
        energy of every active term and the kinetic energy [J], scalars) at `time` [s] from
        the structure's flat arrays (`dynfab.solvers.contract.RunModel.frame`); the loads are those
        of the ramp at `time` (`dynfab.model.loading.load_at_time`)."""
        pos = np.asarray(arrays["positions"], float)
        anchors = np.asarray(arrays["anchors"], float)
        layout = self.record_layout
        frame = {"time": float(time), **layout.frame_nodes(arrays)}
        frame.update({"contact_force": layout.per_crossing(self.contact_forces(pos)),
                      "anchors": layout.per_crossing(anchors), **self.planes(pos)})
        P = (self.yarn_loads(*load_at_time(self, time)) if self.control == "force"
             else np.zeros(self.yarns))
        frame.update(self.energy_records(pos, P, anchors, self.friction_limits(pos)))
        frame["energy/kinetic"] = float(np.sum(arrays["kinetic_energy"]))
        return {name: np.asarray(value) for name, value in frame.items()}

    def transient_drive(self):
        """The transient's drive (`dynfab.model.loading.family_drive`): one row per family."""
        return family_drive(self)

    def frame_arrays(self, frame: dict) -> dict:
        """The structure's flat arrays of a frame `frame` made (positions, velocities, force
        (n, 2), anchors (T, 2), time): what a resumed transient restores."""
        return self.record_layout.frame_arrays(frame, 2)

    def finish_step(self, state: State, start: StepStart, solution: StepSolution):
        """(new state, record) of the step `start` began, from the solver's `solution`
        (`dynfab.solvers.contract.RunModel.finish_step`): the contact forces, the end forces (the
        load under force control, else the reaction dV/du_N of the elastic terms and the friction
        at F_T frozen), the anchors' radial return map and its dissipation, the loads' work,
        and the record of the module docstring."""
        f, pos, limit, terms = self.structure, solution.positions, solution.limit, self.terms
        anchors = start.anchors.copy()
        R = self.contact_forces(pos)
        if self.control == "force":
            end_force = np.asarray(start.chain_loads, float).copy()
        else:
            grad = np.zeros_like(pos)
            terms.gradient(pos, f, np.zeros(self.yarns), anchors, limit, grad)
            end_force = grad[f.load_node, 0].copy()
        sliding, friction_force, lost = self.return_map(pos, anchors, limit)
        new, u_new = self.end_of_step(state, start.load.copy(), pos, anchors[:, :2].copy(),
                                      end_force, lost)
        physical = physical_positions(f, pos)
        record = {
            "load": start.load.copy(), "end_force": end_force, "end_displacement": u_new,
            **self.record_layout.nodes("positions", physical),
            "strain": self.strains(pos), "stress": self.stresses(end_force),
            "crimp": self.crimps(physical),
            **self.crossing_records(R, limit, sliding, friction_force, anchors[:, :2]),
            **self.planes(pos),
            "dissipated": new.dissipated[0], "work": new.work,
            **{name: np.asarray(value)[0] for name, value in solution.fields.items()},
        }
        P = end_force if self.control == "force" else np.zeros(self.yarns)
        record.update(self.energy_records(pos, P, anchors, limit))
        if self.slides:  # every crossing's nodes stay on its planes
            record["slip_ratio"] = 0.0
            new = self._slide(new, record)
        else:
            ratios = fabric_slip_ratios(record, *self.crossing_nodes())
            record["slip_ratio"] = np.max(np.concatenate([r.ravel() for r in ratios]),
                                          initial=0.0)
        return new, {name: np.asarray(value) for name, value in record.items()}

    def _slide(self, new: State, record: dict) -> State:
        """Where the crossings slide: the record's material coordinates, slides and crossings
        present at the step's end (`record_slides`); the state in the structure after the
        crossings a yarn end has passed."""
        dofs, gone = self.record_slides(new.positions, record)
        if gone:
            new = State(dofs, np.delete(new.anchors, gone, 0), new.dissipated, new.load,
                        new.end_force, new.work)
        return new

    def end_of_step(self, state: State, load, pos, anchors, end_force, lost: float):
        """(the state a step from `state` to `load` ends in, the end displacements u (Y,) [m]):
        its positions, return-mapped anchors and end forces [N]; the dissipation plus `lost` [J],
        and the end loads' work by the trapezoid rule over the step [J]."""
        f = self.structure
        u_old = state.positions[f.load_node, 0] - f.rest_position[f.load_node, 0]
        u_new = pos[f.load_node, 0] - f.rest_position[f.load_node, 0]
        work = state.work + float(0.5 * (state.end_force + end_force) @ (u_new - u_old))
        return State(pos, anchors, state.dissipated + lost, load, end_force, work), u_new

    def crossing_name(self, c: int) -> str:
        """Crossing c as the scene counts it: "(warp k, weft j)", 1-based."""
        k, j = divmod(int(c), self.wefts)
        return f"(warp {k + 1}, weft {j + 1})"

    def yarn_name(self, y: int) -> str:
        """Yarn y (0-based, warps first) as the scene counts it: "warp k" or "weft j"."""
        return f"warp {y + 1}" if y < self.warps else f"weft {y - self.warps + 1}"

    # ------------------------------------------------------------------ observables

    def crimps(self, pos) -> np.ndarray:
        """Mean crimps (warp, weft) [-]: (arc length - projected length) / projected length of
        each yarn (`dynfab.model.geometry.crimp`, the projected length its end-to-end extent
        along itself), averaged over the family (docs/model.md section 10)."""
        return np.array([crimp(family).mean() for family in self.record_layout.blocks_of(pos)])

    def families(self) -> tuple[np.ndarray, np.ndarray]:
        """(warp mask, weft mask) (Y,) of the yarns a family's strain and stress average
        over, its loaded yarns (docs/model.md section 10): under displacement control a
        yarn of factor 0 is held, not loaded, and left out (a pull-out's other warps), unless
        the whole family is; under force control a factor-0 yarn's end is free and counts."""
        f = self.structure
        loaded = (f.load_factor != 0) | (self.control == "force")
        warp = f.chain_family == 0
        out = []
        for family in (warp, ~warp):
            out.append(family & loaded if (family & loaded).any() else family)
        return out[0], out[1]

    def strains(self, pos) -> np.ndarray:
        """Nominal strains (warp, weft): the mean end displacement of the family's loaded
        yarns (`families`) over their length (docs/model.md section 10)."""
        f = self.structure
        u = pos[f.load_node, 0] - f.rest_position[f.load_node, 0]
        return np.array([u[chosen].mean() / length for chosen, length
                         in zip(self.families(), (self.warp.length, self.weft.length))])

    def widths(self) -> np.ndarray:
        """The width per yarn of each family [m], (warp, weft), as woven: a warp's is the
        wefts' length over the warps, L_we / n_wa; a weft's L / n_we (docs/model.md
        section 10)."""
        return np.array([self.weft.length / self.warps, self.warp.length / self.wefts])

    def stresses(self, end_force) -> np.ndarray:
        """Loads per unit width (warp, weft) [N/m]: the mean end force of the family's
        loaded yarns (`families`, the yarns of its strain) over its width per yarn
        (`widths`): on the periodic cell and a patch under force control, the force the
        family carries over the fabric's width; in a pull-out, the pulled warp's force over
        its width (docs/model.md section 10)."""
        end_force = np.asarray(end_force, float)
        return np.array([end_force[chosen].mean() for chosen in self.families()]) / self.widths()

    def planes(self, positions) -> dict:
        """warp_planes (n_wa,) Y_k and weft_planes (n_we,) X_j [m] at `positions`
        (`assembly.planes`: as woven, or moved with the ends)."""
        x, y = plane_positions(positions, self.woven_structure)  # per crossing k n_we + j
        return {"warp_planes": y[::self.wefts].copy(), "weft_planes": x[:self.wefts].copy()}
