"""Precision report (`dynfab precision`): error against cost of every dynamic method.

`run_precision(out_dir, quick=False, scene=None)` relaxes single load steps with every
dynamic method (docs/model.md section 5) over a ladder of tolerances, times each warm, measures its
error against the static reference converged to float64's rounding floor (docs/model.md section 6)
and writes, into `out_dir`:

* ``points.csv``: tidy rows, one per (solve, quantity), with the units of each;
* ``summary.json``: the machine, the plan, the cases, every point, the Pareto fronts
  and the cheapest-method tables;
* ``cheapest.json`` and ``precision.md``: which method is cheapest for a relative error
  of 1e-3, 1e-5 and 1e-7, by warm wall time and by force evaluations;
* ``work_precision_time.png``, ``work_precision_evaluations.png``: relative error against
  wall time and against force evaluations, log-log, one curve per method, the static
  Newton solve and scipy's L-BFGS-B as reference points, the Pareto front marked;
* ``error_vs_residual.png``: the error each solve left against its force residual, with
  the bound ||K^-1||_inf (r + r_ref).

Cases. Each scene is solved along its own load path by the static solver (tolerance
`REFERENCE_TOLERANCE`, so every step stops at the rounding floor) up to the start of
the studied step; every solver then relaxes that one step from the same state, friction
anchors included. The steps studied are the first (from the as-woven geometry: a
prestressed yarn relaxes its prestress there), and those at about 22.5 % and 82.5 % of
the path: on the paper's 40 steps to 10 mm, 0 -> 0.25, 2 -> 2.25 and 8 -> 8.25 mm.
Default scenes: ``runs/paper_fig3.toml`` entry K = 0.2 m/N and ``runs/paper_fig5.toml``
entry 0 (friction); a scene file given instead is studied entry by entry (its [dynamic]
table is ignored: the report sets every option itself).

Measured per solve:

* relative error: the largest node position error |x - x_ref| over all nodes and both
  coordinates [m], divided by the crimp amplitude A_wa (by L for a straight yarn);
* end error: under displacement control the relative error of the end force (the
  reaction P), under force control that of the end displacement;
* residual: the largest free force component (friction included, F_T from the current
  contact forces, the anchors of the step's start) recomputed in float64 at the returned
  positions, so a float32 run is judged by the force its positions really leave; the
  solver's own figure is kept as ``solver_residual``;
* the bound ||K^-1||_inf (r + r_ref) on the position error (linearising the residual map
  at the reference; K the Hessian over the free dofs, with friction the coupled
  Jacobian), as tests/test_dynamic_relaxation.py uses it;
* warm wall time: one untimed call first (it builds or loads the kernel variant), then
  the fastest of `Plan.repeats` timed calls of `DynamicSolver.step`, from the start
  state to the finished step record (solver construction excluded);
* force evaluations (machine-independent): the dynamic solver's count; the static
  Newton solve's gradient evaluations (iterations + 1, each with a banded Hessian and
  line-search energies besides); L-BFGS-B's energy-and-gradient evaluations.

Two static Newton points: the reference solve itself, timed the same way (Newton is
deterministic, so it reproduces the reference exactly: its error is the floor of the
comparison), and the solve at the scene's `static.tolerance` (1e-11 N by default), what
`dynfab run` does. Errors are shown no lower than the position rounding floor
eps max|x| / A_wa.
scipy's L-BFGS-B minimises the same energy
(`dynfab.model.assembly`) over the free dofs with ``gtol`` = the tolerance; with friction,
whose F_T depends on the contact forces (docs/model.md section 4: not a pure minimisation), it
alternates minimisations with F_T frozen and F_T updates until the residual with the
current F_T meets the tolerance or stops falling.

``quick=True`` solves the paper yarn cut to 4 crossings (L / 4, N = 56, the same spacing,
weft and contact law, end displacements / 4) with few methods and 2-3 tolerances each,
using only the kernel variants the dynamic tests already build (displacement control;
explicit kinetic, viscous and FIRE, semi_implicit and float32 kinetic without friction;
kinetic and semi_implicit with friction). Errors for user mistakes are `UserError`s.
"""

from __future__ import annotations

import contextlib
import math
import time
import warnings
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Callable

import numpy as np
from threadpoolctl import threadpool_info, threadpool_limits

from dynfab.model import assembly
from dynfab.linalg.banded import to_dense
from dynfab.solvers.dynamic import DynamicSolver
from dynfab.errors import SolverError
from dynfab.model.yarn import Model, State, initial_state
from dynfab.model.builders import build_model
from dynfab.model.observables import finish_step
from dynfab.plots.style import save_png
from dynfab.reports.common import (cut_yarn, kernel_name, machine, output_folder, paper_yarns,
                                   write_csv, write_json, write_summary, write_text)
