"""Benchmark of the fabric's static solver (docs/model.md sections 6, 10) on clamped patches.

Run:  python benchmarks/fabric_static.py     (prints a table, writes benchmarks/fabric_static.json)

Balanced square patches of n warps x n wefts at the paper's mesh density (14 segments
per crossing, crossing spacing 0.1/16 m, paper yarns, k_c = 1e5 N/m), n = 4, 8, 16. Per
size, warm (one untimed run compiles), best of a few repeats (time.perf_counter):

- one force step (warp 0.3 N, weft 0.1 N per yarn) from the as-woven state, without and
  with friction, through `FabricStaticSolver.step` (its inertia check included): the
  step's time, its Newton iterations and the time per iteration;
- at the converged frictionless state, the pieces of one Newton iteration: gradient,
  Hessian assembly (numba values + CSC), SuperLU factor and solve, with its default
  options (COLAMD, partial pivoting) and in the symmetric mode the solver uses;
- the inertia: Haynsworth's Schur complement over per-yarn banded LDL^T with the dense
  complement by Bunch-Kaufman (`dynfab.fabric.inertia`, what the solver uses), against
  the dense eigenvalues of the whole Hessian (numpy eigvalsh), where that fits (n <= 8).
"""

from __future__ import annotations

import json
import platform
import time
from pathlib import Path

import numpy as np
import scipy
import scipy.sparse.linalg

from dynfab.fabric import inertia
from dynfab.fabric.spec import FabricSpec, Family, Friction
from dynfab.fabric.static import FabricStaticSolver, _sparse_solve

OUTPUT = Path(__file__).resolve().parent / "fabric_static.json"
SIZES = (4, 8, 16)
PER_CROSSING = 14
"""Segments per crossing (the paper's 224 segments for 16 crossings)."""
SPACING = 0.1 / 16
"""Crossing spacing [m] (the paper's L / N_we)."""
FRICTION = Friction(alpha=0.2, beta=1e3, contact_length=2e-3, fiber_radius=1e-3)
LOADS = (0.3, 0.1)
"""(warp, weft) end forces of the timed step [N]."""


def spec(n: int, friction) -> FabricSpec:
    yarn = Family(length=n * SPACING, segments=PER_CROSSING * n, amplitude=0.5e-3, EA=13.72,
                  EI=1.47e-7, kawabata_C=0.2e-3, kawabata_K=0.2)
    return FabricSpec(warp=yarn, weft=yarn, warps=n, wefts=n, friction=friction,
                      warp_values=(LOADS[0],), weft_values=(LOADS[1],))


def best(function, repeats: int) -> float:
    """Best wall time of `repeats` calls [s], after one untimed call."""
    function()
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        function()
        times.append(time.perf_counter() - start)
    return min(times)


def measure(n: int) -> dict:
    row = {"n": n, "segments_per_yarn": PER_CROSSING * n}
    for name, friction in (("frictionless", None), ("friction", FRICTION)):
        solver = FabricStaticSolver(spec(n, friction))
        start = solver.initial_state()
        holder = {}

        def step():
            holder["out"] = solver.step(start, *LOADS)

        seconds = best(step, 3 if n < 16 else 1)
        record = holder["out"][1]
        row[name] = {"step_s": seconds, "newton_iterations": int(record["iterations"]),
                     "friction_solves": int(record["friction_solves"]),
                     "s_per_iteration": seconds / max(int(record["iterations"]), 1),
                     "residual_N": float(record["residual"]),
                     "negative_eigenvalues": int(record["negative_eigenvalues"])}
    solver = FabricStaticSolver(spec(n, None))
    state = solver.step(solver.initial_state(), *LOADS)[0]
    pos, anchors = state.positions, state.anchors
    limit = np.zeros(n * n)
    P = solver.yarn_loads(*LOADS)
    H = solver.hessian(pos, anchors, limit)
    g = solver.gradient(pos, P, anchors, limit).ravel()[solver.free]
    repeats = 5 if n < 16 else 2
    row["dofs_free"] = int(H.shape[0])
    row["hessian_nonzeros"] = int(H.nnz)
    row["gradient_s"] = best(lambda: solver.gradient(pos, P, anchors, limit), repeats)
    row["hessian_s"] = best(lambda: solver.hessian(pos, anchors, limit), repeats)
    row["splu_default_s"] = best(lambda: scipy.sparse.linalg.splu(H).solve(-g), repeats)
    row["splu_symmetric_s"] = best(lambda: _sparse_solve(H, -g), repeats)
    result = inertia.inertia(solver, pos, anchors, limit)
    row["schur_size"] = result.schur_size
    row["inertia_schur_s"] = best(lambda: inertia.inertia(solver, pos, anchors, limit), repeats)
    if n <= 8:
        dense = H.toarray()
        row["inertia_dense_eigvalsh_s"] = best(lambda: np.linalg.eigvalsh(dense), 2)
        row["dense_negatives"] = int(np.count_nonzero(np.linalg.eigvalsh(dense) < 0))
    row["schur_negatives"] = result.negatives
    return row


def main() -> None:
    rows = [measure(n) for n in SIZES]
    print(f"{'n':>3} {'dofs':>6} {'iter fl/fr':>10} {'s/iter fl':>10} {'s/iter fr':>10} "
          f"{'hess':>8} {'splu':>8} {'splu sym':>8} {'schur':>8} {'dense':>8}")
    for r in rows:
        print(f"{r['n']:>3} {r['dofs_free']:>6} "
              f"{r['frictionless']['newton_iterations']:>4}/{r['friction']['newton_iterations']:<5} "
              f"{r['frictionless']['s_per_iteration']:>10.2e} {r['friction']['s_per_iteration']:>10.2e} "
              f"{r['hessian_s']:>8.1e} {r['splu_default_s']:>8.1e} {r['splu_symmetric_s']:>8.1e} "
              f"{r['inertia_schur_s']:>8.1e} "
              f"{r.get('inertia_dense_eigvalsh_s', float('nan')):>8.1e}")
    OUTPUT.write_text(json.dumps({
        "machine": platform.processor() or platform.machine(),
        "python": platform.python_version(), "numpy": np.__version__,
        "scipy": scipy.__version__, "rows": rows}, indent=2) + "\n")
    print(f"wrote {OUTPUT}")


if __name__ == "__main__":
    main()
