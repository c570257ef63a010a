"""Benchmark of the dynamic solver (docs/model.md section 5): one load step of the paper yarn, per
method.

The case: the paper yarn (runs/paper_fig3.toml at K = 0.2 m/N, prestressed) under
force control, relaxed by the static solver at P = 0.2 N; each dynamic method then
relaxes it to P = 0.3 N at the 1e-8 N tolerance. Wall times are warm (a first
untimed run compiles and loads the kernels) and the best of a few repeats (the
least disturbed by other processes on a shared machine); every ratio below is of
two figures measured in this one run.

1. Scaling with the mesh: N = 224, 448, 896 segments with every method (explicit
   with kinetic, viscous or FIRE damping; semi_implicit), and semi_implicit on to
   N = 3584: time steps, force evaluations, warm wall time; the exponent of a
   least-squares fit of log(steps) and log(time) against log(N) per method (and the
   local exponent between successive N).
2. Batched yarns: [sweep] of 1, 8 and 64 copies of the yarn (warp.kawabata_K =
   0.2 (1 + 1e-6 k), nearly equal), kinetic damping and semi_implicit: wall time
   per yarn on one core (one launch of all yarns) and split across the cores
   (`DynamicSolver.use_cores`), checking that both give bit-identical positions.
3. semi_implicit against the static Newton solver (`StaticSolver.step`) on the same
   step from the same state, at the same 1e-8 N tolerance and at the static
   default 1e-11 N.
4. The cost of one explicit time step per node [ns], Warp's kernel beside a plain
   numba loop doing the same step (the `dynfab.model.assembly` forces, the residual and the
   kinetic-damping update), N = 224.

Aims (the table ends with each and "met" / "NOT met"): Warp's explicit step within
1.2x numba's per node; the best explicit method within 10,000 time steps (N = 224);
semi_implicit within 10x the static Newton time (N = 224, same tolerance); the
64-yarn sweep within 1.2x the per-yarn time of a one-yarn run (each method, on the
cores available).

Run: python benchmarks/dynamic.py   (prints the tables, writes benchmarks/dynamic.json)
"""

import json
import os
import platform
import time
from dataclasses import replace
from pathlib import Path

import numba
import numpy as np
import warp as wp

from dynfab.model import assembly
from dynfab.solvers.dynamic import DynamicSolver, available_cores
from dynfab.model.yarn import initial_state
from dynfab.model.builders import build_model
from dynfab.scene import Dynamic, load_scene, validate_scene, with_key
from dynfab.solvers.static import StaticSolver
from dynfab.timing import best_time

HERE = Path(__file__).resolve().parent
METHODS = {
    "explicit, kinetic damping": Dynamic(damping="kinetic"),
    "explicit, viscous (adaptive c)": Dynamic(damping="viscous"),
    "explicit, FIRE 2.0": Dynamic(damping="fire"),
    "semi_implicit": Dynamic(method="semi_implicit"),
}
EXPLICIT_SEGMENTS = (224, 448, 896)
"""Meshes of the scaling study, every method."""
SEMI_IMPLICIT_SEGMENTS = (224, 448, 896, 1792, 3584)
"""Meshes of the scaling study, semi_implicit."""
PAPER_SEGMENTS = 224
"""The paper's mesh: the aims on steps, the static comparison and the step cost."""
SWEEP_CASES = ((224, 1), (224, 2), (224, 8), (224, 64), (32, 2))
"""(N, yarns) of the batched runs: the paper mesh with 1 to 64 yarns, and the smallest mesh
of 16 crossings with 2 yarns (where the split has the least work to share)."""
SWEEP_METHODS = ("explicit, kinetic damping", "semi_implicit")
"""Methods of the batched runs."""
START_LOAD, END_LOAD = 0.2, 0.3
"""The load step [N]: from the static equilibrium at START_LOAD to END_LOAD."""
TOLERANCE = 1e-8
"""Residual of the dynamic relaxations [N] (docs/model.md section 5)."""
STEPS_TIMED = 20_000
"""Time steps of the per-step cost measurement."""
REPEATS = 5
"""Timed repetitions of each per-step measurement; the fastest is kept (the least disturbed
by other processes on the machine)."""
TIMING_BUDGET = 1.0
"""Wall time [s] a relaxation is repeated for (at least MIN_REPEATS times, at most REPEATS);
the fastest repeat is kept."""
MIN_REPEATS = 2
TIMING = dict(repeats=MIN_REPEATS, warm=True, until=TIMING_BUDGET, most=REPEATS)
"""`dynfab.timing.best_time` of a relaxation: one untimed call, then at least MIN_REPEATS and
at most REPEATS timed ones within TIMING_BUDGET."""
AIMS = {"warp_step_per_node_over_numba": 1.2, "best_explicit_time_steps": 10_000,
        "semi_implicit_over_static_newton": 10.0, "sweep_64_per_yarn_over_one_yarn": 1.2}
