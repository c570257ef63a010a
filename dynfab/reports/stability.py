"""Stability report (`dynfab stability`): stiff and extreme cases against every dynamic method.

`run_stability(out_dir, quick=False)` takes the paper's yarn (``runs/paper_fig3.toml``
entry K = 0.2 m/N, prestressed, displacement control; the friction cases take Gralen's
law from ``runs/paper_fig5.toml`` entry 0) and changes one thing per case: the Kawabata
law, EA, the mesh, the weft tension, the load (up to 50 % strain, force or displacement
control), friction (alpha 0 to 2, stick stiffness up to 1000 x the default) or the
reference state. Each case is one load step from the as-woven state. For each case:

* the static reference (docs/model.md section 6) of the load step, or its SolverError text; a scene
  the model must refuse (a weft tension at or beyond buckling) records its UserError
  text as the verdict;
* the largest stable time step of symplectic Euler with the physical masses, found by
  bisection exactly as ``tests/test_dynamic_relaxation.py`` defines it: from the relaxed
  (static) state perturbed by N(0, (1e-9 m)^2) on the inner nodes, `BISECTION_STEPS`
  undamped steps (viscous c = 0, tolerance 1e-300) must not be declared diverged by the
  kernel's own checks (residual within `status.DIVERGENCE_FACTOR` of its start, kinetic
  energy within `status.ENERGY_FACTOR` of the work done); bisected geometrically to a
  bracket ratio of `BISECTION_RATIO`. Against it: the step the solver predicts
  (`DynamicSolver.predicted_stable_dt`: Gershgorin on the stiffest tangent of the load
  step, every contact at its bound k_we and every crossing sticking), Gershgorin's bound
  on the actual tangent at the relaxed state, and the exact linear limit 2 / omega_max
  of that tangent (its largest eigenvalue);
* every method (explicit kinetic, viscous, FIRE; semi_implicit) on the load step, with
  `max_steps` bounded per case so that the run ends: its time steps and wall time and
  the largest position error against the static reference relative to A_wa, next to
  the bound ||K^-1||_inf (r + r_static) / A_wa that the residuals allow (derivation in
  ``tests/test_dynamic_relaxation.py``); or the SolverError text (a divergence names
  the time step it was caught at, and the state before the load step is kept).

Path cases (`PathCase`, ``summary["paths"]``): the friction yarn driven through
`FRICTION_PATH` (force control: loading to 10 mN, unloading to zero, reloading) at
N = 224, 1792 and 3584, every method against the static reference, each load step from
the method's own last state; the verdict names the load step a method stopped at and its
message. --quick runs it on the quick yarn under displacement control (the static end
displacements of the force path), with the methods the tests compile.

Explicit methods on meshes finer than `EXTRAPOLATE_ABOVE` segments are not run: their
step count is extrapolated from the measured ones at N = 224, 448, 896 with the fitted
exponent and judged against max_steps.

Files written into `out_dir`: ``stability.md`` (the table), ``stability.csv`` (one row
per case and method, with units), ``summary.json`` (everything, with the machine and
the wall time) and ``map.png`` (measured against predicted stable step, log-log, with
y = x). ``quick=True`` takes the paper yarn cut to 4 crossings (N = 56, the same
crossing spacing, weft and mesh density; loads as the same strains) and one case per
family, with only the kernel variants the dynamic tests compile (`QUICK_METHODS`).
"""

from __future__ import annotations

import math
import time
import warnings
from dataclasses import replace
from typing import Callable

import numpy as np

from dynfab.model import assembly
from dynfab.linalg.banded import BANDWIDTH, to_dense
from dynfab.solvers.dynamic import DynamicSolver
from dynfab.errors import UserError, SolverError
from dynfab.kernels import status
from dynfab.model.yarn import initial_state
from dynfab.model.builders import build_model
from dynfab.plots.style import save_png
from dynfab.reports.common import (cut_yarn, default_stick_stiffness, kernel_name,
                                   output_folder, paper_yarns as common_paper_yarns,
                                   report_header, with_load, write_csv, write_summary, write_text)
from dynfab.reports.stability_cases import (EXPLICIT, FULL, METHODS, QUICK, QUICK_METHODS, Case,
                                            PathCase, Plan, short_number)
from dynfab.reports.stability_plots import plot_map
from dynfab.reports.stability_tables import stability_markdown
from dynfab.scene import Dynamic, Scene, with_key
from dynfab.solvers.static import StaticSolver

