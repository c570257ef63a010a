"""What the woven-in contact does to a shear specimen's force (docs/model.md section 10, "The
woven-in contact"; docs/results.md): a Cao scene run with several `crossing.preload` values,
its load path cut at `--until` d, each run's clamp force [N] and normalised shear force [N/m]
at the path's nominal angles, and after step 0 the median contact force over the preload.

Run: PYTHONPATH=. python benchmarks/preload.py [--scene runs/cao2008_frame.toml]
     [--preloads 0.06,0.24,0.5] [--until 0.02] [--out benchmarks/preload.json]
(a preload whose release would fold a free yarn end is refused, as `dynfab run` refuses it:
the row says so)
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
from dynfab import run  # noqa: E402
from dynfab.errors import UserError  # noqa: E402
from dynfab.scene import load_scene, with_key  # noqa: E402
from dynfab.model.specimen_layout import nominal_shear_angle  # noqa: E402

OUTPUT = Path(__file__).resolve().parent / "preload.json"


def one(scene, preload: float) -> dict:
    """One preload's run (module docstring)."""
    scene = with_key(scene, "crossing.preload", preload)
    began = time.perf_counter()
    try:
        steps = run(scene, solver="static").steps
    except UserError as error:
        return {"preload_N": preload, "refused": str(error)}
    s = scene.specimen
    dims = ({"width": s.width, "height": s.height} if s.test == "bias_extension"
            else {"side": s.side})
    d = np.asarray(steps["load"], float)[:, 0]
    return {"preload_N": preload, "wall_s": time.perf_counter() - began,
            "d_mm": (1e3 * d).tolist(),
            "nominal_deg": [float(np.degrees(nominal_shear_angle(s.test, x, **dims)))
                            for x in d],
            "clamp_force_N": np.asarray(steps["clamp_force"], float).tolist(),
            "normalised_shear_force_N_per_m":
                np.asarray(steps["normalised_shear_force"], float).tolist(),
            "median_contact_over_preload_step0":
                float(np.median(np.asarray(steps["contact_force"], float)[0]) / preload)}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scene", type=Path, default=ROOT / "runs" / "cao2008_frame.toml")
    parser.add_argument("--preloads", default="0.06,0.24,0.5")
    parser.add_argument("--until", type=float, default=0.02, help="last d of the path [m]")
    parser.add_argument("--out", type=Path, default=OUTPUT)
    args = parser.parse_args()
    scene = load_scene(args.scene)
    values = tuple(v for v in scene.load.values if v <= args.until + 1e-12)
    scene = with_key(scene, "load.values", values)
    rows = [one(scene, float(p)) for p in args.preloads.split(",")]
    print(f"{args.scene.name}, d to {1e3 * values[-1]:g} mm")
    for r in rows:
        if "refused" in r:
            print(f"  R_p = {r['preload_N']:g} N: refused: {r['refused']}")
            continue
        print(f"  R_p = {r['preload_N']:g} N: median contact after step 0 "
              f"{r['median_contact_over_preload_step0']:.3f} R_p; {r['wall_s']:.0f} s")
        for d, a, f, n in zip(r["d_mm"], r["nominal_deg"], r["clamp_force_N"],
                              r["normalised_shear_force_N_per_m"]):
            print(f"    d {d:6.3g} mm  nominal {a:5.2f} deg  clamp force {f:8.4g} N  "
                  f"normalised {n:8.4g} N/m")
    args.out.write_text(json.dumps({"scene": str(args.scene.resolve().relative_to(ROOT)),
                                    "until_m": args.until, "rows": rows}, indent=1) + "\n")
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