"""The limit of each aim (at most)."""


def paper_yarn(segments: int = PAPER_SEGMENTS, yarns: int = 1):
    """The model of the paper yarn (K = 0.2 m/N, prestressed) under force control with
    `segments` segments; `yarns` > 1: a [sweep] of that many copies, warp.kawabata_K =
    0.2 (1 + 1e-6 k) for copy k (nearly equal: the same work per yarn)."""
    scene = replace(load_scene(HERE.parent / "runs" / "paper_fig3.toml"), sweep=())
    scene = with_key(with_key(scene, "load.control", "force"), "load.values",
                     [START_LOAD, END_LOAD])
    scene = with_key(scene, "geometry.segments", segments)
    if yarns > 1:
        values = tuple(0.2 * (1.0 + 1e-6 * k) for k in range(yarns))
        scene = validate_scene(replace(scene, sweep=(("warp.kawabata_K", values),)))
    return build_model(scene)


def static_start(model):
    """The static equilibrium at START_LOAD from the as-woven state."""
    state, _ = StaticSolver(model).step(initial_state(model), START_LOAD)
    return state


def relax(model, start, options):
    """One method on one model: time steps, force evaluations, warm wall time [s] and the
    residual [N] of the step from START_LOAD to END_LOAD (yarn 0)."""
    solver = DynamicSolver(model, replace(options, tolerance=TOLERANCE))
    elapsed, (_, record) = best_time(lambda: solver.step(start, END_LOAD), **TIMING)
    return {"time_steps": int(record["time_steps"][0]),
            "force_evaluations": int(record["force_evaluations"][0]),
            "wall_time_s": elapsed, "residual_N": float(record["residual"][0])}


def bending_over_stretch(model) -> float:
    """Largest Gershgorin row sum of bending over that of stretching, 16 (EI/lbar) / l0^2 over
    4 EA / l0 at an interior node of a straight chain (stencils 1 -4 6 -4 1 and -1 2 -1 on each
    coordinate): above 1, bending sets the fictitious masses, so the explicit methods' steps go
    as sqrt(lambda_max / lambda_min) ~ sqrt(N^3 N) = N^2 instead of sqrt(N N) = N."""
    yarn = model.yarns[0]
    l0 = float(np.median(yarn.rest_length))
    bending = 16.0 * float(np.median(yarn.bend_stiffness[1:-1])) / l0 ** 2
    return bending / (4.0 * float(np.median(yarn.stretch_stiffness)))


def exponent(segments, values) -> float:
    """Slope of the least-squares line through (log N, log value)."""
    return float(np.polyfit(np.log(segments), np.log(values), 1)[0])


def local_exponents(segments, values) -> list:
    """Slopes of log(value) against log(N) between successive meshes."""
    logs_n, logs_v = np.log(segments), np.log(values)
    return [float(e) for e in np.diff(logs_v) / np.diff(logs_n)]


