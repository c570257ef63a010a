"""Whether GMRES on the kept factors pays on the planar fabric (docs/model.md 11.10,
`SOLVE_ON_KEPT_FACTORS`): `StaticSolver.step` on benchmarks/fabric.py's clamped n x n patch
with the Hessian solves tried on the step's last factors first and without, in turns in one
process (best of --rounds each), with the factorisations and the GMRES solves.

Run: PYTHONPATH=. python benchmarks/kept_factor.py [--sizes 16,32] [--rounds 3]
     (prints a table, writes benchmarks/kept_factor.json)
"""

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import fabric as patch  # noqa: E402  (benchmarks/fabric.py: the patch and its load step)
from dynfab.model.fabric import assembly, ordering  # noqa: E402
from dynfab.solvers.static import StaticSolver  # noqa: E402

OUTPUT = Path(__file__).resolve().parent / "kept_factor.json"


def step_time(solver: StaticSolver, start) -> tuple:
    """(wall time [s], factorisations, GMRES solves) of one step."""
    began = time.perf_counter()
    solver.step(start, patch.LOAD)
    wall = time.perf_counter() - began
    kept = solver.backend.kept
    return wall, kept.factorisations, kept.krylov_solves


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sizes", default="16,32")
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument("--out", type=Path, default=OUTPUT)
    args = parser.parse_args()
    warm = StaticSolver(patch.patch_model(4))
    warm.step(warm.initial_state(), patch.LOAD)
    rows = []
    for n in (int(s) for s in args.sizes.split(",")):
        solver = StaticSolver(patch.patch_model(n))
        start = solver.initial_state()
        best = {True: (np.inf, 0, 0), False: (np.inf, 0, 0)}
        for _ in range(args.rounds):
            for on_kept in (True, False):
                assembly.SOLVE_ON_KEPT_FACTORS = on_kept
                solver.backend.kept = None
                timing = step_time(solver, start)
                best[on_kept] = min(best[on_kept], timing)
        assembly.SOLVE_ON_KEPT_FACTORS = False
        row = {"n": n, "unknowns": int(solver.backend.pattern.free_count),
               "with_kept_s": best[True][0], "with_kept_factorisations": best[True][1],
               "with_kept_gmres_solves": best[True][2], "without_s": best[False][0],
               "without_factorisations": best[False][1]}
        rows.append(row)
        print(f"{n} x {n} ({row['unknowns']} unknowns): with GMRES on kept factors "
              f"{row['with_kept_s']:.3f} s ({row['with_kept_factorisations']} factorisations, "
              f"{row['with_kept_gmres_solves']} by GMRES), without {row['without_s']:.3f} s "
              f"({row['without_factorisations']} factorisations): "
              f"with / without {row['with_kept_s'] / row['without_s']:.2f}", flush=True)
    args.out.write_text(json.dumps({"rounds": args.rounds, "sizes": rows}, indent=1))


if __name__ == "__main__":
    main()
