"""A fabric scene (geometry.model = "fabric", docs/model.md section 10) as a run: its model
and its solvers under the run's contract.

`FabricModel` is what a run needs of a fabric scene: its structure (`dynfab.build.fabric`),
its yarn families, the load path, the as-woven reference, the root attributes, the start
state and a resumed state; `FabricSolver` wraps `FabricStaticSolver` (or the dynamic one)
so that it conforms to `dynfab.solver.Solver`: `step(state, load)` with `load` the step's
pair (warp value, weft value) of the path, the same kind of thing the one-yarn model's load
value is (a value of the path, not an index into it), returning a record of the names
below, written as `steps/<name>` (units in `dynfab.results.UNITS`).

Record of one fabric step (n_wa warps of N+1 nodes, n_we wefts of M+1 nodes; Y = n_wa
+ n_we yarns, warps first):

- load (2,): (warp, weft) value [N or m]; end_force, end_displacement (Y,) [N], [m];
- positions (n_wa, N+1, 2): the warps' (x, z); weft_positions (n_we, M+1, 2): the
  wefts' (y, z) [m];
- strain, crimp (2,): (warp, weft) nominal strain and mean crimp [-]; stress (2,):
  (warp, weft) load per unit width [N/m] (`FabricStaticSolver.stresses`);
- slip_ratio: the largest slip ratio of the step's crossing nodes [-]
  (`dynfab.domain.slip_ratios`; a run stops a step above 1/2, docs/model.md section 10);
- contact_force, friction_limit, sliding (n_wa, n_we); friction_force, anchors
  (n_wa, n_we, 2) [N], [m] (in-plane: warp x, weft y; the anchors relative to the planes);
- warp_planes (n_wa,): the plane y = Y_k of each warp, weft_planes (n_we,): x = X_j of each
  weft [m], where they are at the step's end (they move with "affine" planes and on the
  periodic cell, docs/model.md section 10);
- dissipated, work [J]; energy/<term> [J] per active term of the registry
  (`dynfab.terms.registry`, its dataset names and order, as the one-yarn model's);
- residual [N], iterations, friction_solves, rounding_floor, stable, buckled (an escape
  from a saddle was taken), lowest_eigenvalue [N/m] (the eigenvalue nearest zero of the
  frozen-F_T Hessian: the lowest when none is negative), negative_eigenvalues; scalars;
- with the dynamic solver, time_steps (the time steps of the step's relaxations, also its
  iterations), and with the semi-implicit method cg_iterations (their CG iterations).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from dynfab.build.fabric import Family, families, fabric_structure
from dynfab.domain import check_crossings_held, check_not_folded, fabric_slip_ratios
from dynfab.errors import UserError
from dynfab.fabric.assembly import TERMS, planes
from dynfab.fabric.static import FabricState, FabricStaticSolver, as_woven_state
from dynfab.scene import Scene
from dynfab.structure import Structure
from dynfab.terms import registry


@dataclass
class FabricModel:
    """A fabric scene as the solvers see it: its structure (`dynfab.build.fabric`), its yarn
    families and its load path (docs/model.md section 10)."""

    scene: Scene
    structure: Structure
    warp: Family
    weft: Family

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

    def split(self, nodes: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """All nodes (nodes, 2) -> (warps (n_wa, N+1, 2), wefts (n_we, M+1, 2))."""
        cut = self.warps * (self.warp.segments + 1)
        return (nodes[:cut].reshape(self.warps, self.warp.segments + 1, 2),
                nodes[cut:].reshape(self.wefts, self.weft.segments + 1, 2))

    def reference(self) -> dict:
        """The result file's `reference/`: both families as woven, the crossing nodes."""
        warps, wefts = self.split(self.structure.rest_position)
        nodes, weft_nodes = self.crossing_nodes()
        return {"positions": warps, "weft_positions": wefts,
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
        `FabricSolver.step` takes."""
        return self.load_values[index]

    def check_step(self, record: dict) -> None:
        """SolverError if the step left the model's domain: a yarn folded back
        (`dynfab.domain.check_not_folded`), or a crossing node carried more than half a
        segment from its crossing (`dynfab.domain.check_crossings_held`); for every solver."""
        check_not_folded(record, lambda: self.labels)  # labels made only for the message
        g = self.scene.geometry
        check_crossings_held(record, *self.crossing_nodes(), suggest_affine=(
            g.boundary == "clamped" and g.planes == "fixed" and self.pullout is None))

    def solver(self, name: str, device: str | None = None, status=None) -> "FabricSolver":
        """The solver `name` ("static", "dynamic") for this model under `dynfab.solver.Solver`;
        it reports within each step to `status` (per Newton iteration, per launch of a
        relaxation)."""
        if device is not None and name == "static":
            raise UserError(f"--device {device}: the static solver runs on the CPU (numba); "
                            "a device is for --solver dynamic")
        if name == "dynamic":
            _check_dynamic_keys(self.scene.dynamic)
        return FabricSolver(self, name, device or "cpu", status)

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

    def initial_state(self) -> FabricState:
        return as_woven_state(self.structure)

    def state_from_step(self, last: dict) -> FabricState:
        """The state a finished step left (a resumed run continues from it)."""
        nodes = np.concatenate([np.asarray(last["positions"]).reshape(-1, 2),
                                np.asarray(last["weft_positions"]).reshape(-1, 2)])
        return FabricState(nodes, np.array(last["anchors"]).reshape(self.warps * self.wefts, 2),
                           float(last["dissipated"]), float(last["work"]),
                           np.array(last["end_force"], float))

    @property
    def planes_move(self) -> bool:
        """The planes X_j, Y_k follow the ends ("affine" planes, the periodic cell)."""
        return bool(self.structure.plane_nodes_a.size or self.structure.plane_nodes_b.size)

    def point_data(self, record: dict) -> dict:
        """The XDMF view's nodal point data of a step (`dynfab.xdmf`): contact force and
        the slip s (docs/model.md (10.7): in-plane coordinate - plane - anchor) at each
        family's crossing nodes, 0 elsewhere; where the planes move, each node's plane
        coordinate (`xdmf/plane`: the warps' y, `xdmf/weft_plane`: the wefts' x), which the
        view draws them at."""
        ref = self.reference()
        R = np.asarray(record["contact_force"])
        anchors = np.asarray(record["anchors"])
        warp_planes, weft_planes = np.asarray(record["warp_planes"]), np.asarray(record["weft_planes"])
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
            out[f"xdmf/{prefix}contact_force"], out[f"xdmf/{prefix}slip"] = f, slip
            if self.planes_move:
                out[f"xdmf/{prefix}plane"] = np.repeat(own[:, None], positions.shape[1], axis=1)
        return out


class FabricSolver:
    """A fabric solver under `dynfab.solver.Solver`, one load step per call: the static
    `FabricStaticSolver`, or the dynamic `FabricDynamicSolver` (Warp), which returns the
    same record (plus its time steps)."""

    def __init__(self, model: FabricModel, name: str = "static", device: str = "cpu",
                 status=None):
        self.model, self.name = model, name
        self.solver = FabricStaticSolver(model)
        self.engine = self.solver
        if name == "static":
            self.solver.status = status  # per Newton iteration
        if name == "dynamic":
            from dynfab.fabric.dynamic import FabricDynamicSolver  # imports Warp: only here
            from dynfab.kernels.runtime import initialize

            initialize(device)
            dynamic = model.scene.dynamic
            self.engine = FabricDynamicSolver(model, device=device,
                                              damping=dynamic.damping_used(),
                                              tolerance=dynamic.tolerance,
                                              max_steps=dynamic.max_steps,
                                              method=dynamic.method,
                                              damping_coefficient=dynamic.damping_coefficient,
                                              status=status)

    def attrs(self) -> dict:
        static = self.model.scene.static
        attrs = {"solver": self.name, "static_tolerance": static.tolerance,
                 "static_max_iterations": static.max_iterations}
        if self.name == "dynamic":
            attrs["dynamic_damping"] = self.model.scene.dynamic.damping_used()
            attrs["dynamic_method"] = self.model.scene.dynamic.method  # as the one-yarn run's
        return attrs

    def step(self, state: FabricState, load) -> tuple[FabricState, dict]:
        """Solve the step under `load` = (warp value, weft value) from `state` (not modified);
        returns (new state, record of the module docstring's names). SolverError as
        `FabricStaticSolver.step`."""
        warp_value, weft_value = (float(v) for v in load)
        new, raw = self.engine.step(state, warp_value, weft_value)
        model = self.model
        warps, wefts = model.split(new.positions)
        shape = (model.warps, model.wefts)
        record = {
            "load": np.array([warp_value, weft_value]),
            "end_force": raw["end_force"], "end_displacement": raw["end_displacement"],
            "positions": warps, "weft_positions": wefts,
            "strain": raw["strain"], "stress": self.solver.stresses(raw["end_force"]),
            "crimp": raw["crimp"],
            "contact_force": raw["contact_force"], "friction_limit": raw["friction_limit"],
            "sliding": raw["sliding"], "friction_force": raw["friction_force"].reshape(*shape, 2),
            "anchors": new.anchors.reshape(*shape, 2),
            **self.planes(new.positions),
            "dissipated": new.dissipated, "work": new.work,
            "residual": raw["residual"], "iterations": raw["iterations"],
            "friction_solves": raw["friction_solves"], "rounding_floor": raw["rounding_floor"],
            "stable": raw["stable"], "buckled": raw["escapes"] > 0,
            "lowest_eigenvalue": raw["nearest_eigenvalue"],
            "negative_eigenvalues": raw["negative_eigenvalues"],
        }
        record.update(self._energies(new, warp_value, weft_value, raw["friction_limit"]))
        ratios = fabric_slip_ratios(record, *model.crossing_nodes())
        record["slip_ratio"] = np.max(np.concatenate([r.ravel() for r in ratios]), initial=0.0)
        for name in ("time_steps", "cg_iterations"):  # the dynamic solver's (the semi-implicit's)
            if name in raw:
                record[name] = raw[name]
        return new, {name: np.asarray(value) for name, value in record.items()}

    def planes(self, positions) -> dict:
        """warp_planes (n_wa,) Y_k and weft_planes (n_we,) X_j [m] at `positions`
        (`assembly.planes`: as woven, or moved with the ends)."""
        wefts = self.model.wefts
        x, y = planes(positions, self.solver.fabric)  # per crossing c = k n_we + j
        return {"warp_planes": y[::wefts].copy(), "weft_planes": x[:wefts].copy()}

    def _energies(self, state: FabricState, warp_value, weft_value, limit) -> dict:
        """energy/<term> [J] at the step's end: the load term with the end forces P (force
        control; none under displacement control), friction with the return-mapped anchors."""
        solver = self.solver
        P = (solver.yarn_loads(warp_value, weft_value) if self.model.control == "force"
             else np.zeros(solver.yarns))
        solver.energy(state.positions, P, state.anchors, np.asarray(limit).ravel())
        values = dict(zip(TERMS, solver._terms))  # the assembly's energy vector, by term name
        return {registry.TERMS[registry.index(term)].dataset: float(values[term])
                for term in registry.active_terms(self.model.scene)}


_DYNAMIC_SUPPORTED = {"mode": "quasi_static", "method": "explicit", "precision": "float64",
                      "masses": None, "dt": None, "safety": 0.9}
"""The [dynamic] settings the fabric's dynamic solver runs (`FabricDynamicSolver`: a
quasi-static explicit relaxation in float64 with its own fictitious masses and time step);
any other value is refused rather than ignored; method "semi_implicit" is accepted too
(`fabric_semi_implicit.FabricSemiImplicit`, docs/model.md section 10)."""


def _check_dynamic_keys(dynamic) -> None:
    """Refuse, in one line, a [dynamic] setting the fabric's dynamic solver would ignore."""
    for key, supported in _DYNAMIC_SUPPORTED.items():
        value = getattr(dynamic, key)
        if key == "method" and value == "semi_implicit":  # FabricSemiImplicit
            continue
        if value != supported:
            raise UserError(f"dynamic.{key} = {value!r}: the fabric's dynamic solver runs "
                            f"{key} = {supported!r} only (docs/model.md section 10)")
    if dynamic.damping_used() == "viscous" and dynamic.damping_coefficient is None:
        raise UserError("dynamic.damping = 'viscous': the fabric's dynamic solver has no "
                        "adaptive viscous coefficient; give dynamic.damping_coefficient [1/s] "
                        "or use \"kinetic\" or \"fire\"")
