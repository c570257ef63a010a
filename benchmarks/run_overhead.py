"""Benchmark of a run's overhead: what `dynfab.run` costs around the solver's step.

Run:  python benchmarks/run_overhead.py            (prints the figures, writes benchmarks/run_overhead.json)
      python benchmarks/run_overhead.py --no-write (prints only; e.g. to time another checkout
                                                    of dynfab put first on PYTHONPATH)

The run: one paper equilibrium in memory, `dynfab.run(scene, solver="static")` with no
output file, the scene being runs/paper_fig5.toml's friction entry (one yarn, N = 224,
prestressed, K = 0.2 m/N) cut to its first load value (end displacement 0.25 mm from
the as-woven state). A fit or a study calls `run` thousands of times on such scenes, so
what `run` adds to the step counts as much as the step.

Measured in one process, warm (two untimed rounds first), each figure the median of
`REPEATS` rounds, each round taking the three calls below in turn so that they see the same
machine:

- step: `StaticSolver.step` from the as-woven state (what the solver costs);
- build: `build_model` and `make_solver` (the model's arrays and the solver);
- total: `dynfab.run(scene, solver="static")`;
- outside: total - step, everything `run` does around the step (build included): the
  median over the rounds of each round's difference, and its ratio to the step's median.

Each in wall time (time.perf_counter) and in this thread's CPU time (time.thread_time):
on a machine shared with other processes, a call of a few ms is often descheduled for
a time slice, which the wall time counts and the CPU time does not.

Aim: outside at most 0.3 x step.
"""

from __future__ import annotations

import argparse
import json
import platform
import statistics
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

import dynfab
from dynfab.model.yarn import initial_state
from dynfab.model.builders import build_model
from dynfab.run import make_solver
from dynfab.scene import Load, expand_sweep, load_scene, validate_scene

ROOT = Path(__file__).resolve().parent.parent
OUTPUT = Path(__file__).resolve().parent / "run_overhead.json"
REPEATS = 30
"""Timed calls per figure (the median is reported)."""
AIM = 0.3
"""Largest ratio of the time outside the step to the step's."""


def equilibrium_scene():
    """runs/paper_fig5.toml's friction entry (sweep entry 0), its first load value only."""
    entry = expand_sweep(load_scene(ROOT / "runs" / "paper_fig5.toml"))[0]
    first = float(entry.load.values[0])
    return validate_scene(replace(entry, load=Load(control=entry.load.control, values=(first,))))


def timed_rounds(calls: dict, repeats: int = REPEATS) -> dict:
    """{name: (wall times [s], CPU times of this thread [s])} of `repeats` rounds of `calls`,
    each round calling each in turn (so that the calls of a round see the same machine),
    after two untimed rounds."""
    times = {name: ([], []) for name in calls}
    for round_ in range(repeats + 2):
        for name, call in calls.items():
            wall, cpu = time.perf_counter(), time.thread_time()
            call()
            cpu, wall = time.thread_time() - cpu, time.perf_counter() - wall
            if round_ >= 2:
                times[name][0].append(wall)
                times[name][1].append(cpu)
    return times


def measure() -> dict:
    """The figures of the module docstring [s], and the run's result as a check."""
    scene = equilibrium_scene()
    model = build_model(scene)
    solver = make_solver(model, "static")
    start = initial_state(model)
    load = float(model.load_values[0])
    times = timed_rounds({"step": lambda: solver.step(start, load),
                          "build": lambda: make_solver(build_model(scene), "static"),
                          "total": lambda: dynfab.run(scene, solver="static")})
    results = dynfab.run(scene, solver="static")
    _, record = solver.step(start, load)
    assert np.array_equal(results.steps["positions"][0], record["positions"])
    out = {"segments": scene.geometry.segments, "load_m": load, "repeats": REPEATS, "aim": AIM}
    for clock, column in (("wall", 0), ("cpu", 1)):
        step, build, total = (times[name][column] for name in ("step", "build", "total"))
        outside = statistics.median(t - s for t, s in zip(total, step))  # paired by round
        out[clock] = {"step_s": statistics.median(step), "build_s": statistics.median(build),
                      "total_s": statistics.median(total), "outside_s": outside,
                      "outside_over_step": outside / statistics.median(step)}
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--no-write", action="store_true", help="print only")
    args = parser.parse_args()
    figures = measure()
    print(f"dynfab from {Path(dynfab.__file__).parent}")
    print(f"{'median of ' + str(REPEATS):<14} {'wall [ms]':>10} {'CPU [ms]':>10}")
    rows = (("step", "step_s", "StaticSolver.step"), ("build", "build_s", "build_model + make_solver"),
            ("total", "total_s", "dynfab.run, in memory"), ("outside", "outside_s", "total - step, per round"))
    for name, key, what in rows:
        print(f"{name:<14} {1e3 * figures['wall'][key]:>10.3f} {1e3 * figures['cpu'][key]:>10.3f}"
              f"   ({what})")
    print(f"{'outside/step':<14} {figures['wall']['outside_over_step']:>10.2f} "
          f"{figures['cpu']['outside_over_step']:>10.2f}   (aim <= {AIM})")
    if not args.no_write:
        figures["machine"] = {"python": platform.python_version(), "cpu": platform.processor()
                              or platform.machine(), "numpy": np.__version__}
        OUTPUT.write_text(json.dumps(figures, indent=2) + "\n")
        print(f"wrote {OUTPUT.relative_to(ROOT)}")


if __name__ == "__main__":
    main()
