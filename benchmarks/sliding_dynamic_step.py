"""One dynamic step of a 20 x 40 mm bias specimen (tests/test_sliding_crossings.py's `specimen`:
its relaxation as woven) with fixed and with sliding crossings (docs/model.md 11.13), and the
fixed crossings in the gather order the sliding ones run: time steps, wall time and time per
time step of each, best of 3, in one run (the kernels compiled before the timing). Prints them
and writes benchmarks/sliding_dynamic_step.json.

Run: PYTHONPATH=. python benchmarks/sliding_dynamic_step.py
"""

import json
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
from dynfab.solvers.dynamic import DynamicSolver  # noqa: E402
from test_sliding_crossings import specimen  # noqa: E402

CASES = {"fixed": ("fixed", "scatter"), "fixed, gather order": ("fixed", "gather"),
         "sliding": ("sliding", "gather")}
out = {}
for name, (motion, order) in CASES.items():
    model = specimen(motion, values=(5e-4,))
    walls = []
    for _ in range(4):  # the first compiles or loads the kernels
        began = time.perf_counter()
        _, record = DynamicSolver(model, order=order).step(model.initial_state(),
                                                           model.step_load(0))
        walls.append(time.perf_counter() - began)
    steps = int(record["time_steps"])
    wall = min(walls[1:])
    out[name] = {"time_steps": steps, "wall_s": wall, "us_per_time_step": 1e6 * wall / steps,
                 "nodes": int(model.structure.rest_position.shape[0])}
    print(f"{name}: {out[name]}", flush=True)
base = out["fixed"]
for name, case in out.items():
    case["ratio_per_time_step"] = case["us_per_time_step"] / base["us_per_time_step"]
    case["ratio_wall"] = case["wall_s"] / base["wall_s"]
    print(f"{name}: {case['ratio_per_time_step']:.2f}x per time step, "
          f"{case['ratio_wall']:.2f}x the step's wall time")
Path(__file__).with_suffix(".json").write_text(json.dumps(out, indent=1) + "\n")
