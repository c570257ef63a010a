"""Why a shear specimen refuses float32 (docs/model.md section 11.11): the 60 mm picture frame
of tests/test_shear_dynamic.py relaxed in float64 and in float32, each step's residual, whether
it stopped at its rounding floor, and its certificate's position error bound.

A run refuses float32 on a specimen (`dynfab.kernels.spatial_terms.REFUSALS`); this script
lifts that one refusal for its own process, to measure what the refusal is for. Both runs use
the same scene; float32 runs with dynamic.accuracy = 1e300 (off), so that its bound is recorded
rather than refused. Prints a line per precision and writes benchmarks/specimen_float32.json.

Run: PYTHONPATH=. python benchmarks/specimen_float32.py
"""

import json
import sys
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent / "tests"))
from dynfab import run  # noqa: E402
from dynfab.scene import parse_scene_text  # noqa: E402
from dynfab.kernels import spatial_terms  # noqa: E402
from test_shear_dynamic import CASES  # noqa: E402
from test_shear_specimens import scene_text  # noqa: E402

spatial_terms.REFUSALS = tuple(r for r in spatial_terms.REFUSALS if r[0] != "precision")
specimen, values, friction = CASES["frame"]
text = scene_text(specimen, values, friction)
static = run(parse_scene_text(text), solver="static")
figures = {}
for precision in ("float64", "float32"):
    extra = f'\n[dynamic]\nprecision = "{precision}"\naccuracy = 1e300\n'
    steps = run(parse_scene_text(text + extra), solver="dynamic").steps
    difference = np.abs(steps["positions"] - static.steps["positions"]).max(axis=(1, 2))
    figures[precision] = {name: np.asarray(value).tolist() for name, value in (
        ("residual_N", steps["residual"]), ("rounding_floor", steps["rounding_floor"]),
        ("error_estimate_m", steps["error_estimate"]), ("difference_from_static_m", difference))}
    print(f"{precision}: residual {np.array2string(steps['residual'], precision=3)} N, at the "
          f"rounding floor {steps['rounding_floor'].tolist()}, error bound "
          f"{np.array2string(steps['error_estimate'], precision=3)} m, |x - x_static| "
          f"{np.array2string(difference, precision=3)} m", flush=True)
(HERE / "specimen_float32.json").write_text(json.dumps(figures, indent=1) + "\n")