def scaling():
    """Per method: the rows of every mesh, the fitted exponents; and the static Newton solver
    on the same steps ({"N": ..., "time_s_tolerance_1e-8": ..., ...})."""
    results = {name: {"N": [], "rows": []} for name in METHODS}
    ratios = {}
    static = {"N": [], "time_s_tolerance_1e-8": [], "iterations_tolerance_1e-8": [],
              "time_s_tolerance_1e-11": [], "iterations_tolerance_1e-11": []}
    for segments in SEMI_IMPLICIT_SEGMENTS:
        model = paper_yarn(segments)
        start = static_start(model)
        ratios[segments] = bending_over_stretch(model)
        for name, options in METHODS.items():
            if name == "semi_implicit" or segments in EXPLICIT_SEGMENTS:
                results[name]["N"].append(segments)
                results[name]["rows"].append(relax(model, start, options)
                                             | {"bending_over_stretch": ratios[segments]})
        static["N"].append(segments)
        for tolerance, label in ((TOLERANCE, "1e-8"), (1e-11, "1e-11")):
            solver = StaticSolver(model, tolerance=tolerance)
            elapsed, (_, record) = best_time(lambda: solver.step(start, END_LOAD), **TIMING)
            static[f"time_s_tolerance_{label}"].append(elapsed)
            static[f"iterations_tolerance_{label}"].append(int(record["iterations"][0]))
    for data in results.values():
        steps = [row["time_steps"] for row in data["rows"]]
        times = [row["wall_time_s"] for row in data["rows"]]
        data["exponent_time_steps"] = exponent(data["N"], steps)
        data["exponent_wall_time"] = exponent(data["N"], times)
        data["local_exponents_time_steps"] = local_exponents(data["N"], steps)
        data["local_exponents_wall_time"] = local_exponents(data["N"], times)
    return results, static


def interleaved_best(functions: dict) -> dict:
    """label -> (fastest wall time [s], process CPU time of that call [s] (all threads), last
    result) of warm calls of each function, the functions called in turn, repeat after repeat
    (so that a disturbance by other processes falls on all of them alike): one untimed round,
    then at least MIN_REPEATS and at most REPEATS rounds within 2 TIMING_BUDGET."""
    results = {label: function() for label, function in functions.items()}
    timings = {label: [] for label in functions}
    spent = 0.0
    while (len(timings[next(iter(functions))]) < MIN_REPEATS
           or (len(timings[next(iter(functions))]) < REPEATS and spent < 2 * TIMING_BUDGET)):
        for label, function in functions.items():
            wall, cpu = time.perf_counter(), time.process_time()
            results[label] = function()
            wall, cpu = time.perf_counter() - wall, time.process_time() - cpu
            timings[label].append((wall, cpu))
            spent += wall
    return {label: (*min(timings[label]), results[label]) for label in functions}


def sweep():
    """Per method, a row per (N, yarns) case: wall time [s] per yarn of the batch on one core
    and split over the cores, each / the one-yarn run's at the same N timed in turn with them;
    the cores in use during the split run (process CPU time / wall time); the one-core and
    split positions compared bit for bit."""
    results = {name: [] for name in SWEEP_METHODS}
    cores = available_cores()
    for segments, yarns in SWEEP_CASES:
        model, single = paper_yarn(segments, yarns), paper_yarn(segments)
        start, single_start = static_start(model), static_start(single)
        for name in SWEEP_METHODS:
            options = replace(METHODS[name], tolerance=TOLERANCE)
            reference = DynamicSolver(single, options)
            one_core, split = DynamicSolver(model, options), DynamicSolver(model, options)
            one_core.use_cores(1)
            split.use_cores(cores)
            timed = interleaved_best({
                "one_yarn_run": lambda: reference.step(single_start, END_LOAD),
                "one_core": lambda: one_core.step(start, END_LOAD),
                "split": lambda: split.step(start, END_LOAD)})
            one_yarn = timed["one_yarn_run"][0]
            row = {"N": segments, "yarns": yarns, "one_yarn_run_s": one_yarn}
            for label, solver in (("one_core", one_core), ("split", split)):
                wall, cpu, (_, record) = timed[label]
                row[label] = {"groups": len(solver.ranges), "wall_time_s": wall,
                              "per_yarn_s": wall / yarns,
                              "per_yarn_over_one_yarn_run": wall / yarns / one_yarn,
                              "cores_in_use": cpu / wall,
                              "time_steps_max": int(record["time_steps"].max())}
            row["split_gain"] = row["one_core"]["wall_time_s"] / row["split"]["wall_time_s"]
            row["bit_identical"] = bool(np.array_equal(timed["one_core"][2][0].positions,
                                                       timed["split"][2][0].positions))
            results[name].append(row)
    return results