from dynfab.reports.precision_plots import plot_error_vs_residual, plot_work_precision
from dynfab.reports.precision_points import (METHODS, Method, cheapest, method_label,
                                             pareto_fronts, usable_points)
from dynfab.reports.precision_tables import precision_markdown
from dynfab.scene import Dynamic, Scene, expand_sweep, load_scene, with_key
from dynfab.model.loading import prescribe_load
from dynfab.solvers.newton_banded import max_free
from dynfab.solvers.static import StaticSolver
from dynfab.timing import best_time
from dynfab.model.terms.friction import INDEX as FRICTION

REFERENCE_TOLERANCE = 1e-13
"""Static tolerance of the start states and references [N]: below float64's floor at
N = 224 (about 6e-13 N), so Newton stops where the residual stops falling
(docs/model.md section 6)."""

TARGETS = (1e-3, 1e-5, 1e-7)
"""Relative errors for which the cheapest method is reported [-]."""

STEP_FRACTIONS = (0.0, 0.225, 0.825)
"""Studied load steps, as fractions of the load path (step max(1, round(f n)) of n)."""

MAX_DENSE_DOFS = 8000
"""Largest free-dof count for which the dense ||K^-1||_inf and lowest mode are computed."""

EPS = float(np.finfo(np.float64).eps)

CSV_COLUMNS = ("case", "scene", "start_load", "load", "load_units", "solver", "method", "label",
               "precision", "masses", "damping", "damping_coefficient", "damping_coefficient_units",
               "safety", "tolerance", "tolerance_units", "status", "quantity", "value", "units")

QUANTITIES = {
    # name: (units, point key)
    "wall_time": ("s", "wall_time_s"),
    "force_evaluations": ("-", "force_evaluations"),
    "iterations": ("-", "iterations"),
    "position_error": ("m", "position_error_m"),
    "relative_error": ("-", "relative_error"),
    "end_error": ("-", "end_error"),
    "end_error_absolute": (None, "end_error_absolute"),  # N or m: the end quantity's units
    "residual": ("N", "residual_N"),
    "solver_residual": ("N", "solver_residual_N"),
    "error_bound": ("m", "bound_m"),
}


@dataclass(frozen=True)
class Plan:
    """What a report solves: scene size, methods, tolerances, repeats."""

    name: str
    crossings: int | None
    """Cut the paper yarn to this many crossings (same spacing; None: as in the file)."""
    segments: int | None
    """N of the cut paper yarn (None: as in the file)."""
    tolerances: tuple[float, ...]
    """Tolerances of the float64 methods and of L-BFGS-B's gtol [N]."""
    float32_tolerances: tuple[float, ...]
    """Tolerances of the float32 methods [N] (below about 1e-4 N they stall at the floor)."""
    methods: tuple[str, ...]
    """Methods solved on frictionless scenes (keys of METHODS)."""
    friction_methods: tuple[str, ...]
    """Methods solved on scenes with friction."""
    step_fractions: tuple[float, ...] = STEP_FRACTIONS
    paper_scenes: tuple[str, ...] = ("frictionless", "friction")
    """The default paper scenes solved (when no scene file is given)."""
    repeats: int = 1
    """Timed calls per point after the untimed one, at least; the fastest counts."""
    min_timed: float = 0.0
    """Timed calls continue until they add up to this [s] (at most MAX_REPEATS)."""
    lbfgs_repeats: int = 1
    max_steps: int = 300_000
    """dynamic.max_steps of every dynamic solve (a slower one is recorded as failed)."""


FULL = Plan(name="full", crossings=None, segments=None,
            tolerances=tuple(10.0 ** -k for k in range(4, 12)),
            float32_tolerances=(1e-3, 1e-4, 1e-5, 1e-6),
            methods=tuple(METHODS), friction_methods=tuple(METHODS), repeats=5, min_timed=0.02,
            lbfgs_repeats=2)
QUICK = Plan(name="quick", crossings=4, segments=56, tolerances=(1e-4, 1e-7, 1e-10),
             float32_tolerances=(1e-4, 1e-6),
             methods=("kinetic", "viscous", "viscous_c1", "fire", "semi_implicit",
                      "kinetic_float32"),
             friction_methods=("kinetic", "semi_implicit"), repeats=3, lbfgs_repeats=1,
             max_steps=100_000)


