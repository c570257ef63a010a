"""Benchmark of the fabric's moving planes and periodic cell in the dynamic solver
(docs/model.md section 10): the explicit time step's cost with them against fixed planes,
`dynfab run` wall times of every fabric scene (static, explicit, semi-implicit), and the
semi-implicit time step rules.

Run:  python benchmarks/fabric_planes.py [--sizes 8,16,32] [--modes fixed,affine,periodic]
                                         [--no-runs] [--parts steps,runs,semi]
                                         [--semi-sizes 8,16]
                                         [--output benchmarks/fabric_planes.json]
      (prints a table per part, writes the JSON)

1. `step_costs`: balanced n x n patches of the paper's yarn with the paper's friction
   (`fabric_data.paper_patch_scene`, 8 segments per half-wave), force control, loaded by
   LOAD per yarn, in three boundary modes: clamped with fixed planes, clamped with "affine"
   planes (the slip measured from planes moving with the mean end displacement, its
   reaction gathered on the end nodes), and the periodic cell (wrap springs, tied cell
   lengths, planes moving with the cell). A fixed number of viscous time steps from the
   as-woven state in each layout (grouped: one launch, scatter order; node_parallel: a
   launch per stage, gather order), the fastest of REPEATS, modes alternating within each
   repeat; ns per node and time step, and each mode over fixed planes. `--modes fixed`
   runs on a tree without the moving planes too (the same public API), for before/after
   ratios of the fixed-plane step.
2. `run_times` (unless --no-runs): `dynfab run runs/<scene>.toml --out <tmp> --quiet`
   with --solver static, --solver dynamic (explicit) and --solver dynamic --method
   semi_implicit for each fabric scene of runs/, the order rotated per scene, one run each
   in a subprocess (numba and Warp caches warm: run the tests or the script once before),
   wall time around the subprocess.
3. `semi_rules` (part "semi"): the semi-implicit relaxation of the first load step, from the
   step's start (`StructureRelaxation.relax`, grouped layout), under each time step rule
   (`RULES`: "halving": undo and halve dt on a step that does not lower f^T M^-1 f, no line
   search, no secant blocks; "line_search": first halve the step's length along its velocity,
   `structure_semi_implicit.MAX_BACKTRACKS` times, and where the planes move the sliding
   crossings' secant blocks, the layer's default): runs/fabric_strip.toml's first step and the
   n x n patches of part 1 in each mode (--semi-sizes). Time steps, rejected and shortened
   steps, CG iterations and the wall time of one relaxation after a warm-up run
   (compilation), the rules alternating which runs first per case.
"""

from __future__ import annotations

import argparse
import json
import platform
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
OUTPUT = ROOT / "benchmarks" / "fabric_planes.json"
LOAD = (0.3, 0.1)
"""(warp, weft) end force per yarn [N]."""
DAMPING = 0.05
"""Viscous coefficient [1/s] of the timed steps (the result is not a relaxation)."""
STEP_WORK = 4e6
"""Node-steps timed per configuration (persistent layout): steps = STEP_WORK / nodes."""
PER_STEP_WORK = 5e5
"""Node-steps timed in the per-step layout (two launches per step: slower on the CPU)."""
REPEATS = 3
SCENES = ("fabric_biaxial", "fabric_biaxial_2to1", "fabric_biaxial_1to2", "fabric_strip")
"""The runs/ fabric scenes `run_times` times with every solver (runs/fabric_pullout.toml's
crossings slide: the static solver's alone, docs/model.md 11.13)."""
PAPER_FRICTION = {"alpha": 0.2, "beta": 1e3, "contact_length": 2e-3, "fiber_radius": 1e-3}
"""The paper's Gralen parameters (docs/model.md section 7), R_0 the default 1e-5 N."""


def patch(n: int, mode: str):
    """The n x n patch's `FabricModel` in one boundary mode (module docstring)."""
    from dynfab.model.fabric.model import FabricModel
    from dynfab.reports.fabric_data import paper_patch_scene

    more = {"fixed": {}, "affine": {"planes": "affine"}, "periodic": {"boundary": "periodic"}}[mode]
    return FabricModel.from_scene(paper_patch_scene(
        n, n, friction=PAPER_FRICTION,
        load={"control": "force", "values": [LOAD[0]], "weft_values": [LOAD[1]]}, **more))