PERTURBATION = 1e-9
"""Standard deviation [m] of the random displacement of the inner nodes before a bisection
trial (as the dynamic tests): excites every mode, well inside the linear range."""
BISECTION_STEPS = 3000
"""Undamped time steps of one bisection trial (as the dynamic tests). A mode at a fraction e
above its stability limit grows by about exp(2 sqrt(2 e)) a step, so 3000 steps expose
e >= 3e-6: the finite trial biases the result by far less than the bracket."""
BISECTION_RATIO = 1.02
"""Bisection stops when unstable / stable dt is below this [-] (as the dynamic tests)."""
BISECTION_RANGE = (0.5, 4.0)
"""First bracket, as multiples of the predicted dt; widened by 4 (or halved) while needed."""
MAX_WIDENINGS = 10
"""Times the first bracket may be widened before the bisection gives up (a stated verdict)."""
EXTRAPOLATE_ABOVE = 896
"""Explicit methods on finer meshes are extrapolated from N = 224, 448, 896, not run."""
EXPLICIT_MAX_STEPS = 200_000
"""max_steps of the explicit methods in every case (what a case that reaches it costs:
docs/results.md, "The stability report's step limit")."""
SEMI_IMPLICIT_MAX_STEPS = 2_000
"""max_steps of semi_implicit (far above the steps it takes where it converges:
docs/results.md, "semi_implicit's steps per load step")."""

PATH_MAX_STEPS = {"explicit": 1_000_000, "semi_implicit": 20_000}
"""max_steps per load step of the path cases (the solver's default for the explicit methods:
a failure there is what a user meets)."""

QUICK_SKIPPED = {"verdict": "skipped", "message": "--quick: this method's kernel variant is not "
                 "among those the dynamic tests compile"}
"""The result of a method --quick does not run (`QUICK_METHODS`)."""


CSV_COLUMNS = ("case", "family", "label", "segments", "control", "load", "load_units",
               "reference", "friction", "predicted_dt_s", "measured_dt_s",
               "measured_over_predicted", "gershgorin_actual_dt_s", "linear_dt_s",
               "dt_measured_with", "method", "verdict", "time_steps", "wall_time_s",
               "residual_N", "error_over_A_wa", "bound_over_A_wa", "message")


def run_stability(out_dir, *, quick: bool = False,
                  progress: Callable[[str], None] | None = None) -> dict:
    """Run every case of the plan, write the table, CSV, JSON and map; return the summary.

    `progress` receives one line per solve (None: silent). Raises UserError when
    `out_dir` cannot be a folder or the paper scenes are missing; a case's own
    failures are verdicts, never exceptions.
    """
    out = output_folder(out_dir)
    plan = QUICK if quick else FULL
    started = time.perf_counter()
    bases = paper_yarns(plan)
    runner = _Runner(plan, quick, progress)
    cases = [runner.run(case, bases) for case in plan.cases]
    paths = [runner.run_path(path, bases[True]) for path in plan.paths]
    mesh_fit = extrapolate_mesh(cases)
    summary = {
        **report_header("stability", plan.name, quick),
        "settings": {"perturbation_m": PERTURBATION, "bisection_steps": BISECTION_STEPS,
                     "bisection_ratio": BISECTION_RATIO, "explicit_max_steps": EXPLICIT_MAX_STEPS,
                     "semi_implicit_max_steps": SEMI_IMPLICIT_MAX_STEPS,
                     "extrapolate_above_segments": EXTRAPOLATE_ABOVE},
        "kernel_variants": sorted(runner.variants),
        "mesh_fit": mesh_fit,
        "cases": cases,
        "paths": paths,
    }
    files = [write_csv(out / "stability.csv", CSV_COLUMNS, csv_rows(cases), cell=_finite),
             write_text(out / "stability.md", stability_markdown(summary)),
             save_png(plot_map(cases, plan), out / "map.png")]
    return write_summary(out, summary, files, started)


# --------------------------------------------------------------------------
# Scenes.


def paper_yarns(plan: Plan) -> dict[bool, Scene]:
    """{friction: scene}: the paper yarn (K = 0.2 m/N) without and with Gralen friction,
    cut to `plan.crossings` at the same spacing (weft unchanged), `plan.segments`."""
    frictionless, friction = common_paper_yarns("the stability report")
    return {False: cut_yarn(frictionless, plan.crossings, plan.segments),
            True: cut_yarn(friction, plan.crossings, plan.segments)}