def run_precision(out_dir, *, quick: bool = False, progress: Callable[[str], None] | None = None,
                  scene=None, plan: Plan | None = None) -> dict:
    """Run the study, write the CSV, JSON, markdown and PNGs; return the summary.

    `scene`: a scene file to study instead of the paper scenes. `plan`: overrides the
    quick/full plan (tests). `progress` receives one line per (case, method).
    """
    started = time.perf_counter()
    out = output_folder(out_dir)
    plan = plan or (QUICK if quick else FULL)
    scenes = _scenes(scene, plan)
    cases = [case for label, s in scenes.items() for case in build_cases(label, s, plan)]
    study = _Study(plan, progress)
    points = [point for case in cases for point in study.solve_case(case)]
    fronts = {case.key: pareto_fronts([p for p in points if p["case"] == case.key], case.floor)
              for case in cases}
    for point in points:
        point["pareto_time"] = point["id"] in fronts[point["case"]]["wall_time_s"]
        point["pareto_evaluations"] = point["id"] in fronts[point["case"]]["force_evaluations"]
    summary = {
        "report": "precision",
        "plan": _plan_dict(plan),
        "quick": quick,
        "scene_file": None if scene is None else str(scene),
        "machine": machine(),
        "targets": list(TARGETS),
        "cases": [case.describe() for case in cases],
        "kernel_variants": sorted({p["kernel"] for p in points if p.get("kernel")}
                                  | {case.info["probe_kernel"] for case in cases
                                     if "probe_kernel" in case.info}),
        "failures": [{k: p[k] for k in ("case", "method", "tolerance", "message")}
                     for p in points if p["status"] == "failed"],
        "cheapest": cheapest_table(points, cases),
        "one_setting": one_setting_table(points, cases),
        "points": points,
        "solve_time_s": study.solve_time,
    }
    cheapest = {key: summary[key] for key in ("targets", "cheapest", "one_setting")}
    files = [write_csv(out / "points.csv", CSV_COLUMNS, csv_rows(points, cases)),
             write_json(out / "cheapest.json", cheapest),
             write_text(out / "precision.md", precision_markdown(summary)),
             save_png(plot_work_precision(summary, "wall_time_s"), out / "work_precision_time.png"),
             save_png(plot_work_precision(summary, "force_evaluations"),
                      out / "work_precision_evaluations.png"),
             save_png(plot_error_vs_residual(summary), out / "error_vs_residual.png")]
    return write_summary(out, summary, files, started)


# --------------------------------------------------------------------------
# Scenes and cases.


def _scenes(path, plan: Plan) -> dict[str, Scene]:
    """The scenes to study, by label: a scene file's entries, or the paper scenes."""
    if path is not None:
        entries = expand_sweep(load_scene(path))
        stem = Path(path).stem
        if len(entries) == 1:
            return {stem: entries[0]}
        return {f"{stem} entry {k}": entry for k, entry in enumerate(entries)}
    paper = dict(zip(("frictionless", "friction"),
                     paper_yarns("without a scene argument the precision report")))
    return {label: _cut(paper[label], plan) for label in plan.paper_scenes}


def _cut(scene: Scene, plan: Plan) -> Scene:
    """The paper yarn cut to `plan.crossings` (None: as it is), N = `plan.segments` (None: as
    it is), its end displacements scaled with its length (the same strains)."""
    if plan.crossings is None:
        return scene if plan.segments is None else with_key(scene, "geometry.segments",
                                                            plan.segments)
    return cut_yarn(scene, plan.crossings, plan.segments, scale_load=True)


