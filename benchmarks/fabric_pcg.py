"""Measurement: preconditioned CG with per-yarn banded solves in place of the static step's sparse LU.

Run:  python benchmarks/fabric_pcg.py     (prints a table, writes benchmarks/fabric_pcg.json)

The question before writing a semi-implicit fabric step (docs/model.md section 5; each step a linear
solve with the Hessian, (M / h^2 + H) dx = f, Newton as h -> inf): can its linear solves be
conjugate gradients preconditioned by each yarn's own banded matrix (the per-yarn blocks
the kernels and the inertia count already handle), dropping only the crossing couplings?
That is the data-parallel solve a GPU step would use. It is measured here inside the static
solver itself, so everything else is equal: `PCGStatic` is `FabricStaticSolver` with its
Newton direction -H^-1 g (`_direction`, SuperLU) computed instead by CG on H preconditioned
by B = the per-yarn blocks of H (every entry joining two yarns dropped: the contact's
-dR/dg between warp z and weft z, the Huber block's x_warp / y_weft entry; each crossing
dof keeps its diagonal), each block factored once per Newton iteration by banded Cholesky
(scipy.linalg.cholesky_banded, all yarns in one call: `PCGStatic._preconditioner`), to a relative residual of CG_RTOL. Where B is not positive
definite or CG does not reach it in CG_MAX iterations, the step falls back to SuperLU
(counted). The coupled friction Newton (non-symmetric) keeps SuperLU.

Case: the patches of benchmarks/fabric_solvers.py (paper yarns, 8 segments per crossing,
force control, three load steps, tolerance 1e-10 N), n = 4 and 8, without and with the
paper's friction. Per load step, warm, fastest of REPEATS runs: the static step's time and
the PCG step's, its Newton iterations, CG iterations per Newton iteration (mean, max),
fallbacks, and the largest position difference between the two (both stop at the residual
tolerance, so within ||H^-1|| 2e-10 of each other).
"""

from __future__ import annotations

import json
import os
import platform
import time
from pathlib import Path

import numpy as np
import scipy.linalg
import scipy.sparse
import scipy.sparse.linalg

from dynfab.fabric.static import FabricStaticSolver
from dynfab.kernels.fabric_arrays import PAPER_FRICTION, paper_patch

OUTPUT = Path(__file__).resolve().parent / "fabric_pcg.json"
SIZES = (4, 8)
LOADS = ((0.1, 0.03), (0.3, 0.1), (0.5, 0.2))
TOLERANCE = 1e-10
CG_RTOL = 1e-12
"""CG's relative residual |H d + g| / |g|: a Newton direction needs far less, but the
line search and the stopping test then see the same steps as SuperLU's."""
CG_MAX = 2000
REPEATS = 3


class PCGStatic(FabricStaticSolver):
    """The static solver with its Newton direction by per-yarn preconditioned CG."""

    def __init__(self, spec):
        super().__init__(spec)
        f = self.fabric
        dof_yarn = np.repeat(np.arange(self.yarns), 2 * np.diff(f.yarn_start))
        unknown = self.pattern.index >= 0
        self.unknown_yarn = np.zeros(self.pattern.free_count, int)
        self.unknown_yarn[self.pattern.index[unknown]] = dof_yarn[unknown]
        assert np.all(np.diff(self.unknown_yarn) >= 0)  # yarn after yarn (no ties)
        self.cg_iterations, self.fallbacks = [], 0

    def _preconditioner(self, H):
        """B^-1 as a LinearOperator, or None if B is not positive definite.

        The unknowns of a clamped patch run yarn after yarn, so B (H without the entries
        joining two yarns) is one band matrix whose bands never cross a yarn's boundary:
        one banded Cholesky of it is every yarn's own, done in one LAPACK call."""
        H = H.tocoo()
        keep = self.unknown_yarn[H.row] == self.unknown_yarn[H.col]
        row, col, value = H.row[keep], H.col[keep], H.data[keep]
        width = int(np.abs(row - col).max())
        band = np.zeros((width + 1, H.shape[0]))
        upper = col >= row  # upper form: band[width + i - j, j] = B[i, j]
        np.add.at(band, (width + row[upper] - col[upper], col[upper]), value[upper])
        try:
            factor = scipy.linalg.cholesky_banded(band)
        except np.linalg.LinAlgError:
            return None
        n = H.shape[0]
        return scipy.sparse.linalg.LinearOperator(
            (n, n), matvec=lambda r: scipy.linalg.cho_solve_banded((factor, False), r))

    def _direction(self, H, g):
        B = self._preconditioner(H)
        if B is not None:
            count = [0]
            d, info = scipy.sparse.linalg.cg(H, -g, rtol=CG_RTOL, atol=0.0, maxiter=CG_MAX, M=B,
                                             callback=lambda _: count.__setitem__(0, count[0] + 1))
            if info == 0 and g @ d < 0.0:
                self.cg_iterations.append(count[0])
                return d
        self.fallbacks += 1
        return super()._direction(H, g)


