"""Benchmark: the fabric's dynamic solver (Warp relaxation) against the static one (Newton), per load step.

Run:  python benchmarks/fabric_solvers.py     (prints a table, writes benchmarks/fabric_solvers.json)

Clamped balanced n x n patches of the paper's yarn (`fabric_arrays.paper_patch`: pitch
0.1/16 m, 8 segments per crossing, k_c = 1e5 N/m), n = 4 and 8, under force control along
three load steps (warp, weft) = (0.1, 0.03), (0.3, 0.1), (0.5, 0.2) N per yarn, without and
with the paper's friction, both solvers to the residual tolerance 1e-10 N. Warm (one untimed
run of the path compiles), the fastest of REPEATS runs of the whole path, per step:

- static: `FabricStaticSolver.step` (Newton, its inertia check included), its iterations;
- dynamic: `FabricDynamicSolver.step` on the CPU (persistent layout, kinetic damping), its
  time steps, and the relaxation alone (`relax_time`: the step less the record and the
  stability check, which reuses the static solver's inertia count);
- the largest position difference between the two after each step.
"""

from __future__ import annotations

import json
import os
import platform
import time
from pathlib import Path

import numpy as np
import warp as wp

from dynfab.fabric.dynamic import FabricDynamicSolver
from dynfab.fabric.static import FabricStaticSolver
from dynfab.kernels.fabric_arrays import PAPER_FRICTION, paper_patch

OUTPUT = Path(__file__).resolve().parent / "fabric_solvers.json"
SIZES = (4, 8)
LOADS = ((0.1, 0.03), (0.3, 0.1), (0.5, 0.2))
"""(warp, weft) end forces per yarn [N] of the load steps."""
TOLERANCE = 1e-10
REPEATS = 3


def spec(n: int, friction):
    return paper_patch(n, n, friction=friction, warp_values=tuple(v[0] for v in LOADS),
                       weft_values=tuple(v[1] for v in LOADS), tolerance=TOLERANCE)


def run_path(solver):
    """(per-step wall times [s], records, states) of the whole load path."""
    state = solver.initial_state()
    times, records, states = [], [], []
    for warp_value, weft_value in LOADS:
        began = time.perf_counter()
        state, record = solver.step(state, warp_value, weft_value)
        times.append(time.perf_counter() - began)
        records.append(record)
        states.append(state)
    return np.array(times), records, states


def fastest(solver):
    """Per step, the fastest of REPEATS warm runs (one untimed run first), and the fastest
    relaxation (`relax_time`, dynamic only); the last run's records and states."""
    run_path(solver)
    best, relax = None, None
    for _ in range(REPEATS):
        times, records, states = run_path(solver)
        best = times if best is None else np.minimum(best, times)
        if "relax_time" in records[0]:
            relaxed = np.array([r["relax_time"] for r in records])
            relax = relaxed if relax is None else np.minimum(relax, relaxed)
    return best, relax, records, states


def measure(n: int, friction) -> dict:
    s_times, _, s_records, s_states = fastest(FabricStaticSolver(spec(n, friction)))
    dynamic = FabricDynamicSolver(spec(n, friction))
    d_times, d_relax, d_records, d_states = fastest(dynamic)
    return {"n": n, "friction": friction is not None, "nodes": dynamic.arrays.nodes,
            "static_s": s_times.tolist(),
            "static_iterations": [int(r["iterations"]) for r in s_records],
            "dynamic_s": d_times.tolist(),
            "dynamic_relax_s": d_relax.tolist(),
            "dynamic_time_steps": [int(r["time_steps"]) for r in d_records],
            "position_difference_m": [float(np.abs(a.positions - b.positions).max())
                                      for a, b in zip(s_states, d_states)]}


def main() -> None:
    wp.config.quiet = True
    wp.init()
    rows = []
    print(f"{'patch':>6} {'friction':>8} {'step':>4} {'static s':>9} {'iter':>5} {'dynamic s':>10} "
          f"{'relax s':>8} {'steps':>7} {'|dx| m':>9}")
    for n in SIZES:
        for friction in (None, PAPER_FRICTION):
            row = measure(n, friction)
            rows.append(row)
            for k in range(len(LOADS)):
                print(f"{n:>2} x{n:<2} {str(row['friction']):>8} {k + 1:>4} {row['static_s'][k]:>9.4f} "
                      f"{row['static_iterations'][k]:>5} {row['dynamic_s'][k]:>10.4f} "
                      f"{row['dynamic_relax_s'][k]:>8.4f} {row['dynamic_time_steps'][k]:>7} "
                      f"{row['position_difference_m'][k]:>9.1e}", flush=True)
    result = {"machine": {"platform": platform.platform(), "cpus": os.cpu_count(),
                          "warp": wp.config.version},
              "case": {"sizes": SIZES, "loads_N": LOADS, "tolerance_N": TOLERANCE,
                       "repeats": REPEATS, "segments_per_crossing": 8},
              "rows": rows}
    OUTPUT.write_text(json.dumps(result, indent=2) + "\n")


if __name__ == "__main__":
    main()