def case_scene(case: Case, base: Scene, load: float) -> Scene:
    """The case's scene: `base` with the case's changes and one load step `load`.

    Keys: any dotted scene key; "kawabata_K" / "kawabata_C" set both yarns; "EA_factor"
    multiplies warp.EA; "stick_factor" sets k_t to that multiple of the default
    EA / (L / N); "alpha_we" sets P_we = alpha_we Pcr_we; "k_we_factor" sets P_we so
    that k_we (prop. to 1 + alpha_we / N_wa^2, docs/model.md section 3) is that many times its
    P_we = 0 value. Raises UserError for a scene the model refuses.
    """
    scene = base
    for key, value in case.changes:
        if key in ("kawabata_K", "kawabata_C"):
            scene = with_key(with_key(scene, f"warp.{key}", value), f"weft.{key}", value)
        elif key == "EA_factor":
            scene = with_key(scene, "warp.EA", scene.warp.EA * value)
        elif key == "stick_factor":
            scene = with_key(scene, "friction.stick_stiffness",
                             value * default_stick_stiffness(scene))
        elif key == "alpha_we":
            scene = with_key(scene, "weft.tension", value * buckling_load(scene))
        elif key == "k_we_factor":
            alpha = (value - 1.0) * scene.weft.count ** 2
            scene = with_key(scene, "weft.tension", alpha * buckling_load(scene))
        else:
            scene = with_key(scene, key, value)
    return with_load(scene, case.control, (load,))


def buckling_load(scene: Scene) -> float:
    """Pcr_we = pi^2 EI_we / L_we^2 [N] (docs/model.md section 3)."""
    return math.pi ** 2 * scene.weft.EI / scene.weft.length ** 2


# --------------------------------------------------------------------------
# One case.