def sweep_row(rows, segments: int, yarns: int) -> dict:
    """The row of one (N, yarns) case."""
    return next(row for row in rows if row["N"] == segments and row["yarns"] == yarns)


def warp_step_cost(model, start) -> float:
    """ns per node per explicit kinetic-damping time step of the Warp kernel (one launch of
    STEPS_TIMED steps from the load step's start, to a zero tolerance: the kernel's start and
    that launch, `StructureRelaxation.relax`), fastest of REPEATS."""
    solver = DynamicSolver(model, Dynamic(damping="kinetic"))
    relaxation = solver.relaxation
    relaxation.chunk = STEPS_TIMED
    begun = model.start_of_step(start, 0.3)
    costs = []
    for _ in range(1 + REPEATS):  # the first launch loads the kernel
        began = time.perf_counter()
        _, outcome = relaxation.relax(begun.positions, begun.chain_loads, begun.anchors,
                                      tolerance=0.0, max_steps=STEPS_TIMED)
        wp.synchronize()
        elapsed = time.perf_counter() - began
        steps = int(outcome.steps[0])  # fewer if it stalled at the rounding floor
        costs.append(elapsed / (steps * (model.segments + 1)) * 1e9)
    return min(costs[1:])


@numba.njit(cache=True)
def numba_kinetic_steps(pos, vel, mass, yarn, P, anchors, fixed, steps):
    """`steps` explicit kinetic-damping steps (dt = 1 s, fictitious masses) in plain numba:
    the same work per step as the Warp kernel without friction. Returns the last residual."""
    grad = np.zeros_like(pos)
    no_limit = np.zeros(anchors.size)
    flat_fixed = fixed.reshape(pos.shape)
    kinetic, residual = 0.0, 0.0
    for _ in range(steps):
        assembly.gradient(pos, yarn, P, anchors, no_limit, grad)
        residual = 0.0
        trial = 0.0
        for i in range(pos.shape[0]):
            for c in range(2):
                if flat_fixed[i, c]:
                    grad[i, c] = 0.0
                residual = max(residual, abs(grad[i, c]))
                v = vel[i, c] - grad[i, c] / mass[i]
                trial += 0.5 * mass[i] * v * v
        if trial < kinetic:
            for i in range(pos.shape[0]):
                for c in range(2):
                    pos[i, c] -= 0.5 * vel[i, c]
                    vel[i, c] = 0.0
            kinetic = 0.0
        else:
            for i in range(pos.shape[0]):
                for c in range(2):
                    vel[i, c] -= grad[i, c] / mass[i]
                    pos[i, c] += vel[i, c]
            kinetic = trial
    return residual


def numba_step_cost(model, start, masses) -> float:
    """ns per node per time step of `numba_kinetic_steps`, fastest of REPEATS (warm: compiled
    by a first call)."""
    yarn, fixed = model.yarns[0], model.fixed_dofs()
    arguments = (yarn, 0.3, model.per_crossing(start.anchors)[0], fixed)
    first = model.per_yarn(start.positions)[0]
    numba_kinetic_steps(first.copy(), np.zeros_like(first), masses, *arguments, 10)
    costs = []
    for _ in range(REPEATS):
        pos, vel = first.copy(), np.zeros_like(first)
        began = time.perf_counter()
        numba_kinetic_steps(pos, vel, masses, *arguments, STEPS_TIMED)
        elapsed = time.perf_counter() - began
        costs.append(elapsed / (STEPS_TIMED * (model.segments + 1)) * 1e9)
    return min(costs)


