"""The dynamic solver against the static one on the shear specimens of
tests/test_shear_dynamic.py (docs/model.md section 11.11): per damping, each step's time steps,
the run's wall time and max |x_dyn - x_static| against the two runs' error bounds.

Run: PYTHONPATH=. python benchmarks/shear_dynamic.py
"""

import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
from dynfab import run  # noqa: E402
from dynfab.scene import parse_scene_text  # noqa: E402
from test_shear_dynamic import CASES  # noqa: E402
from test_shear_specimens import scene_text  # noqa: E402

for name in ("frame", "bias"):
    specimen, values, friction = CASES[name]
    scene = parse_scene_text(scene_text(specimen, values, friction))
    began = time.perf_counter()
    static = run(scene, solver="static")
    print(f"{name} static {time.perf_counter() - began:.1f} s", flush=True)
    for damping in ("kinetic", "fire", "viscous"):
        began = time.perf_counter()
        dynamic = run(scene, solver="dynamic", damping=damping)
        wall = time.perf_counter() - began
        x, y = dynamic.steps["positions"], static.steps["positions"]
        difference = np.abs(x - y).reshape(x.shape[0], -1).max(axis=1)
        bound = dynamic.steps["error_estimate"] + static.steps["error_estimate"]
        print(f"{name} {damping}: time steps {dynamic.steps['time_steps'].tolist()}, "
              f"{wall:.1f} s; max |x_dyn - x_static| {np.array2string(difference, precision=2)}"
              f" m, bounds {np.array2string(bound, precision=2)} m", flush=True)