class _Runner:
    """Runs the cases one by one; keeps the kernel variants used and writes progress."""

    def __init__(self, plan: Plan, quick: bool, progress):
        self.plan, self.quick, self.progress = plan, quick, progress
        self.variants: set[str] = set()
        self.done = 0

    def say(self, text: str) -> None:
        if self.progress is not None:
            self.progress(text)

    def run(self, case: Case, bases: dict[bool, Scene]) -> dict:
        """Every result of one case (a JSON-ready dict); failures are recorded, not raised."""
        self.done += 1
        where = f"[{self.done:>2}/{len(self.plan.cases)}] {case.name}"
        base = bases[case.friction]
        record = {"case": case.name, "family": case.family, "label": case.label,
                  "control": case.control, "strain": case.strain, "friction": case.friction,
                  "segments": base.geometry.segments, "load": None, "refused": None,
                  "static": None, "stability": None, "methods": {}}
        displacement = case.strain * base.geometry.length
        try:
            scene = case_scene(replace(case, control="displacement"), base, displacement)
            if case.control == "force":
                scene = case_scene(case, base, self._reaction(scene, displacement))
        except UserError as error:
            record["refused"] = str(error)
            self.say(f"{where}: refused: {error}")
            return record
        except SolverError as error:  # the static solve that gives the force failed
            record["static"] = {"failed": str(error)}
            self.say(f"{where}: no reaction force for force control: {error}")
            return record
        model = build_model(scene)
        load = float(model.load_values[0])
        record.update(segments=scene.geometry.segments, load=load,
                      load_units="N" if case.control == "force" else "m",
                      reference=scene.geometry.reference, amplitude=scene.geometry.amplitude,
                      contact_law=model.yarns[0].contact_law.tolist(),
                      stick_stiffness=model.yarns[0].stick_stiffness or None,
                      stretch_stiffness_max=float(model.yarns[0].stretch_stiffness.max()),
                      weft_tension=scene.weft.tension)
        start = initial_state(model)
        static_state, static_record = self._static(model, start, load, record, where)
        states = {}
        for name in METHODS:
            result, state = self._method(name, model, start, load, static_state,
                                         static_record, record["static"], case, where)
            record["methods"][name] = result
            if state is not None:
                states[name] = state
        relaxed = static_state if static_state is not None else next(iter(states.values()), None)
        record["stability"] = self._stability(model, relaxed, load, case, where)
        return record

    def run_path(self, path: PathCase, base: Scene) -> dict:
        """The static reference and every method along a friction load path (a JSON-ready
        dict); a method's failure is its verdict, with the load step it stopped at."""
        where = f"[path] {path.name}"
        scene = with_key(base, "geometry.segments", path.segments)
        scene = with_load(scene, "force", path.values)
        model = build_model(scene)
        record = {"case": path.name, "segments": path.segments, "values": list(path.values),
                  "control": path.control, "static": None, "methods": {}}
        static = self._static_path(model)
        record["static"] = static
        if "failed" in static:
            self.say(f"{where}: static reference failed: {static['failed']}")
            return record
        self.say(f"{where}: static reference: {sum(static['iterations'])} Newton iterations")
        if path.control == "displacement":
            scene = with_load(scene, "displacement", tuple(static["end_displacement_m"]))
            model = build_model(scene)
            static = self._static_path(model)
            record["static_displacement_control"] = static
        for name in METHODS:
            if self.quick and name not in QUICK_METHODS.get((path.control, True), ()):
                record["methods"][name] = dict(QUICK_SKIPPED)
                continue
            record["methods"][name] = self._method_path(name, model, static, where)
        return record

    @staticmethod
    def _static_path(model) -> dict:
        """The static reference along the model's load path: per load step, the end
        displacement [m], the end force [N], iterations and residual; or {"failed": text}."""
        solver, state, steps = StaticSolver(model), initial_state(model), []
        try:
            for value in model.load_values:
                state, step = solver.step(state, float(value))
                steps.append(step)
        except SolverError as error:
            return {"failed": str(error), "finished_load_steps": len(steps)}
        return {"end_displacement_m": [float(s["end_displacement"][0]) for s in steps],
                "end_force_N": [float(s["end_force"][0]) for s in steps],
                "iterations": [int(s["iterations"][0]) for s in steps],
                "residual_N": [float(s["residual"][0]) for s in steps]}

    def _method_path(self, name: str, model, static: dict, where: str) -> dict:
        """One method along the load path: time steps per load step, wall time, the largest
        end displacement (force control) or end force (displacement control) difference
        from the static reference; or the SolverError text and the load step it stopped at."""
        explicit = name in EXPLICIT
        options = replace(METHODS[name], max_steps=PATH_MAX_STEPS[
            "explicit" if explicit else "semi_implicit"])
        solver = DynamicSolver(model, options)
        self.variants.add(kernel_name(solver))
        key, reference = (("end_displacement", static["end_displacement_m"])
                          if model.control == "force" else ("end_force", static["end_force_N"]))
        state, steps, differences = initial_state(model), [], []
        result = {"max_steps": options.max_steps}
        started = time.perf_counter()
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            for k, value in enumerate(model.load_values):
                try:
                    state, step = solver.step(state, float(value))
                except SolverError as error:
                    steps.append(int(solver.last_relaxation()["time_steps"][0]))
                    result.update(verdict="failed", message=str(error), failed_load_step=k + 1,
                                  time_steps=steps, wall_time_s=time.perf_counter() - started)
                    self.say(f"{where}: {name}: FAILED at load step {k + 1} after {steps[-1]} "
                             f"time steps: {error}")
                    return result
                steps.append(int(step["time_steps"][0]))
                differences.append(abs(float(step[key][0]) - reference[k]))
        result.update(verdict="converged", time_steps=steps,
                      wall_time_s=time.perf_counter() - started,
                      largest_difference=max(differences),
                      largest_difference_units="m" if key == "end_displacement" else "N",
                      relative_difference=max(differences) / max(abs(r) for r in reference))
        self.say(f"{where}: {name}: {sum(steps)} time steps, {result['wall_time_s']:.2f} s, "
                 f"largest {key} difference {result['largest_difference']:.2g} "
                 f"{result['largest_difference_units']}")
        return result

    @staticmethod
    def _reaction(scene: Scene, displacement: float) -> float:
        """P [N]: the static reaction of `scene` (displacement control) at `displacement`."""
        model = build_model(scene)
        _, record = StaticSolver(model).step(initial_state(model), displacement)
        return float(record["end_force"][0])

    def _static(self, model, start, load: float, record: dict, where: str):
        """The static reference of the load step; (state, step record) or (None, None)."""
        started = time.perf_counter()
        try:
            state, step = StaticSolver(model).step(start, load)
        except SolverError as error:
            record["static"] = {"failed": str(error)}
            self.say(f"{where}: static reference failed: {error}")
            return None, None
        elapsed = time.perf_counter() - started
        law = model.yarns[0].contact_law
        R = step["contact_force"][0]
        norm = inverse_stiffness_norm(model, model.per_yarn(state.positions)[0],
                                      step["anchors"][0], coupled="friction" in model.terms)
        record["static"] = {
            "iterations": int(step["iterations"][0]), "residual_N": float(step["residual"][0]),
            "rounding_floor": bool(step["rounding_floor"][0]), "wall_time_s": elapsed,
            "end_force_N": float(step["end_force"][0]),
            "end_displacement_m": float(step["end_displacement"][0]),
            "max_contact_force_N": float(R.max()) if R.size else 0.0,
            "closed_crossings": int((R > 0).sum()),
            "sliding_crossings": int(step["sliding"][0].sum()),
            # delta_m / C_m = 1 - exp(-a_m R) at the largest contact force (docs/model.md section 3)
            "compression_saturation": [float(1 - np.exp(-law[2] * R.max())),
                                       float(1 - np.exp(-law[4] * R.max()))] if R.size else None,
            "inverse_stiffness_norm_m_per_N": norm,
        }
        self.say(f"{where}: static reference: {record['static']['iterations']} Newton iterations, "
                 f"residual {step['residual'][0]:.2g} N, P = {step['end_force'][0]:.4g} N")
        return state, step

    def _method(self, name, model, start, load, static_state, static_record, norms, case, where):
        """One method on the load step: (result dict, final state or None)."""
        explicit = name in EXPLICIT
        if explicit and model.segments > EXTRAPOLATE_ABOVE:
            return {"verdict": "extrapolated"}, None  # filled in by extrapolate_mesh
        if self.quick and name not in QUICK_METHODS.get((case.control, case.friction), ()):
            return dict(QUICK_SKIPPED), None
        max_steps = EXPLICIT_MAX_STEPS if explicit else SEMI_IMPLICIT_MAX_STEPS
        options = replace(METHODS[name], max_steps=max_steps)
        solver = DynamicSolver(model, options)
        self.variants.add(kernel_name(solver))
        solver.predicted_stable_dt(start, load)  # compiles (or loads) the kernel outside the timing
        result = {"max_steps": max_steps}
        started = time.perf_counter()
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            try:
                state, step = solver.step(start, load)
            except SolverError as error:
                elapsed = time.perf_counter() - started
                steps = int(solver.last_relaxation()["time_steps"][0])
                result.update(verdict="failed", message=str(error), time_steps=steps,
                              wall_time_s=elapsed, failed_load_step=1,
                              last_good_state={"load_step": 0, "finite": bool(
                                  np.isfinite(start.positions).all())})
                self.say(f"{where}: {name}: FAILED after {steps} time steps, {elapsed:.2f} s: "
                         f"{error}")
                return result, None
        elapsed = time.perf_counter() - started
        result.update(verdict="converged", time_steps=int(step["time_steps"][0]),
                      wall_time_s=elapsed, residual_N=float(step["residual"][0]),
                      rounding_floor=any("rounding floor" in str(w.message) for w in caught))
        if static_state is not None:
            error = np.abs(state.positions - static_state.positions).max()
            amplitude = model.scene.geometry.amplitude
            norm = norms.get("inverse_stiffness_norm_m_per_N")
            bound = None if norm is None else norm * (result["residual_N"]
                                                       + float(static_record["residual"][0]))
            result.update(error_m=float(error), error_over_A_wa=float(error / amplitude),
                          bound_over_A_wa=float(bound / amplitude) if bound is not None else None,
                          same_sliding=bool((step["sliding"] == static_record["sliding"]).all()))
        self.say(f"{where}: {name}: {result['time_steps']} time steps, {elapsed:.3f} s, residual "
                 f"{result['residual_N']:.2g} N, error/A_wa "
                 f"{short_number(result.get('error_over_A_wa'))}")
        return result, state

    def _relax_at(self, model, load: float, dt: float, where: str) -> dict:
        """The load step relaxed from the as-woven state with the physical masses and kinetic
        damping at a fixed `dt` [s]: does the energy-stable step also converge?"""
        if model.segments > EXTRAPOLATE_ABOVE:
            return {"verdict": "not run", "message": f"N > {EXTRAPOLATE_ABOVE}"}
        options = Dynamic(damping="kinetic", masses="physical", dt=dt,
                          max_steps=EXPLICIT_MAX_STEPS)
        solver = DynamicSolver(model, options)
        self.variants.add(kernel_name(solver))
        started = time.perf_counter()
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            try:
                _, step = solver.step(initial_state(model), load)
            except SolverError as error:
                steps = int(solver.last_relaxation()["time_steps"][0])
                self.say(f"{where}: physical masses at the measured dt {dt:.3g} s: FAILED after "
                         f"{steps} time steps: {error}")
                return {"verdict": "failed", "dt_s": dt, "message": str(error),
                        "time_steps": steps, "wall_time_s": time.perf_counter() - started}
        return {"verdict": "converged", "dt_s": dt, "time_steps": int(step["time_steps"][0]),
                "wall_time_s": time.perf_counter() - started}

    def _stability(self, model, relaxed, load: float, case: Case, where: str) -> dict | None:
        """Predicted and measured stable dt from the relaxed state (None without one)."""
        if relaxed is None:
            return {"message": "no relaxed state (the static reference and every method failed)"}
        allowed = QUICK_METHODS.get((case.control, case.friction), ()) if self.quick else METHODS
        damping = "viscous" if "viscous" in allowed else "kinetic"
        started = time.perf_counter()
        result = measure_stable_dt(model, relaxed, load, damping=damping, variants=self.variants)
        if case.friction and damping == "viscous":  # the quick plan's kinetic fallback, checked
            check = measure_stable_dt(model, relaxed, load, damping="kinetic", variants=self.variants)
            result["kinetic_damping_check_dt_s"] = check.get("measured_dt_s")
        result.update(linear_stable_dts(model, relaxed))
        if result.get("measured_dt_s") is not None:
            result["relaxation_at_measured_dt"] = self._relax_at(model, load,
                                                                 result["measured_dt_s"], where)
        result["wall_time_s"] = time.perf_counter() - started
        if result.get("measured_dt_s") is not None:
            result["measured_over_predicted"] = result["measured_dt_s"] / result["predicted_dt_s"]
        self.say(f"{where}: stable dt: predicted {result['predicted_dt_s']:.3g} s, measured "
                 f"{short_number(result.get('measured_dt_s'))} s ({result['measured_with']}, "
                 f"{result['trials']} trials), linear {result['linear_dt_s']:.3g} s; relaxation "
                 f"at the measured dt: {result.get('relaxation_at_measured_dt', {}).get('verdict')}")
        return result