@dataclass
class Case:
    """One load step of one scene, relaxed by every solver from the same start state."""

    key: str
    scene_label: str
    model: Model
    step: int
    """The studied load step, 1-based."""
    start_load: float
    load: float
    start: State
    reference: State
    reference_record: dict
    reference_residual: np.ndarray
    """Float64 residual of the reference, per yarn [N]."""
    scale: float
    """A_wa (L for a straight yarn) [m]: position errors are divided by it."""
    floor: float
    """Position rounding floor eps max|x_ref| / scale [-]."""
    inverse_norm: np.ndarray | None
    """||K^-1||_inf per yarn at the reference [m/N] (None above MAX_DENSE_DOFS)."""
    critical_damping: float | None
    """Twice the lowest circular frequency with the fictitious masses [1/s]."""
    info: dict = field(default_factory=dict)

    @property
    def control(self) -> str:
        return self.model.control

    @property
    def end_quantity(self) -> str:
        """The end quantity the solver does not prescribe: its error is reported."""
        return "end_force" if self.control == "displacement" else "end_displacement"

    @property
    def load_units(self) -> str:
        return "m" if self.control == "displacement" else "N"

    @property
    def scale_name(self) -> str:
        return "A_wa" if self.model.scene.geometry.amplitude > 0 else "L"

    @property
    def title(self) -> str:
        return f"{self.scene_label}, {_load_text(self.start_load, self.load, self.control)}"

    def describe(self) -> dict:
        record = self.reference_record
        return {"case": self.key, "title": self.title, "scene": self.scene_label,
                "step": self.step, "start_load": self.start_load, "load": self.load,
                "load_units": self.load_units, "control": self.control,
                "segments": self.model.segments, "crossings": self.model.crossings,
                "yarns": self.model.yarn_count, "friction": "friction" in self.model.terms,
                "end_quantity": self.end_quantity,
                "end_value": float(np.abs(record[self.end_quantity]).max()),
                "scale_m": self.scale, "scale_name": self.scale_name,
                "rounding_floor_relative": self.floor,
                "reference_tolerance_N": REFERENCE_TOLERANCE,
                "reference_residual_N": float(self.reference_residual.max()),
                "reference_at_rounding_floor": bool(record["rounding_floor"].all()),
                "reference_iterations": int(record["iterations"].sum()),
                "inverse_stiffness_norm_m_per_N": None if self.inverse_norm is None
                else float(self.inverse_norm.max()),
                "critical_damping_per_s": self.critical_damping,
                "sliding_crossings": int(record["sliding"].sum()),
                "closed_crossings": int((record["contact_force"] > 0).sum()), **self.info}


def _load_text(start: float, end: float, control: str) -> str:
    if control == "displacement":
        return f"u = {1e3 * start:g} -> {1e3 * end:g} mm"
    return f"P = {start:g} -> {end:g} N"


def studied_steps(count: int, fractions) -> list[int]:
    """The 1-based load steps studied on a path of `count` steps."""
    return sorted({min(count, max(1, round(f * count))) for f in fractions})


def build_cases(label: str, scene: Scene, plan: Plan) -> list[Case]:
    """The studied steps of one scene, each with its start state and static reference."""
    model = build_model(scene)
    solver = StaticSolver(model, tolerance=REFERENCE_TOLERANCE)
    steps = studied_steps(model.load_values.size, plan.step_fractions)
    state = initial_state(model)
    done, cases = 0, []
    for step in steps:
        for value in model.load_values[done:step - 1]:
            state, _ = solver.step(state, value)
        done = step - 1
        load = float(model.load_values[step - 1])
        reference, record = solver.step(state, load)
        residual = float_residuals(model, reference.positions, state.anchors, load)
        scale = scene.geometry.amplitude if scene.geometry.amplitude > 0 else scene.geometry.length
        key = f"{label.replace(' ', '_')}_step{step}"
        case = Case(key=key, scene_label=label, model=model, step=step,
                    start_load=float(state.load.max()), load=load, start=state.copy(),
                    reference=reference, reference_record=record, reference_residual=residual,
                    scale=scale, floor=EPS * float(np.abs(reference.positions).max()) / scale,
                    inverse_norm=None, critical_damping=None)
        case.inverse_norm, case.critical_damping = stiffness_measures(case)
        cases.append(case)
    return cases


# --------------------------------------------------------------------------
# Linear algebra at the reference.


def dense_hessian(model: Model, positions, anchors, k: int, coupled: bool) -> np.ndarray:
    """Yarn k's Hessian of V plus the Huber terms (coupled: the friction Jacobian) over its
    free dofs, dense [N/m]; anchors of the step's start, F_T from the contact forces."""
    band = assembly.tangent(positions[k], model.yarns[k], anchors[k], coupled)
    free = ~model.fixed_dofs()
    return to_dense(band)[np.ix_(free, free)]


def stiffness_measures(case: Case) -> tuple[np.ndarray | None, float | None]:
    """(||K^-1||_inf per yarn [m/N], critical viscous c of the lowest mode [1/s]).

    c_crit = 2 omega_min, omega_min^2 the lowest eigenvalue of M^-1 K with the fictitious
    masses the explicit solver chooses at the step's start (K symmetric: without the
    friction coupling). Both None above MAX_DENSE_DOFS free dofs.
    """
    model = case.model
    if (~model.fixed_dofs()).sum() > MAX_DENSE_DOFS:
        return None, None
    positions = model.per_yarn(case.reference.positions)
    anchors = model.per_crossing(case.start.anchors)
    coupled = "friction" in model.terms
    norms = np.array([np.abs(np.linalg.inv(dense_hessian(model, positions, anchors, k, coupled)))
                      .sum(axis=1).max() for k in range(model.yarn_count)])
    probe = DynamicSolver(model, Dynamic(damping="kinetic"))  # the masses of every damping
    probe.predicted_stable_dt(case.start, case.load)
    case.info["probe_kernel"] = kernel_name(probe)
    masses = probe.last_relaxation()["masses"].reshape(model.yarn_count, -1)
    free = ~model.fixed_dofs()
    lowest = []
    for k in range(model.yarn_count):
        stiffness = dense_hessian(model, positions, anchors, k, False)
        root = 1.0 / np.sqrt(np.repeat(masses[k], 2)[free])
        lowest.append(np.linalg.eigvalsh(root[:, None] * stiffness * root[None, :])[0])
    omega2 = min(lowest)
    return norms, (2.0 * math.sqrt(omega2) if omega2 > 0 else None)


