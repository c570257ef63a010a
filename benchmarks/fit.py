"""Benchmark of `dynfab fit`: the exact Jacobian against a forward solve, and the whole fit
against the same fit with a finite-difference Jacobian.

Run:  python benchmarks/fit.py            (prints a table, writes benchmarks/fit.json)

Measured in one run, warm (everything runs once to compile before timing; each
figure is the best of several repeats, `dynfab.timing.best_time`):

- one forward solve of a curve (`dynfab.fitting.sensitivity.solve_path`: the static
  solver over the load path) against one Jacobian of the same curve
  (`path_sensitivities` of the measured observable, as a fit asks for it:
  per step one coupled Jacobian, one banded LU, one solve and two residual
  evaluations per parameter), for 1, 2 and 4
  parameters, on two scenes: the fit example (runs/fit_example, N = 32,
  4 crossings, friction, 20 steps) and the paper's friction yarn
  (runs/paper_fig5.toml entry 0, N = 224, 16 crossings, 40 steps). Aim:
  Jacobian / forward <= 1 + 0.2 x parameters.
- the whole fit of runs/fit_example (warp.EA and friction.alpha) with the
  exact Jacobian against scipy's forward-difference Jacobian ("2-point",
  whole runs): wall time, curve solves, and the fitted values.
"""

from __future__ import annotations

import json
import platform
from pathlib import Path

import numpy as np
import scipy

from dynfab.fitting.fit import fit
from dynfab.results.measured_curve import read_curve
from dynfab.scene import expand_sweep, load_scene
from dynfab.fitting.sensitivity import path_sensitivities, solve_path
from dynfab.timing import best_time

ROOT = Path(__file__).resolve().parent.parent
EXAMPLE = ROOT / "runs" / "fit_example"
OUTPUT = Path(__file__).resolve().parent / "fit.json"
KEYS = ["warp.EA", "friction.alpha", "warp.kawabata_K", "weft.kawabata_C"]
REPEATS = 10


def jacobian_against_forward(scene, label):
    solve_path(scene)  # compile
    forward, solution = best_time(lambda: solve_path(scene), REPEATS)
    rows = []
    for count in (1, 2, 4):
        keys = KEYS[:count]
        observed = ["end_force" if scene.load.control == "displacement" else "end_displacement"]
        path_sensitivities(solution, keys, observables=observed)
        jac, _ = best_time(lambda: path_sensitivities(solution, keys, observables=observed),
                           REPEATS)
        rows.append({"scene": label, "steps": int(solution.load.size),
                     "segments": scene.geometry.segments, "parameters": count,
                     "forward_s": forward, "jacobian_s": jac, "ratio": jac / forward,
                     "aim": 1 + 0.2 * count})
    return rows


def whole_fits():
    scene = load_scene(EXAMPLE / "scene.toml")
    data = read_curve(EXAMPLE / "curve.csv", scene.load.control)
    keys = ["warp.EA", "friction.alpha"]
    out = {}
    for method in ("exact", "finite-difference"):
        calls = {"solves": 0}
        import dynfab.fitting.sensitivity as sensitivity
        original = sensitivity.solve_path

        def counting(*args, **kwargs):
            calls["solves"] += 1
            return original(*args, **kwargs)

        sensitivity.solve_path = counting
        try:
            seconds, result = best_time(lambda: fit(scene, data, keys, jacobian=method), 3)
        finally:
            sensitivity.solve_path = original
        out[method] = {"wall_s": seconds, "curve_solves": calls["solves"] // 3,
                       "iterations": result.iterations,
                       "values": {k: v["value"] for k, v in result.parameters.items()},
                       "cost": result.cost_history[-1] if result.cost_history else None}
    out["speedup"] = out["finite-difference"]["wall_s"] / out["exact"]["wall_s"]
    return out


def main():
    example = load_scene(EXAMPLE / "scene.toml")
    from dynfab.fitting.fit import refined_path, with_path
    data = read_curve(EXAMPLE / "curve.csv", example.load.control)
    example = with_path(example, refined_path(data.load, 2)[0])
    paper = expand_sweep(load_scene(ROOT / "runs" / "paper_fig5.toml"))[0]
    rows = jacobian_against_forward(example, "fit example") + \
        jacobian_against_forward(paper, "paper Fig. 5, friction")
    print(f"{'scene':<24}{'N':>5}{'steps':>7}{'params':>8}{'forward [ms]':>14}"
          f"{'Jacobian [ms]':>15}{'ratio':>8}{'aim':>6}")
    for r in rows:
        print(f"{r['scene']:<24}{r['segments']:>5}{r['steps']:>7}{r['parameters']:>8}"
              f"{1e3 * r['forward_s']:>14.2f}{1e3 * r['jacobian_s']:>15.2f}{r['ratio']:>8.2f}"
              f"{r['aim']:>6.1f}")
    fits = whole_fits()
    print("\nwhole fit of runs/fit_example (warp.EA, friction.alpha):")
    for method in ("exact", "finite-difference"):
        f = fits[method]
        values = ", ".join(f"{k} {v:.6g}" for k, v in f["values"].items())
        print(f"  {method:<18} {1e3 * f['wall_s']:8.1f} ms, {f['curve_solves']:3d} curve solves, "
              f"{f['iterations']} iterations: {values}")
    print(f"  speed-up of the exact Jacobian: {fits['speedup']:.2f}x")
    OUTPUT.write_text(json.dumps({
        "machine": {"python": platform.python_version(), "numpy": np.__version__,
                    "scipy": scipy.__version__, "processor": platform.processor()},
        "jacobian_against_forward": rows, "whole_fit": fits}, indent=2) + "\n")
    print(f"wrote {OUTPUT}")


if __name__ == "__main__":
    main()