# --------------------------------------------------------------------------
# Stable time step.


def measure_stable_dt(model, relaxed, load: float, *, damping: str = "viscous",
                      steps: int = BISECTION_STEPS, seed: int = 5, variants: set | None = None) -> dict:
    """The largest stable dt [s] of symplectic Euler with physical masses, by bisection.

    A trial runs `steps` time steps of the explicit relaxation kernel at a fixed dt from
    `relaxed` perturbed by N(0, PERTURBATION^2) on the inner nodes, with viscous c = 0
    (`damping="viscous"`: undamped, the definition of the dynamic tests) or kinetic
    damping (`"kinetic"`, used where the undamped variant is not to be compiled). A mode
    that grows without bound has a kinetic energy that rises every step, never meets the
    peak that would reset it, and is caught as when undamped: without friction both give
    the same threshold. With friction they differ: stick/slip switching makes the motion
    a switched system, which slowly pumps energy into an undamped motion below the linear
    limit of each of its pieces, and kinetic damping's resets remove that energy; its
    threshold is then higher (the full report measures both: docs/results.md, "Stability").

    A trial is unstable when the kernel reports divergence: the residual beyond
    DIVERGENCE_FACTOR x its start, a non-finite state, or (the test that catches the fine
    meshes, where an unstable chain folds and its forces saturate before the residual
    test trips) a kinetic energy beyond status.ENERGY_FACTOR x the work the forces can
    have done since the start (`dynfab.kernels.structure_checks`). Returns predicted, measured
    (largest stable) and smallest unstable dt, the trial count, how many unstable trials
    the energy test caught, and the method.
    """
    rng = np.random.default_rng(seed)
    perturbed = relaxed.copy()
    inner = model.per_yarn(perturbed.positions)[:, 1:-1]  # a view of the state's (n, 2)
    inner += rng.normal(0.0, PERTURBATION, inner.shape)
    options = Dynamic(damping=damping, damping_coefficient=0.0 if damping == "viscous" else None,
                      masses="physical")
    probe = DynamicSolver(model, options)
    if variants is not None:
        variants.add(kernel_name(probe))
    predicted = float(probe.predicted_stable_dt(perturbed, load)[0])
    trials, by_energy = 0, []

    def stable(dt: float) -> bool:
        nonlocal trials
        trials += 1
        solver = DynamicSolver(model, replace(options, dt=dt, tolerance=1e-300, max_steps=steps))
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            try:
                solver.step(perturbed, load)
            except SolverError as error:
                if "diverged" in str(error):
                    if (solver.last_relaxation()["energy_ratio"] > status.ENERGY_FACTOR).any():
                        by_energy.append(dt)
                    return False
        return True

    result = {"predicted_dt_s": predicted, "measured_dt_s": None, "unstable_dt_s": None,
              "measured_with": "undamped (viscous c = 0)" if damping == "viscous"
              else "kinetic damping", "trials_steps": steps}
    low, high = BISECTION_RANGE[0] * predicted, BISECTION_RANGE[1] * predicted
    for _ in range(MAX_WIDENINGS):
        if stable(low):
            break
        high, low = low, low / 4.0
    else:
        result.update(trials=trials, message=f"unstable even at {low / predicted:.2g} x the "
                      "predicted dt")
        return result
    for _ in range(MAX_WIDENINGS):
        if not stable(high):
            break
        low, high = high, high * 4.0
    else:
        result.update(trials=trials, measured_dt_s=low, message=f"stable up to "
                      f"{low / predicted:.3g} x the predicted dt (bisection range exhausted)")
        return result
    while high / low > BISECTION_RATIO:
        middle = math.sqrt(low * high)
        if stable(middle):
            low = middle
        else:
            high = middle
    result.update(trials=trials, measured_dt_s=low, unstable_dt_s=high,
                  caught_by_energy=len(by_energy))
    return result


