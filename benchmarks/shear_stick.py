"""The stick stiffness k_t of a shear specimen's crossings as a regularisation of Coulomb's
law (docs/model.md section 11.10): its results' distance from the stiffest k_t, and the
static solver's Newton iterations, against k_t.

The scene is runs/cao2008_bias_115x230.toml cut to a W x H specimen (default 60 x 120 mm,
277 crossings) loaded to d = 1, 2, 3 mm after step 0, with `friction.stick_stiffness` set
to each k_t in turn. Per k_t: the Newton iterations and wall time of the path, the largest
difference of the clamp force [N] and of the crossings' shear angles [degrees] from the
stiffest k_t's, over the steps. A first-order regularisation moves them by a factor 10 per
decade of k_t (tests/test_shear_stick.py asserts it).

Run: python benchmarks/shear_stick.py [--stiffnesses 3e3,3e4,3e5,3e6,3e7,3e8]
     [--width 0.06] [--out benchmarks/shear_stick.json]
Times are wall-clock on this machine (shared: compare within one run).
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

from dynfab import run
from dynfab.scene import load_scene, with_key

ROOT = Path(__file__).resolve().parents[1]
SCENE = ROOT / "runs" / "cao2008_bias_115x230.toml"
LOADS = (1e-3, 2e-3, 3e-3)
"""Clamp displacements [m] after step 0."""
TOLERANCE = 1e-9
"""Newton's residual tolerance [N]: the differences measured reach 3e-8 N of clamp force, so
the solves go ten times below the Cao scenes' 1e-8 N (the table was measured at 1e-9 N)."""


def specimen(width: float, stick_stiffness: float):
    """The Cao fabric's bias specimen W = width, H = 2 W, at the given k_t [N/m]."""
    scene = with_key(load_scene(SCENE), "specimen.width", width)
    scene = with_key(scene, "specimen.height", 2.0 * width)
    scene = with_key(scene, "load.values", LOADS)
    scene = with_key(scene, "static.tolerance", TOLERANCE)
    return with_key(scene, "friction.stick_stiffness", stick_stiffness)


def path(scene) -> dict:
    """The static solver's path (`dynfab.run`): clamp forces [N], shear angles [rad],
    iterations, wall [s]."""
    started = time.perf_counter()
    results = run(scene, solver="static")
    steps = results.steps
    return {"clamp_force_N": np.asarray(steps["clamp_force"]),
            "shear_angle_rad": np.asarray(steps["shear_angle"]),
            "iterations": int(np.sum(steps["iterations"])),
            "wall_s": time.perf_counter() - started}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--stiffnesses", default="3e3,3e4,3e5,3e6,3e7,3e8")
    parser.add_argument("--width", type=float, default=0.06)
    parser.add_argument("--out", default=str(ROOT / "benchmarks" / "shear_stick.json"))
    args = parser.parse_args()
    stiffnesses = sorted(float(k) for k in args.stiffnesses.split(","))
    runs = {k: path(specimen(args.width, k)) for k in stiffnesses}
    reference = runs[stiffnesses[-1]]
    rows = []
    print(f"bias specimen {1e3 * args.width:g} x {2e3 * args.width:g} mm, d = "
          f"{', '.join(f'{1e3 * d:g}' for d in LOADS)} mm; differences from k_t = "
          f"{stiffnesses[-1]:g} N/m")
    print("k_t [N/m] | iterations | wall [s] | clamp force diff [N] | shear angle diff [deg]")
    for k in stiffnesses:
        run = runs[k]
        row = {"stick_stiffness_N_per_m": k, "iterations": run["iterations"],
               "wall_s": run["wall_s"],
               "clamp_force_diff_N": float(np.abs(run["clamp_force_N"]
                                                  - reference["clamp_force_N"]).max()),
               "shear_angle_diff_deg": float(np.degrees(np.abs(
                   run["shear_angle_rad"] - reference["shear_angle_rad"]).max())),
               "last_clamp_force_N": float(run["clamp_force_N"][-1])}
        rows.append(row)
        print(f"{k:9.3g} | {row['iterations']:10d} | {row['wall_s']:8.2f} | "
              f"{row['clamp_force_diff_N']:20.3g} | {row['shear_angle_diff_deg']:.3g}")
    Path(args.out).write_text(json.dumps({"width_m": args.width, "loads_m": LOADS,
                                          "rows": rows}, indent=1) + "\n")
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
