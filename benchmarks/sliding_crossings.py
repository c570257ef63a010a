"""What crossings that slide cost (docs/model.md 11.13): one static Newton iteration on a
clamped patch of the paper's yarns, and on shear specimens, with fixed crossings and with
sliding ones, in one run.

Run:  python benchmarks/sliding_crossings.py            (n x n patches, n = 8, 16, 32; the
                                                          150 x 450 mm bias specimen)
      python benchmarks/sliding_crossings.py --sizes 8,16 --specimens ""

A Newton iteration of the static solver's sparse backend (`dynfab.solvers.newton_sparse`):
the gradient, the Hessian on the unknowns, and the Newton direction (the factorisation in the
pattern's nested-dissection order, PARDISO where MKL is installed, else SuperLU), at the
state one load step has reached (each patch's warps pulled by 0.01 N, wefts 0.005 N, a
woven-in contact of 0.01 N, the paper's friction; a specimen's scene file at its step 1's
start, after its step 0), best of `REPEATS` rounds, the two kinds alternating within each
round. Prints the times and their ratio and writes benchmarks/sliding_crossings.json.
"""

from __future__ import annotations

import argparse
import json
import re
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
OUTPUT = ROOT / "benchmarks" / "sliding_crossings.json"
REPEATS = 5
FRICTION = {"alpha": 0.2, "beta": 1e3, "contact_length": 2e-3, "fiber_radius": 1e-3}


def solved_backend(n: int, motion: str):
    """(the patch's sparse backend, its state after one load step) for one crossing motion."""
    from dynfab.model.fabric.model import FabricModel
    from dynfab.reports.fabric_data import paper_patch_scene
    from dynfab.solvers.static import StaticSolver

    load = {"control": "force", "values": [0.01], "weft_values": [0.005]}
    scene = paper_patch_scene(n, n, friction=FRICTION, load=load,
                              crossing={"motion": motion, "preload": 0.01})
    solver = StaticSolver(FabricModel.from_scene(scene))
    state, _ = solver.step(solver.initial_state(), solver.model.step_load(0))
    start = solver.model.start_of_step(state, solver.model.step_load(0))
    return solver.backend, start


def solved_specimen_backend(path: str, motion: str):
    """(a specimen scene file's sparse backend, its step 1's start after step 0) with the
    crossing motion `motion`."""
    from dynfab.model.fabric.specimen_model import SpecimenModel
    from dynfab.scene import parse_scene_text
    from dynfab.solvers.static import StaticSolver

    text = re.sub(r'(?m)^motion = "\w+"\n', "", Path(path).read_text())
    text = text.replace("[crossing]", f'[crossing]\nmotion = "{motion}"', 1)
    solver = StaticSolver(SpecimenModel(parse_scene_text(text)))
    state, _ = solver.step(solver.initial_state(), solver.model.step_load(0))
    start = solver.model.start_of_step(state, solver.model.step_load(1))
    return solver.backend, start


def iteration(backend, start) -> float:
    """Seconds of one Newton iteration's pieces at the step's start."""
    pos, P, anchors = start.positions, start.chain_loads, start.anchors
    began = time.perf_counter()
    limit = backend.friction_limits(pos)
    grad = backend.gradient(pos, P, anchors, limit)
    H = backend.hessian(pos, anchors, limit)
    backend._direction(H, backend.pattern.reduce(grad))
    return time.perf_counter() - began


def measure(n: int | str) -> dict:
    """The two motions' best iteration times on an n x n patch or a specimen's scene file."""
    made = solved_backend if isinstance(n, int) else solved_specimen_backend
    kinds = {motion: made(n, motion) for motion in ("fixed", "sliding")}
    for backend, start in kinds.values():
        iteration(backend, start)  # compile and analyse once
    best = {motion: np.inf for motion in kinds}
    for _ in range(REPEATS):
        for motion, (backend, start) in kinds.items():
            best[motion] = min(best[motion], iteration(backend, start))
    unknowns = kinds["fixed"][0].pattern.free_count
    name = f"{n} x {n}" if isinstance(n, int) else Path(n).stem
    return {"patch": name, "unknowns": int(unknowns), "fixed_s": best["fixed"],
            "sliding_s": best["sliding"], "sliding_over_fixed": best["sliding"] / best["fixed"]}


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sizes", default="8,16,32")
    parser.add_argument("--specimens", default="runs/cao2008_bias_150x450.toml",
                        help="specimen scene files, comma-separated")
    args = parser.parse_args(argv)
    rows = []
    cases = [int(v) for v in args.sizes.split(",") if v]
    cases += [str(ROOT / v) for v in args.specimens.split(",") if v]
    for n in cases:
        row = measure(n)
        rows.append(row)
        print(f"{row['patch']:>8} ({row['unknowns']:6d} unknowns): fixed {1e3 * row['fixed_s']:8.2f}"
              f" ms, sliding {1e3 * row['sliding_s']:8.2f} ms per Newton iteration, "
              f"{row['sliding_over_fixed']:.2f} x", flush=True)
    OUTPUT.write_text(json.dumps({"rows": rows, "repeats": REPEATS}, indent=1) + "\n")
    print(f"wrote {OUTPUT.relative_to(ROOT)}")


if __name__ == "__main__":
    main()