def tangent_band(model, positions: np.ndarray, anchors: np.ndarray, coupled: bool) -> np.ndarray:
    """The banded tangent K [N/m] of yarn 0 at `positions` (actual contact tangents, Huber
    curvature as assembled; with `coupled`, the friction Jacobian of the static solver)."""
    return assembly.tangent(positions, model.yarns[0], anchors, coupled)


def linear_stable_dts(model, relaxed) -> dict:
    """dt [s] from the tangent at the relaxed state (yarn 0, physical masses):
    Gershgorin's 2 min_i sqrt(m_i / max row sum of the node) over every node as the solver
    takes it but on the actual tangent, and the exact linear limit 2 / omega_max,
    omega_max^2 the largest eigenvalue of M^-1/2 K M^-1/2 over the free dofs."""
    band = tangent_band(model, model.per_yarn(relaxed.positions)[0],
                        model.per_crossing(relaxed.anchors)[0], coupled=False)
    mass = np.repeat(model.yarns[0].mass, 2)
    rows = np.abs(band).sum(axis=1)
    node_rows = np.maximum(rows[0::2], rows[1::2])
    positive = node_rows > 0
    gershgorin = float(2.0 * np.sqrt(model.yarns[0].mass[positive] / node_rows[positive]).min())
    free = np.flatnonzero(~model.fixed_dofs())
    first, last = free[0], free[-1] + 1
    assert free.size == last - first, "the free dofs are contiguous"
    scale = 1.0 / np.sqrt(mass[first:last])
    scaled = band[first:last].copy()
    for offset in range(-BANDWIDTH, BANDWIDTH + 1):
        rows_ = np.arange(max(0, -offset), min(scaled.shape[0], scaled.shape[0] - offset))
        scaled[rows_, offset + BANDWIDTH] *= scale[rows_] * scale[rows_ + offset]
    largest = _largest_symmetric_eigenvalue(scaled)
    return {"gershgorin_actual_dt_s": gershgorin,
            "linear_dt_s": float(2.0 / math.sqrt(largest)) if largest > 0 else None}