def relaxer(n: int, mode: str, layout: str, steps: int):
    """A callable running `steps` viscous steps of the mode's patch in one layout (friction
    compiled in, as the patches have it)."""
    from dynfab.kernels.structure_relaxation import StructureRelaxation

    structure = patch(n, mode).structure
    order = "scatter" if layout == "grouped" else "gather"
    solver = StructureRelaxation(structure, layout=layout, order=order, damping="viscous",
                                 damping_coefficient=DAMPING)
    solver.check_interval, solver.chunk = 1 << 30, steps
    loads = solver.chain_loads(LOAD)
    return structure.rest_position.shape[0], lambda: solver.relax(
        structure.rest_position, loads, None, tolerance=0.0, max_steps=steps)


def step_costs(sizes, modes) -> list[dict]:
    """ns per node and step of each (size, layout, mode), modes alternating per repeat."""
    rows = []
    for n in sizes:
        for layout, work in (("grouped", STEP_WORK), ("node_parallel", PER_STEP_WORK)):
            nodes = {}
            runs = {}
            for mode in modes:
                count, _ = relaxer(n, mode, layout, 1)
                steps = max(10, int(work / count))
                nodes[mode], runs[mode] = count, relaxer(n, mode, layout, steps)[1]
                runs[mode]()  # compile / load the kernels, warm the caches
            best = {mode: np.inf for mode in modes}
            for repeat in range(REPEATS):
                for mode in (modes if repeat % 2 == 0 else modes[::-1]):
                    began = time.perf_counter()
                    runs[mode]()
                    best[mode] = min(best[mode], time.perf_counter() - began)
            for mode in modes:
                steps = max(10, int(work / nodes[mode]))
                ns = 1e9 * best[mode] / (nodes[mode] * steps)
                rows.append({"n": n, "layout": layout, "mode": mode, "nodes": nodes[mode],
                             "steps": steps, "seconds": best[mode], "ns_per_node_step": ns})
            fixed = [r for r in rows if r["n"] == n and r["layout"] == layout and r["mode"] == "fixed"]
            for row in rows[-len(modes):]:
                if fixed:
                    row["over_fixed"] = row["ns_per_node_step"] / fixed[0]["ns_per_node_step"]
            for row in rows[-len(modes):]:
                print(f"{n:4d} x {n:<3d} {layout:10s} {row['mode']:9s} {row['nodes']:7d} nodes "
                      f"{row['ns_per_node_step']:8.1f} ns/node/step"
                      + (f"  {row['over_fixed']:.3f} x fixed" if "over_fixed" in row else ""),
                      flush=True)
    return rows


RULES = {"halving": dict(backtracks=0, secant=False), "line_search": {}}
"""The semi-implicit time step rules compared (module docstring): `StructureRelaxation`
attributes."""


def first_step_relaxer(model, rule: str):
    """A callable relaxing the first load step of `model` (a `FabricModel`) with the
    semi-implicit kernels under `rule`, to the scene's static tolerance; its Outcome."""
    from dynfab.kernels.structure_relaxation import StructureRelaxation

    relaxation = StructureRelaxation(model.structure, method="semi_implicit")
    for name, value in RULES[rule].items():
        setattr(relaxation, name, value)
    begun = model.start_of_step(model.initial_state(), model.load_values[0])
    return lambda: relaxation.relax(begun.positions, begun.chain_loads, begun.anchors,
                                    tolerance=model.scene.static.tolerance,
                                    max_steps=model.scene.dynamic.max_steps)[1]