def float_residuals(model: Model, positions, anchors, load: float) -> np.ndarray:
    """The residual per yarn [N], in float64 at `positions` (the yarns' or the state's
    layout): the largest free component of the force, friction with F_T from the contact forces
    and the step's start anchors (a state's, (T, 2))."""
    positions, anchors = model.per_yarn(positions), model.per_crossing(anchors)
    P = load if model.control == "force" else 0.0
    fixed, c = model.fixed_dofs(), model.crossings
    out = np.zeros(model.yarn_count)
    for k, yarn in enumerate(model.yarns):
        pos = np.ascontiguousarray(positions[k], dtype=np.float64)
        force, limit, tangent = np.zeros(c), np.zeros(c), np.zeros(c)
        assembly.contact_state(pos, yarn, force, limit, tangent)
        grad = np.zeros_like(pos)
        assembly.gradient(pos, yarn, P, np.ascontiguousarray(anchors[k], dtype=np.float64), limit,
                          grad)
        out[k] = max_free(grad, fixed)
    return out


# --------------------------------------------------------------------------
# Solves.


class _Study:
    """Solves every point of a case, one progress line per (case, method)."""

    def __init__(self, plan: Plan, progress):
        self.plan, self.progress = plan, progress
        self.solve_time = 0.0
        self.count = 0

    def _curve(self, case: Case, label: str, solves) -> list[dict]:
        """The points of `solves` (an iterator that solves them), numbered; one progress line."""
        started = time.perf_counter()
        points = [self._point(case, point) for point in solves]
        if self.progress is None:
            return points
        elapsed = time.perf_counter() - started
        done = [p for p in points if p["status"] != "failed"]
        errors = [p["relative_error"] for p in done]
        failed = len(points) - len(done)
        text = (f"errors {max(errors):.1e} .. {min(errors):.1e}" if errors else "no result")
        self.progress(f"{case.title}: {label}: {len(points)} solve(s), {text}"
                      f"{f', {failed} failed' if failed else ''}, {elapsed:.2f} s")
        return points

    def solve_case(self, case: Case) -> list[dict]:
        friction = "friction" in case.model.terms
        plan = self.plan
        points = self._curve(case, "static Newton", (static_point(case, plan, reference=reference)
                                                     for reference in (True, False)))
        for key in plan.friction_methods if friction else plan.methods:
            method = METHODS[key]
            tolerances = (plan.float32_tolerances if method.options.precision == "float32"
                          else plan.tolerances)
            points += self._curve(case, method.label, (dynamic_point(case, method, tolerance, plan)
                                                       for tolerance in tolerances))
        return points + self._curve(case, "scipy L-BFGS-B", (lbfgs_point(case, tolerance, plan)
                                                             for tolerance in plan.tolerances))

    def _point(self, case: Case, point: dict) -> dict:
        self.count += 1
        self.solve_time += point.pop("_elapsed", 0.0)
        point.update({"id": self.count, "case": case.key, "scene": case.scene_label,
                      "start_load": case.start_load, "load": case.load,
                      "load_units": case.load_units, "end_quantity": case.end_quantity})
        return point


MAX_REPEATS = 200
"""Timed calls of one point at most, however short a call (see `_timed`)."""


def _timed(call, repeats: int, min_total: float) -> float:
    """The fastest of at least `repeats` timed calls [s], more (up to MAX_REPEATS) until
    they add up to `min_total` [s]: a sub-millisecond solve gets enough tries that one
    of them runs while no other process holds the CPU."""
    return best_time(call, repeats, until=min_total, most=MAX_REPEATS)[0]


def _base_point(solver: str, method: str, label: str, tolerance: float, **options) -> dict:
    point = {"solver": solver, "method": method, "label": label, "tolerance": tolerance,
             "precision": "float64", "masses": "", "damping": "", "damping_coefficient": "",
             "safety": "", "kernel": "", "status": "converged", "message": ""}
    point.update(options)
    return point