def _largest_symmetric_eigenvalue(band: np.ndarray) -> float:
    """lambda_max of a symmetric banded matrix (`dynfab.linalg.banded` layout)."""
    n = band.shape[0]
    try:
        from scipy.linalg import eigvals_banded
    except ImportError:  # scipy is optional: the dense matrix (slower for large N)
        return float(np.linalg.eigvalsh(to_dense(band))[-1])
    upper = np.zeros((BANDWIDTH + 1, n))  # LAPACK upper storage: a[u + i - j, j] = A[i, j]
    for offset in range(BANDWIDTH + 1):
        upper[BANDWIDTH - offset, offset:] = band[:n - offset, BANDWIDTH + offset]
    return float(eigvals_banded(upper, select="i", select_range=(n - 1, n - 1))[0])


def inverse_stiffness_norm(model, positions: np.ndarray, anchors: np.ndarray,
                           coupled: bool) -> float | None:
    """||K^-1||_inf [m/N] over the free dofs of yarn 0 (coupled: the friction Jacobian),
    as tests/test_dynamic_relaxation.py; None if K is singular."""
    band = tangent_band(model, positions, anchors, coupled)
    free = ~model.fixed_dofs()
    matrix = to_dense(band)[np.ix_(free, free)]
    try:
        inverse = np.linalg.inv(matrix)
    except np.linalg.LinAlgError:
        return None
    norm = float(np.abs(inverse).sum(axis=1).max())
    return norm if math.isfinite(norm) else None


