"""The semi-implicit method against kinetic damping on the shear specimens of
tests/test_shear_dynamic.py (docs/model.md section 11.11): per method, each step's time steps
and CG iterations, the wall time of a second run (the first compiles the kernels), their ratio
measured in this one process, and max |x_dyn - x_static| against the two runs' error bounds.
Prints a line per specimen and method and writes benchmarks/shear_semi_implicit.json.

Run: PYTHONPATH=. python benchmarks/shear_semi_implicit.py
"""

import json
import sys
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent / "tests"))
from dynfab import run  # noqa: E402
from dynfab.scene import parse_scene_text  # noqa: E402
from test_shear_dynamic import CASES  # noqa: E402
from test_shear_specimens import scene_text  # noqa: E402

figures = {}
for name in ("frame", "bias"):
    specimen, values, friction = CASES[name]
    text = scene_text(specimen, values, friction)
    static = run(parse_scene_text(text), solver="static")
    for method in ("semi_implicit", "explicit"):
        scene = parse_scene_text(text + f'\n[dynamic]\nmethod = "{method}"\n')
        run(scene, solver="dynamic")  # compiles
        began = time.perf_counter()
        steps = run(scene, solver="dynamic").steps
        wall = time.perf_counter() - began
        x, y = steps["positions"], static.steps["positions"]
        difference = np.abs(x - y).reshape(x.shape[0], -1).max(axis=1)
        bound = steps["error_estimate"] + static.steps["error_estimate"]
        figures[f"{name}/{method}"] = {
            "time_steps": steps["time_steps"].tolist(), "wall_s": wall,
            "cg_iterations": np.asarray(steps.get("cg_iterations", [])).tolist(),
            "difference_from_static_m": difference.tolist(), "bound_m": bound.tolist()}
        print(f"{name} {method}: time steps {steps['time_steps'].tolist()}, CG iterations "
              f"{figures[f'{name}/{method}']['cg_iterations']}, {wall:.2f} s; max |x - "
              f"x_static| {np.array2string(difference, precision=2)} m, bounds "
              f"{np.array2string(bound, precision=2)} m", flush=True)
    ratio = figures[f"{name}/explicit"]["wall_s"] / figures[f"{name}/semi_implicit"]["wall_s"]
    figures[f"{name}/explicit_over_semi_implicit"] = ratio
    print(f"{name}: kinetic damping takes {ratio:.2f} x the semi-implicit wall time", flush=True)
(HERE / "shear_semi_implicit.json").write_text(json.dumps(figures, indent=1) + "\n")
print("wrote benchmarks/shear_semi_implicit.json")