def step_cost():
    """Warp's and numba's ns per node per explicit kinetic-damping time step, N = 224."""
    model = paper_yarn()
    start = static_start(model)
    probe = DynamicSolver(model, Dynamic(damping="kinetic"))
    probe.predicted_stable_dt(start, END_LOAD)
    masses = probe.last_relaxation()["masses"]  # the one yarn's nodes
    warp_ns, numba_ns = warp_step_cost(model, start), numba_step_cost(model, start, masses)
    return {"warp": warp_ns, "numba": numba_ns, "ratio": warp_ns / numba_ns}


def judge(results: dict) -> dict:
    """Each aim: the measured value, its limit and whether it is met."""
    methods, static = results["methods"], results["static_newton"]
    paper = static["N"].index(PAPER_SEGMENTS)
    best_name = min((name for name in METHODS if name != "semi_implicit"),
                    key=lambda name: methods[name]["time_steps"])
    sweeps = {name: sweep_row(rows, PAPER_SEGMENTS, 64)["split"]["per_yarn_over_one_yarn_run"]
              for name, rows in results["sweep"].items()}
    worst_sweep = max(sweeps, key=sweeps.get)
    measured = {
        "warp_step_per_node_over_numba": results["step_cost_ns_per_node"]["ratio"],
        "best_explicit_time_steps": methods[best_name]["time_steps"],
        "semi_implicit_over_static_newton": (methods["semi_implicit"]["wall_time_s"]
                                             / static["time_s_tolerance_1e-8"][paper]),
        "sweep_64_per_yarn_over_one_yarn": sweeps[worst_sweep],
    }
    notes = {"warp_step_per_node_over_numba": "N = 224",
             "best_explicit_time_steps": f"N = 224, {best_name}",
             "semi_implicit_over_static_newton": "N = 224, both to 1e-8 N",
             "sweep_64_per_yarn_over_one_yarn": f"split over {available_cores()} cores, worst "
                                                f"method ({worst_sweep})"}
    return {name: {"value": value, "at_most": AIMS[name], "met": bool(value <= AIMS[name]),
                   "where": notes[name]} for name, value in measured.items()}