def measure(case: Case, positions: np.ndarray, record: dict) -> dict:
    """Errors against the reference, the float64 residual and its position-error bound."""
    model, ref = case.model, case.reference
    positions = np.asarray(positions, dtype=np.float64).reshape(-1, 2)  # the state's layout
    per_yarn = np.abs(model.per_yarn(positions - ref.positions)).max(axis=(1, 2))
    residual = float_residuals(model, positions, case.start.anchors, case.load)
    quantity = case.end_quantity
    reference_end = np.asarray(case.reference_record[quantity], dtype=np.float64)
    end_error = np.abs(np.asarray(record[quantity], dtype=np.float64) - reference_end)
    result = {"position_error_m": float(per_yarn.max()),
              "relative_error": float(per_yarn.max() / case.scale),
              "end_error_absolute": float(end_error.max()),
              "end_error": float((end_error / np.maximum(np.abs(reference_end), 1e-300)).max()),
              "residual_N": float(residual.max()),
              "solver_residual_N": float(np.max(record["residual"])),
              "bound_m": None, "within_bound": None}
    if case.inverse_norm is not None:
        bound = case.inverse_norm * (residual + case.reference_residual)
        result["bound_m"] = float(bound.max())
        result["within_bound"] = bool((per_yarn <= bound).all())
    return result


def static_point(case: Case, plan: Plan, reference: bool) -> dict:
    """A static Newton solve, timed: the reference (to the rounding floor; Newton is
    deterministic, so it reproduces the reference and its error is the floor), or the
    solve at the scene's static.tolerance."""
    tolerance = REFERENCE_TOLERANCE if reference else case.model.scene.static.tolerance
    solver = StaticSolver(case.model, tolerance=tolerance, accuracy=math.inf)
    began = time.perf_counter()
    state, record = solver.step(case.start, case.load)
    wall = _timed(lambda: solver.step(case.start, case.load), plan.repeats, plan.min_timed)
    iterations = int(record["iterations"].sum())
    key = "static_reference" if reference else "static_newton"
    point = _base_point("static", key, method_label(key).replace("\n", " "), tolerance,
                        status="rounding_floor" if record["rounding_floor"].any() else "converged")
    point.update(measure(case, state.positions, record))
    point.update({"wall_time_s": wall, "iterations": iterations,
                  "force_evaluations": iterations + case.model.yarn_count,
                  "_elapsed": time.perf_counter() - began})
    return point


def dynamic_point(case: Case, method: Method, tolerance: float, plan: Plan) -> dict:
    """One dynamic solve of the case: untimed, then the fastest of `plan.repeats` timed."""
    # accuracy = inf: this report measures each solve's error itself, loose tolerances included
    options = replace(method.options, tolerance=tolerance, max_steps=plan.max_steps,
                      accuracy=math.inf)
    coefficient = None
    if method.critical_factor is not None:
        if case.critical_damping is None:
            point = _base_point("dynamic", method.key, method.label, tolerance,
                                precision=options.precision)
            return _mark_failed(point, "no critical damping (the lowest mode was not computed)")
        coefficient = method.critical_factor * case.critical_damping
        options = replace(options, damping_coefficient=coefficient)
    began = time.perf_counter()
    solver = DynamicSolver(case.model, options)
    attrs = solver.attrs()
    damping = attrs["dynamic_damping"] if options.method == "explicit" else ""
    shown_coefficient = (coefficient if coefficient is not None
                         else "adaptive" if damping == "viscous" else "")
    point = _base_point("dynamic", method.key, method.label, tolerance,
                        precision=options.precision, masses=attrs["dynamic_masses"],
                        damping=damping, damping_coefficient=shown_coefficient,
                        safety=options.safety, kernel=kernel_name(solver))
    point["dynamic_method"] = options.method
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)  # the floor is read from the record
            state, record = solver.step(case.start, case.load)
            wall = _timed(lambda: solver.step(case.start, case.load), plan.repeats,
                          plan.min_timed)
    except SolverError as error:
        point = _mark_failed(point, str(error))
        point["_elapsed"] = time.perf_counter() - began
        return point
    if float(np.max(record["residual"])) > tolerance:
        point["status"] = "rounding_floor"
    point.update(measure(case, state.positions, record))
    point.update({"wall_time_s": wall, "iterations": int(record["time_steps"].sum()),
                  "force_evaluations": int(record["force_evaluations"].sum()),
                  "_elapsed": time.perf_counter() - began})
    return point