def semi_rules(sizes, modes) -> list[dict]:
    """Per case and time step rule: the first load step's time steps, CG iterations, wall time."""
    from dynfab.model.fabric.model import FabricModel
    from dynfab.scene import load_scene

    cases = [("strip", FabricModel.from_scene(load_scene(ROOT / "runs" / "fabric_strip.toml")))]
    cases += [(f"{n}x{n} {mode}", patch(n, mode)) for n in sizes for mode in modes]
    rules = tuple(RULES)
    rows = []
    for index, (name, model) in enumerate(cases):
        runs = {rule: first_step_relaxer(model, rule) for rule in rules}
        for rule in rules:
            runs[rule]()  # compile / load the kernels
        seconds = {}
        outcomes = {}
        for rule in (rules if index % 2 == 0 else rules[::-1]):
            began = time.perf_counter()
            outcomes[rule] = runs[rule]()
            seconds[rule] = time.perf_counter() - began
        for rule in rules:
            out = {name: int(getattr(outcomes[rule], name)[0]) for name in
                   ("status", "steps", "rejected", "shortened", "cg_iterations")}
            residual = float(outcomes[rule].residual[0])
            rows.append({"case": name, "rule": rule, **out, "residual_N": residual,
                         "seconds": seconds[rule]})
            print(f"{name:18s} {rule:12s} {out['steps']:6d} steps {out['rejected']:5d} rejected "
                  f"{out['shortened']:5d} shortened {out['cg_iterations']:7d} CG "
                  f"{seconds[rule]:8.3f} s", flush=True)
        by_rule = {row["rule"]: row for row in rows[-len(rules):]}
        before = by_rule["halving"]
        for rule in rules:
            after = by_rule[rule]
            if rule != "halving":
                print(f"{name:18s} {rule} / halving: steps {after['steps'] / before['steps']:.3f}, "
                      f"CG {after['cg_iterations'] / before['cg_iterations']:.3f}, "
                      f"wall {after['seconds'] / before['seconds']:.3f}", flush=True)
    return rows


SOLVERS = {"static": ["--solver", "static"], "dynamic": ["--solver", "dynamic"],
           "semi": ["--solver", "dynamic", "--method", "semi_implicit"]}
"""`dynfab run` options of each solver timed by `run_times` (dynamic: explicit, kinetic)."""


def run_times() -> list[dict]:
    """Wall time of `dynfab run` per scene and solver, the solvers' order rotated per scene."""
    dynfab = Path(sys.executable).parent / "dynfab"
    names = list(SOLVERS)
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for index, scene in enumerate(SCENES):
            row = {"scene": scene}
            for solver in names[index % 3:] + names[:index % 3]:
                out = Path(tmp) / f"{scene}_{solver}.h5"
                command = [str(dynfab), "run", str(ROOT / "runs" / f"{scene}.toml"), "--out",
                           str(out), "--quiet", *SOLVERS[solver]]
                began = time.perf_counter()
                done = subprocess.run(command, capture_output=True, text=True)
                row[f"{solver}_s"] = time.perf_counter() - began
                row[f"{solver}_exit"] = done.returncode
                if done.returncode:
                    row[f"{solver}_error"] = done.stderr.strip().splitlines()[-1:]
            row["dynamic_over_static"] = row["dynamic_s"] / row["static_s"]
            row["semi_over_static"] = row["semi_s"] / row["static_s"]
            print(f"{scene:22s} static {row['static_s']:7.2f} s   dynamic {row['dynamic_s']:7.2f} s"
                  f" ({row['dynamic_over_static']:.2f} x)   semi-implicit {row['semi_s']:7.2f} s"
                  f" ({row['semi_over_static']:.2f} x)", flush=True)
            rows.append(row)
    return rows


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sizes", default="8,16,32", help="patch sizes n (n x n yarns)")
    parser.add_argument("--modes", default="fixed,affine,periodic",
                        help="comma-separated subset of fixed,affine,periodic")
    parser.add_argument("--no-runs", action="store_true", help="skip the dynfab run timings")
    parser.add_argument("--parts", default="steps,runs,semi",
                        help="comma-separated subset of steps,runs,semi (module docstring)")
    parser.add_argument("--semi-sizes", default="8,16", help="patch sizes n of part semi")
    parser.add_argument("--output", type=Path, default=OUTPUT)
    args = parser.parse_args(argv)
    sizes = [int(v) for v in args.sizes.split(",")]
    modes = args.modes.split(",")
    parts = args.parts.split(",")
    result = {"command": "python benchmarks/fabric_planes.py " + " ".join(argv or sys.argv[1:]),
              "machine": platform.platform(), "processor": platform.processor(),
              "load_N": LOAD, "damping_per_s": DAMPING, "repeats": REPEATS}
    if "steps" in parts:
        result["steps"] = step_costs(sizes, modes)
    if "runs" in parts and not args.no_runs:
        result["runs"] = run_times()
    if "semi" in parts:
        result["semi_rules"] = semi_rules([int(v) for v in args.semi_sizes.split(",")], modes)
    args.output.write_text(json.dumps(result, indent=1) + "\n")
    print(f"wrote {args.output}")


if __name__ == "__main__":
    main()