# --------------------------------------------------------------------------
# Explicit methods on fine meshes: extrapolated.


def fit_power_law(segments, steps) -> tuple[float, float]:
    """(exponent p, prefactor c) of the least-squares line log steps = log c + p log N."""
    p, log_c = np.polyfit(np.log(np.asarray(segments, float)), np.log(np.asarray(steps, float)), 1)
    return float(p), float(math.exp(log_c))


def extrapolate_mesh(cases: list[dict]) -> dict:
    """Fit steps = c N^p of each explicit method over the measured meshes (baseline and
    mesh cases with N <= EXTRAPOLATE_ABOVE) and give every finer mesh case its verdict:
    the predicted step count against max_steps. Returns the fits."""
    measured = [c for c in cases if c["family"] in ("baseline", "mesh") and c["refused"] is None
                and c["segments"] <= EXTRAPOLATE_ABOVE]
    finer = [c for c in cases if c["family"] == "mesh" and c["segments"] > EXTRAPOLATE_ABOVE]
    fits = {}
    for name in EXPLICIT:
        points = [(c["segments"], c["methods"][name]) for c in measured
                  if c["methods"].get(name, {}).get("verdict") == "converged"]
        if len(points) < 2:
            continue
        segments = [n for n, _ in points]
        exponent, prefactor = fit_power_law(segments, [r["time_steps"] for _, r in points])
        time_per_node_step = float(np.mean([r["wall_time_s"] / (r["time_steps"] * (n + 1))
                                            for n, r in points]))
        steps = [r["time_steps"] for _, r in points]
        fits[name] = {"segments": segments, "time_steps": steps, "exponent": exponent,
                      "prefactor": prefactor, "time_per_node_step_s": time_per_node_step,
                      # the slope between the two finest meshes: a fit that mixes it with the
                      # coarser, pre-asymptotic ones under-reads the growth
                      "local_exponent": float(math.log(steps[-1] / steps[-2])
                                              / math.log(segments[-1] / segments[-2]))}
        for case in finer:
            n = case["segments"]
            predicted = prefactor * n ** exponent
            over = predicted > EXPLICIT_MAX_STEPS
            verdict = "extrapolated: max_steps" if over else "extrapolated: converges"
            case["methods"][name] = {
                "verdict": verdict, "predicted_time_steps": predicted,
                "predicted_wall_time_s": predicted * (n + 1) * time_per_node_step,
                "max_steps": EXPLICIT_MAX_STEPS,
                "message": (f"not run: {predicted:.3g} time steps predicted (steps = "
                            f"{prefactor:.3g} N^{exponent:.2f}, fitted at N = "
                            f"{', '.join(str(s) for s in segments)}) "
                            + (f"> max_steps = {EXPLICIT_MAX_STEPS}: would stop without "
                               "convergence" if over else
                               f"<= max_steps = {EXPLICIT_MAX_STEPS}: would converge in about "
                               f"{predicted * (n + 1) * time_per_node_step:.2g} s"))}
    return fits


# --------------------------------------------------------------------------
# Files.


def _finite(value):
    """A CSV cell: '' for None or a non-finite number, repr for floats."""
    if value is None:
        return ""
    if isinstance(value, (float, np.floating)):
        return repr(float(value)) if math.isfinite(value) else ""
    return value


def csv_rows(cases: list[dict]) -> list[dict]:
    """One row per (case, method); a refused case has one row per method with its message."""
    rows = []
    for case in cases:
        stability = case.get("stability") or {}
        for name in METHODS:
            method = case["methods"].get(name, {})
            verdict = "refused" if case["refused"] is not None else method.get("verdict", "")
            message = case["refused"] or method.get("message", "")
            rows.append({
                "case": case["case"], "family": case["family"], "label": case["label"],
                "segments": case["segments"], "control": case["control"], "load": case["load"],
                "load_units": case.get("load_units", ""), "reference": case.get("reference", ""),
                "friction": case["friction"],
                **{key: stability.get(key) for key in (
                    "predicted_dt_s", "measured_dt_s", "measured_over_predicted",
                    "gershgorin_actual_dt_s", "linear_dt_s")},
                "dt_measured_with": stability.get("measured_with", ""),
                "method": name, "verdict": verdict,
                "time_steps": method.get("time_steps", method.get("predicted_time_steps")),
                "wall_time_s": method.get("wall_time_s", method.get("predicted_wall_time_s")),
                **{key: method.get(key)
                   for key in ("residual_N", "error_over_A_wa", "bound_over_A_wa")},
                "message": message})
    return rows