def _mark_failed(point: dict, message: str) -> dict:
    """A solve that raised: its message kept, no measurements (left out of figures, tables)."""
    point.update({"status": "failed", "message": message})
    point.update({name: None for name in ("wall_time_s", "iterations", "force_evaluations",
                                          "position_error_m", "relative_error", "end_error",
                                          "end_error_absolute", "residual_N",
                                          "solver_residual_N", "bound_m", "within_bound")})
    return point


MAX_FRICTION_ROUNDS = 30
"""L-BFGS-B with friction: alternations of a minimisation with F_T frozen and an F_T update."""


def lbfgs_solve(model: Model, state: State, load: float, tolerance: float):
    """scipy's L-BFGS-B on V (+ Huber terms) over the free dofs of each yarn, gtol = tolerance.

    With friction, F_T is frozen during a minimisation and then updated from the contact
    forces, until the residual with the current F_T meets the tolerance or stops falling.
    Returns (positions, residual per yarn [N], evaluations).
    """
    from scipy.optimize import minimize

    positions = prescribe_load(model, state, load)
    P = load if model.control == "force" else 0.0
    fixed = model.fixed_dofs()
    free = ~fixed
    c = model.crossings
    residuals, evaluations = np.zeros(model.yarn_count), 0
    for k, yarn in enumerate(model.yarns):
        pos = positions[k]
        flat = pos.reshape(-1)
        anchors = model.per_crossing(state.anchors)[k]
        force, limit, tangent = np.zeros(c), np.zeros(c), np.zeros(c)
        terms, grad = assembly.energy_vector(), np.zeros_like(pos)

        def energy(q):
            flat[free] = q
            assembly.energies(pos, yarn, P, anchors, limit, terms)
            return terms.sum()

        def gradient(q):
            flat[free] = q
            assembly.gradient(pos, yarn, P, anchors, limit, grad)
            return grad.reshape(-1)[free].copy()

        best = math.inf
        for _ in range(MAX_FRICTION_ROUNDS):
            assembly.contact_state(pos, yarn, force, limit, tangent)
            result = minimize(energy, flat[free].copy(), jac=gradient, method="L-BFGS-B",
                              options={"maxiter": 200_000, "maxfun": 400_000, "maxcor": 20,
                                       "ftol": 0.0, "gtol": tolerance})
            flat[free] = result.x
            evaluations += int(result.nfev)
            assembly.contact_state(pos, yarn, force, limit, tangent)
            assembly.gradient(pos, yarn, P, anchors, limit, grad)
            residual = max_free(grad, fixed)
            if not yarn.active[FRICTION] or residual <= tolerance or not residual < 0.5 * best:
                break
            best = residual
        residuals[k] = residual
    return positions, residuals, evaluations


@contextlib.contextmanager
def single_threaded_blas():
    """The BLAS libraries loaded in this process limited to one thread inside the block
    (threadpoolctl); yields whether any was found to limit.

    Every solver compared runs on one thread (the Warp CPU kernel and numba), and
    L-BFGS-B's BLAS calls on vectors of a few hundred entries only lose by threading, the
    more so while other processes load the machine (docs/results.md, "Precision",
    Surprises). The thread counts are restored after.
    """
    with threadpool_limits(limits=1, user_api="blas"):
        yield any(info["user_api"] == "blas" for info in threadpool_info())


def lbfgs_point(case: Case, tolerance: float, plan: Plan) -> dict:
    """scipy's L-BFGS-B from the case's start state, BLAS on one thread; its stopping
    point, timed like the rest."""
    import scipy.optimize  # noqa: F401  (loads scipy's OpenBLAS before it is limited)

    model = case.model
    began = time.perf_counter()

    def solve():
        positions, residual, evaluations = lbfgs_solve(model, case.start, case.load, tolerance)
        _, record = finish_step(model, case.start, positions, case.load, residual,
                                np.zeros(model.yarn_count, np.int64))
        return positions, record, evaluations

    with single_threaded_blas() as limited:
        positions, record, evaluations = solve()
        wall = _timed(solve, plan.lbfgs_repeats, plan.min_timed)
    point = _base_point("lbfgs", "lbfgs", "scipy L-BFGS-B", tolerance)
    point["blas_single_thread"] = limited
    point.update(measure(case, positions, record))
    if point["residual_N"] > tolerance:
        point["status"] = "stalled"
        point["message"] = ("L-BFGS-B stopped above gtol: the energy no longer decreases "
                            "in float64")
    point.update({"wall_time_s": wall, "iterations": evaluations, "force_evaluations": evaluations,
                  "_elapsed": time.perf_counter() - began})
    return point


# --------------------------------------------------------------------------
# The cheapest methods.


