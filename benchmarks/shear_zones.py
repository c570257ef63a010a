"""The bias-extension zones against Cao et al.'s eq. 13 (docs/model.md section 11.9): the
issue's 60 x 120 mm specimen (tests/test_shear_specimens.py's scene, held together by
`HOLDING_FRICTION`) and the same weave on wider specimens (W and H = 2 W scaled, d scaled
with W, so each width reaches eq. 13's 30 degrees at its last step). Per width and step:
the zone medians of `steps/shear_angle` (A: no yarn clamped, B: one, C: both) against
eq. 13, the spread of zone A, the largest slip and the run's wall time.

Run: PYTHONPATH=. python benchmarks/shear_zones.py [--widths 0.06,0.12,0.18]
     [--shear-stiffness K] (prints a table, writes benchmarks/shear_zones.json)
"""

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
from dynfab import run  # noqa: E402
from dynfab.scene import parse_scene_text  # noqa: E402
from test_shear_specimens import (  # noqa: E402
    BIAS, DEGREE, HOLDING_FRICTION, bias_nominal, scene_text)

OUTPUT = Path(__file__).resolve().parent / "shear_zones.json"
D_AT_60_MM = (3e-3, 6e-3, 9e-3, 13.5e-3)
"""Clamp displacements [m] on the 60 mm specimen (eq. 13: 5.9, 12.1, 18.8, 30.0 degrees)."""


def zones(width: float, shear_stiffness: str) -> dict:
    """One width's run: per step d, eq. 13 and the zone medians [degrees]."""
    specimen = BIAS.replace("width = 0.06\nheight = 0.12",
                            f"width = {width!r}\nheight = {2 * width!r}")
    d = [x * width / 0.06 for x in D_AT_60_MM]
    text = scene_text(specimen, d, HOLDING_FRICTION).replace(
        "shear_stiffness = 5e-3", f"shear_stiffness = {shear_stiffness}")
    began = time.perf_counter()
    r = run(parse_scene_text(text), solver="static")
    wall = time.perf_counter() - began
    zone, gamma = r.reference["zone"], r.steps["shear_angle"] / DEGREE
    steps = []
    for k in range(1, gamma.shape[0]):
        dk = float(r.steps["load"][k, 0])
        a = gamma[k][zone == 0]
        steps.append({"d_m": dk, "eq13_deg": float(bias_nominal(dk, width, 2 * width) / DEGREE),
                      "zone_A_deg": float(np.median(a)), "zone_A_min_deg": float(a.min()),
                      "zone_A_max_deg": float(a.max()),
                      "zone_B_deg": float(np.median(gamma[k][zone == 1])),
                      "zone_C_deg": float(np.median(gamma[k][zone == 2])),
                      "slip_ratio": float(r.steps["slip_ratio"][k])})
    return {"width_m": width, "crossings": [int(np.sum(zone == z)) for z in (0, 1, 2)],
            "wall_s": wall, "steps": steps}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--widths", default="0.06,0.12,0.18")
    parser.add_argument("--shear-stiffness", default="5e-3")
    parser.add_argument("--out", type=Path, default=OUTPUT)
    args = parser.parse_args()
    results = []
    for width in (float(w) for w in args.widths.split(",")):
        result = zones(width, args.shear_stiffness)
        results.append(result)
        print(f"W = {width * 1e3:.0f} mm (A, B, C crossings {result['crossings']}), "
              f"{result['wall_s']:.0f} s", flush=True)
        for s in result["steps"]:
            print(f"  d = {s['d_m'] * 1e3:5.2f} mm  eq. 13 {s['eq13_deg']:5.2f}  "
                  f"A {s['zone_A_deg']:5.2f} ({s['zone_A_min_deg']:.1f}..{s['zone_A_max_deg']:.1f})"
                  f"  B {s['zone_B_deg']:5.2f}  C {s['zone_C_deg']:5.2f}  "
                  f"slip {s['slip_ratio']:.3f}", flush=True)
    args.out.write_text(json.dumps({"shear_stiffness": args.shear_stiffness,
                                    "widths": results}, indent=1))


if __name__ == "__main__":
    main()