def spec(n, friction):
    return paper_patch(n, n, friction=friction, warp_values=tuple(v[0] for v in LOADS),
                       weft_values=tuple(v[1] for v in LOADS), tolerance=TOLERANCE)


def run_path(solver):
    state = solver.initial_state()
    times, records, states = [], [], []
    for warp_value, weft_value in LOADS:
        began = time.perf_counter()
        state, record = solver.step(state, warp_value, weft_value)
        times.append(time.perf_counter() - began)
        records.append(record)
        states.append(state)
    return np.array(times), records, states


def fastest(make):
    """(fastest per-step times of REPEATS warm runs, the last solver, records, states)."""
    run_path(make())
    best = None
    for _ in range(REPEATS):
        solver = make()
        times, records, states = run_path(solver)
        best = times if best is None else np.minimum(best, times)
    return best, solver, records, states


def measure(n, friction) -> dict:
    s_times, _, s_records, s_states = fastest(lambda: FabricStaticSolver(spec(n, friction)))
    p_times, pcg, p_records, p_states = fastest(lambda: PCGStatic(spec(n, friction)))
    counts = np.array(pcg.cg_iterations)
    return {"n": n, "friction": friction is not None, "unknowns": pcg.pattern.free_count,
            "static_s": s_times.tolist(), "pcg_s": p_times.tolist(),
            "static_newton": [int(r["iterations"]) for r in s_records],
            "pcg_newton": [int(r["iterations"]) for r in p_records],
            "cg_iterations_mean": float(counts.mean()) if counts.size else None,
            "cg_iterations_max": int(counts.max()) if counts.size else None,
            "cg_solves": int(counts.size), "fallbacks": pcg.fallbacks,
            "position_difference_m": [float(np.abs(a.positions - b.positions).max())
                                      for a, b in zip(s_states, p_states)]}


def main() -> None:
    rows = []
    print(f"{'patch':>6} {'friction':>8} {'unknowns':>8} {'static s/step':>14} {'pcg s/step':>11} "
          f"{'newton s/p':>10} {'cg mean':>8} {'cg max':>7} {'fallbacks':>9} {'|dx| m':>8}")
    for n in SIZES:
        for friction in (None, PAPER_FRICTION):
            row = measure(n, friction)
            rows.append(row)
            print(f"{n:>2} x{n:<2} {str(row['friction']):>8} {row['unknowns']:>8} "
                  f"{np.mean(row['static_s']):>14.4f} {np.mean(row['pcg_s']):>11.4f} "
                  f"{sum(row['static_newton']):>5}/{sum(row['pcg_newton']):<4} "
                  f"{row['cg_iterations_mean'] or 0:>8.1f} {row['cg_iterations_max'] or 0:>7} "
                  f"{row['fallbacks']:>9} {max(row['position_difference_m']):>8.1e}", flush=True)
    result = {"machine": {"platform": platform.platform(), "cpus": os.cpu_count(),
                          "scipy": scipy.__version__},
              "case": {"sizes": SIZES, "loads_N": LOADS, "tolerance_N": TOLERANCE,
                       "cg_rtol": CG_RTOL, "repeats": REPEATS},
              "rows": rows}
    OUTPUT.write_text(json.dumps(result, indent=2) + "\n")


if __name__ == "__main__":
    main()
