"""The one static Newton of issue 36, measured: the paper's yarn solved by the banded backend
(its Newton compiled in numba, chain by chain: the shipped route) and by the sparse backend (the
fabric's Newton, a Python loop around a sparse factorisation, which takes any structure), in
one run, turn about.

Run:  python benchmarks/one_newton.py [--rounds 3] [--out benchmarks/one_newton.json]
      (prints a table, writes the JSON file)

Scenes (224 segments, 16 crossings, 40 load steps to 10 mm): runs/paper_fig3.toml's first
entry (K = 0.02 m/N, frictionless) and runs/paper_fig5.toml's first (friction on), each its
whole load path from the as-woven state by `StaticSolver.step`, the backend set by hand.

Per scene: each backend's best wall time over the rounds and their ratio; the parts of the
sparse backend's time spent in its Newton's sparse solves (`_sparse_solve`) and in its
certificate (`certify_patch`, `escape_patch`), cProfile's cumulative times in one extra run;
the floor of a one Newton with the banded linear algebra: the sparse time without those two
parts (as if a banded solve and the banded certificate cost nothing) over the banded time;
and the largest position difference between the two paths' last steps against the sum of
their error bounds (both solve the same equilibrium: tests/test_static_backends.py).
"""

from __future__ import annotations

import argparse
import cProfile
import json
import pstats
import time
from pathlib import Path

import numpy as np

from dynfab.model.builders import build_model
from dynfab.scene import expand_sweep, load_scene
from dynfab.solvers.newton_banded import BandedNewton
from dynfab.solvers.newton_sparse import SparseNewton
from dynfab.solvers.static import StaticSolver

ROOT = Path(__file__).resolve().parent.parent
OUTPUT = Path(__file__).resolve().parent / "one_newton.json"
SCENES = {"paper_fig3, K = 0.02 (frictionless)": ("paper_fig3.toml", 0),
          "paper_fig5, first entry (friction)": ("paper_fig5.toml", 0)}
"""Label -> (scene file of runs/, its sweep entry)."""


def path(model, backend):
    """(wall time [s], last positions (n, 2), largest error bound [m]) of the whole load path."""
    solver = StaticSolver(model)
    solver.backend = backend(model)
    state, bound = model.initial_state(), 0.0
    began = time.perf_counter()
    for index in range(len(model.load_values)):
        state, record = solver.step(state, model.step_load(index))
        bound = max(bound, float(np.max(record["error_estimate"])))
    return time.perf_counter() - began, np.asarray(state.positions, float), bound


SHARES = {"newton_solves": ("_sparse_solve",), "certificate": ("certify_patch", "escape_patch")}
"""A part of the sparse backend's time -> the functions whose cumulative time it is (disjoint:
the certificate factors on its own)."""


def shares(model) -> dict:
    """The parts (`SHARES`) of the sparse backend's path time [-]."""
    profile = cProfile.Profile()
    profile.enable()
    path(model, SparseNewton)
    profile.disable()
    stats = pstats.Stats(profile).stats
    total = max(v[3] for v in stats.values())
    return {part: sum(v[3] for k, v in stats.items() if k[2] in names) / total
            for part, names in SHARES.items()}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument("--out", type=Path, default=OUTPUT)
    args = parser.parse_args()
    figures = {}
    for name, (file, entry) in SCENES.items():
        model = build_model(expand_sweep(load_scene(ROOT / "runs" / file))[entry])
        for backend in (BandedNewton, SparseNewton):  # compile and warm both
            path(model, backend)
        best = {BandedNewton: np.inf, SparseNewton: np.inf}
        for _ in range(args.rounds):
            for backend in best:
                seconds, positions, bound = path(model, backend)
                best[backend] = min(best[backend], seconds)
                if backend is BandedNewton:
                    banded, banded_bound = positions, bound
                else:
                    sparse, sparse_bound = positions, bound
        part = shares(model)
        ratio = best[SparseNewton] / best[BandedNewton]
        figures[name] = {
            "steps": len(model.load_values), "banded_s": best[BandedNewton],
            "sparse_s": best[SparseNewton], "ratio": ratio,
            **{f"sparse_{k}_share": v for k, v in part.items()},
            "floor_ratio": ratio * (1.0 - sum(part.values())),
            "difference_m": float(np.abs(banded - sparse).max()),
            "bounds_m": banded_bound + sparse_bound}
        f = figures[name]
        print(f"{name}: {f['steps']} steps, banded {f['banded_s']:.3f} s, sparse "
              f"{f['sparse_s']:.3f} s ({ratio:.1f}x; its Newton's solves "
              f"{100 * part['newton_solves']:.0f} %, its certificate "
              f"{100 * part['certificate']:.0f} %; without them {f['floor_ratio']:.1f}x), last "
              f"positions {f['difference_m']:.2e} m apart (bounds {f['bounds_m']:.2e} m)",
              flush=True)
    args.out.write_text(json.dumps({"rounds": args.rounds, "figures": figures}, indent=2) + "\n")
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