def _brief(point: dict | None) -> dict | None:
    if point is None:
        return None
    return {key: point[key] for key in ("id", "method", "label", "tolerance", "wall_time_s",
                                        "force_evaluations", "relative_error", "residual_N")}


def cheapest_table(points: list[dict], cases: list[Case]) -> list[dict]:
    """Per case and target: the cheapest dynamic point by wall time and by force
    evaluations, beside the static Newton solves (at the scene's tolerance and to the
    floor) and the cheapest L-BFGS-B point."""
    rows = []
    for case in cases:
        mine = [p for p in points if p["case"] == case.key]
        static = next(p for p in mine if p["method"] == "static_newton")
        reference = next(p for p in mine if p["method"] == "static_reference")
        lbfgs = [p for p in usable_points(mine) if p["solver"] == "lbfgs"]
        for target in TARGETS:
            reaching = [p for p in lbfgs if p["relative_error"] <= target]
            fastest = cheapest(mine, target, "wall_time_s")
            rows.append({
                "case": case.key, "title": case.title, "target": target,
                "static_speedup": None if fastest is None
                else fastest["wall_time_s"] / static["wall_time_s"],
                "by_wall_time": _brief(fastest),
                "by_force_evaluations": _brief(cheapest(mine, target, "force_evaluations")),
                "static_newton": _brief(static), "static_reference": _brief(reference),
                "lbfgs": _brief(min(reaching, key=lambda p: p["wall_time_s"]) if reaching
                                else None)})
    return rows


def one_setting_table(points: list[dict], cases: list[Case]) -> list[dict]:
    """Per target: the (method, tolerance) of least total wall time over all cases among
    those reaching the target in every case (one setting for a whole load path)."""
    keys = [case.key for case in cases]
    groups: dict[tuple, dict] = {}
    for p in points:
        if p["solver"] == "dynamic":
            groups.setdefault((p["method"], p["tolerance"]), {})[p["case"]] = p
    rows = []
    for target in TARGETS:
        best = None
        for (method, tolerance), by_case in groups.items():
            if set(by_case) != set(keys) or any(
                    p["status"] == "failed" or p["relative_error"] > target
                    for p in by_case.values()):
                continue
            total = sum(p["wall_time_s"] for p in by_case.values())
            evaluations = sum(p["force_evaluations"] for p in by_case.values())
            if best is None or total < best["total_wall_time_s"]:
                best = {"method": method, "label": next(iter(by_case.values()))["label"],
                        "tolerance": tolerance, "total_wall_time_s": total,
                        "total_force_evaluations": evaluations,
                        "worst_relative_error": max(p["relative_error"]
                                                    for p in by_case.values())}
        static_total = sum(p["wall_time_s"] for p in points if p["method"] == "static_newton")
        rows.append({"target": target, "best": best, "static_newton_total_wall_time_s":
                     static_total})
    return rows


# --------------------------------------------------------------------------
# Files.


def _plan_dict(plan: Plan) -> dict:
    return {"name": plan.name, "crossings": plan.crossings, "segments": plan.segments,
            "tolerances_N": list(plan.tolerances),
            "float32_tolerances_N": list(plan.float32_tolerances),
            "methods": {key: METHODS[key].label for key in plan.methods},
            "friction_methods": {key: METHODS[key].label for key in plan.friction_methods},
            "step_fractions": list(plan.step_fractions), "repeats": plan.repeats,
            "min_timed_s": plan.min_timed, "max_repeats": MAX_REPEATS,
            "lbfgs_repeats": plan.lbfgs_repeats, "max_steps": plan.max_steps,
            "reference_tolerance_N": REFERENCE_TOLERANCE}


def csv_rows(points: list[dict], cases: list[Case]):
    """Tidy rows: one per (point, quantity) with the point's identifying columns."""
    end_units = {case.key: ("N" if case.end_quantity == "end_force" else "m") for case in cases}
    for p in points:
        base = {key: p[key] for key in ("case", "scene", "start_load", "load", "load_units",
                                        "solver", "method", "label", "precision", "masses",
                                        "damping", "damping_coefficient", "safety", "tolerance",
                                        "status")}
        base.update(damping_coefficient_units="1/s" if p["damping_coefficient"] != "" else "",
                    tolerance_units="N")
        for quantity, (units, key) in QUANTITIES.items():
            if p.get(key) is None:
                continue
            if quantity.startswith("end_error"):
                quantity = f"{p['end_quantity']}_{quantity[4:]}"
            units = end_units[p["case"]] if units is None else units
            yield dict(base, quantity=quantity, value=p[key], units=units)
