"""Wall time of the semi-implicit method on the shear specimens, for a before/after of a kernel
change: the frame and bias specimens of tests/test_shear_dynamic.py (best of `--rounds` runs
after one that compiles) and the solver time of the whole runs/shear_frame_60mm.toml path.
Runs whichever dynfab is first on the path, so that two trees can be timed in turns:

    PYTHONPATH=/tmp/before python benchmarks/specimen_semi_implicit.py --out before.json
    PYTHONPATH=. python benchmarks/specimen_semi_implicit.py

Prints the figures and writes them (default benchmarks/specimen_semi_implicit.json).
"""

import argparse
import json
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent / "tests"))
from dynfab import run  # noqa: E402
from dynfab.scene import load_scene, parse_scene_text  # noqa: E402
from test_shear_dynamic import CASES, SEMI_IMPLICIT  # noqa: E402
from test_shear_specimens import scene_text  # noqa: E402


def best_wall(scene, rounds: int) -> float:
    """The least wall time [s] of `rounds` dynamic runs of `scene` (after one that compiles)."""
    run(scene, solver="dynamic")
    times = []
    for _ in range(rounds):
        began = time.perf_counter()
        run(scene, solver="dynamic")
        times.append(time.perf_counter() - began)
    return min(times)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument("--out", default=str(HERE / "specimen_semi_implicit.json"))
    args = parser.parse_args()
    figures = {}
    for name in ("frame", "bias"):
        specimen, values, friction = CASES[name]
        scene = parse_scene_text(scene_text(specimen, values, friction) + SEMI_IMPLICIT)
        figures[f"{name}_wall_s"] = best_wall(scene, args.rounds)
    steps = run(load_scene(str(HERE.parent / "runs" / "shear_frame_60mm.toml")),
                solver="dynamic", method="semi_implicit").steps
    compiling = steps["compile_time"].sum() if "compile_time" in steps else 0.0
    figures["frame_60mm_path_solver_s"] = float(steps["wall_time"].sum() - compiling)
    for key, value in figures.items():
        print(f"{key:<28} {value:.3f}")
    Path(args.out).write_text(json.dumps(figures, indent=2) + "\n")


if __name__ == "__main__":
    main()
