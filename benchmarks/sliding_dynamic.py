"""The dynamic solver against the static one on a bias specimen whose edge yarns slide out of
their crossings (tests/test_sliding_crossings.py's `bias_slides_out`: 40 x 80 mm, 8 steps of
0.5 mm; docs/model.md 11.13): each step's crossings present, clamp force and error bound by
both solvers, the dynamic steps' time steps, and the two runs' wall times, measured in one
run. Prints them and writes benchmarks/sliding_dynamic.json.

Run: PYTHONPATH=. python benchmarks/sliding_dynamic.py   (about 20 minutes here)
"""

import json
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
from dynfab import run  # noqa: E402
from dynfab.scene import parse_scene_text  # noqa: E402
from test_sliding_crossings import bias_slides_out  # noqa: E402

scene = parse_scene_text(bias_slides_out())
results, walls = {}, {}
for solver in ("static", "dynamic"):
    began = time.perf_counter()
    results[solver] = run(scene, solver=solver).steps
    walls[solver] = time.perf_counter() - began
    print(f"{solver}: {walls[solver]:.1f} s", flush=True)
static, dynamic = results["static"], results["dynamic"]
present = {name: np.asarray(steps["crossing_present"], bool).sum(axis=1).tolist()
           for name, steps in results.items()}
clamp = {name: np.asarray(steps["clamp_force"], float).tolist() for name, steps in results.items()}
bound = {name: np.asarray(steps["error_estimate"], float).tolist()
         for name, steps in results.items()}
out = {
    "scene": "tests/test_sliding_crossings.py bias_slides_out (40 x 80 mm, 8 x 0.5 mm)",
    "wall_s": walls, "ratio_dynamic_to_static": walls["dynamic"] / walls["static"],
    "crossings_present": present,
    "same_departures": bool(np.array_equal(static["crossing_present"],
                                           dynamic["crossing_present"])),
    "clamp_force_N": clamp,
    "largest_clamp_force_difference_N": float(np.abs(np.subtract(clamp["dynamic"],
                                                                  clamp["static"])).max()),
    "error_estimate_m": bound,
    "dynamic_time_steps": np.asarray(dynamic["time_steps"]).tolist(),
}
for key, value in out.items():
    print(f"{key}: {value}")
Path(__file__).with_suffix(".json").write_text(json.dumps(out, indent=1) + "\n")