def print_tables(results: dict) -> None:
    ms = 1e3
    before, after = results["machine"]["load_average_1min_before_after"]
    print(f"paper yarn (K = 0.2 m/N, prestressed), force control, P = {START_LOAD} -> {END_LOAD} N "
          f"from the static equilibrium, tolerance {TOLERANCE:g} N; warm, best of repeats; "
          f"{available_cores()} cores, 1-minute load average {before:.2f} before the run, "
          f"{after:.2f} after (other processes share the cores)\n")
    print("1. scaling with N (one yarn)")
    print(f"{'method':32s} {'N':>5s} {'time steps':>10s} {'force evals':>11s} {'wall [ms]':>10s} "
          f"{'residual [N]':>12s} {'bend/stretch':>12s}")
    for name, data in results["scaling"].items():
        for segments, row in zip(data["N"], data["rows"]):
            print(f"{name:32s} {segments:5d} {row['time_steps']:10d} {row['force_evaluations']:11d} "
                  f"{ms * row['wall_time_s']:10.2f} {row['residual_N']:12.2e} "
                  f"{row['bending_over_stretch']:12.2f}")
    print(f"\n{'method':32s} {'N range':>10s} {'steps ~ N^':>10s} {'time ~ N^':>10s}   "
          "local (steps; time) between successive N")
    for name, data in results["scaling"].items():
        local = "; ".join(f"{e:.2f}" for e in data["local_exponents_time_steps"]) + " | " + \
            "; ".join(f"{e:.2f}" for e in data["local_exponents_wall_time"])
        print(f"{name:32s} {data['N'][0]:4d}-{data['N'][-1]:<5d} {data['exponent_time_steps']:10.2f} "
              f"{data['exponent_wall_time']:10.2f}   {local}")

    print("\n2. semi_implicit against the static Newton solver, same step, same state")
    static, semi = results["static_newton"], results["scaling"]["semi_implicit"]
    print(f"{'N':>5s} {'semi [ms]':>10s} {'steps':>6s} {'Newton 1e-8 [ms]':>17s} {'iters':>5s} "
          f"{'ratio':>6s} {'Newton 1e-11 [ms]':>18s} {'iters':>5s} {'ratio':>6s}")
    for k, segments in enumerate(static["N"]):
        row = semi["rows"][semi["N"].index(segments)]
        t8, t11 = static["time_s_tolerance_1e-8"][k], static["time_s_tolerance_1e-11"][k]
        print(f"{segments:5d} {ms * row['wall_time_s']:10.3f} {row['time_steps']:6d} "
              f"{ms * t8:17.3f} {static['iterations_tolerance_1e-8'][k]:5d} "
              f"{row['wall_time_s'] / t8:6.1f} {ms * t11:18.3f} "
              f"{static['iterations_tolerance_1e-11'][k]:5d} {row['wall_time_s'] / t11:6.1f}")

    print("\n3. batched yarns ([sweep] of nearly equal K): wall time per yarn [ms] of the batch on "
          "one core and split in groups over the cores, / the one-yarn run's (timed in turn with "
          "them); gain: one core / split; cores: process CPU time / wall time of the split run")
    print(f"{'method':28s} {'N':>4s} {'yarns':>5s} {'1 yarn':>7s} {'one core':>9s} {'ratio':>6s} "
          f"{'groups':>6s} {'split':>7s} {'ratio':>6s} {'gain':>5s} {'cores':>5s} {'identical':>9s}")
    for name, rows in results["sweep"].items():
        for row in rows:
            one, split = row["one_core"], row["split"]
            print(f"{name:28s} {row['N']:4d} {row['yarns']:5d} {ms * row['one_yarn_run_s']:7.3f} "
                  f"{ms * one['per_yarn_s']:9.3f} {one['per_yarn_over_one_yarn_run']:6.2f} "
                  f"{split['groups']:6d} {ms * split['per_yarn_s']:7.3f} "
                  f"{split['per_yarn_over_one_yarn_run']:6.2f} {row['split_gain']:5.2f} "
                  f"{split['cores_in_use']:5.2f} {str(row['bit_identical']):>9s}")

    cost = results["step_cost_ns_per_node"]
    print(f"\n4. explicit time step per node (N = {PAPER_SEGMENTS}): Warp {cost['warp']:.1f} ns, "
          f"numba {cost['numba']:.1f} ns (ratio {cost['ratio']:.2f})")

    print("\naims")
    for name, aim in results["aims"].items():
        value = f"{aim['value']:.0f}" if aim["at_most"] >= 100 else f"{aim['value']:.2f}"
        print(f"  {name:36s} {value:>8s} <= {aim['at_most']:<8g} {'met' if aim['met'] else 'NOT met':8s}"
              f" ({aim['where']})")


def main() -> dict:
    wp.init()
    load_before = os.getloadavg()
    scaling_results, static = scaling()
    paper = {name: data["rows"][data["N"].index(PAPER_SEGMENTS)]
             for name, data in scaling_results.items()}
    results = {"scene": "runs/paper_fig3.toml, K = 0.2 m/N, prestressed, force control 0.2 -> 0.3 N",
               "tolerance_N": TOLERANCE, "methods": paper, "scaling": scaling_results,
               "static_newton": static, "sweep": sweep(), "step_cost_ns_per_node": step_cost()}
    results["aims"] = judge(results)
    results["machine"] = {"processor": platform.processor() or platform.machine(),
                          "cores": available_cores(),
                          "load_average_1min_before_after": [load_before[0], os.getloadavg()[0]],
                          "python": platform.python_version(), "warp": wp.__version__,
                          "numba": numba.__version__}
    return results


if __name__ == "__main__":
    report = main()
    print_tables(report)
    (HERE / "dynamic.json").write_text(json.dumps(report, indent=2) + "\n")
