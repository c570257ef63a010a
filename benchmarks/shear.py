"""In-plane shear specimens with the static solver (docs/model.md section 11): cost per Newton
iteration and iteration counts against the number of crossings, the sparse factorisations
against each other on the same Hessians, and the Cao et al. scenes' load paths.

    python benchmarks/shear.py [--sides 0.03,0.06,0.09,0.12] [--steps 4]
                               [--scenes runs/cao2008_frame.toml,...] [--scene-steps N]
                               [--friction-beta B] [--factor-scenes]
                               [--out benchmarks/shear.json]

- **scaling**: picture frames of the given sides (the Cao fabric of runs/cao2008_frame.toml),
  `--steps` load steps of 1 % of the side each; per size the crossings, unknowns, Newton
  iterations, wall time of the steps and their time per iteration; the exponent of time per
  iteration against crossings (least squares in log-log);
- **factorisations**: the Hessian of each size's last step (F_T frozen, on the unknowns),
  factored by SuperLU in its symmetric mode in the nested-dissection order the solver uses
  without MKL (`dynfab.model.fabric.ordering.OrderedLU`; its negative pivots), by SuperLU with
  its own COLAMD order, and by MKL PARDISO as symmetric indefinite (`dynfab.linalg.pardiso`,
  the analysis and factorisation, then the factorisation alone on its analysis, as the
  Newton solves do; its inertia), where MKL is installed;
- **scenes**: each scene's path with the static solver until it ends or stops (a
  SolverError: the step, the reason), or its first `--scene-steps` steps after step 0; its
  crossings, steps, iterations, wall time and time per iteration (with the scaling's);
  `--factor-scenes` factors each scene's last Hessian as the scaling's (without COLAMD);
  `--friction-beta` replaces the scenes' [friction] beta (1e6 holds the bias specimens'
  free edges, which slide and stop the paper's law early: docs/results.md, to time many
  steps).

Every path also counts the Newton solves' factorisations and the solves by GMRES on kept
factors instead (`dynfab.model.fabric.kept_factor`).

Prints the figures and writes them to the JSON file. Times are wall-clock on this machine
(shared: compare ratios within one run).
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np
import scipy.sparse
import scipy.sparse.linalg

from dynfab.errors import SolverError
from dynfab.model.fabric import ordering
from dynfab.linalg import pardiso
from dynfab.model.builders import build_model
from dynfab.scene import load_scene, with_key
from dynfab.solvers.by_name import make_solver

ROOT = Path(__file__).resolve().parents[1]
FRAME = ROOT / "runs" / "cao2008_frame.toml"


def _path(model, steps: int | None, say=print) -> dict:
    """Run the model's load path (its first `steps` + 1 steps, or all) with the static
    solver: steps done, Newton iterations, wall time, the stop's reason."""
    solver = make_solver(model, "static")
    state = model.initial_state()
    total = len(model.load_values) if steps is None else min(steps + 1, len(model.load_values))
    iterations, started, stop = 0, time.perf_counter(), ""
    done = 0
    for index in range(total):
        try:
            state, record = solver.step(state, model.step_load(index))
            model.check_step(record)
        except SolverError as error:
            stop = str(error)
            break
        iterations += int(np.max(record["iterations"]))
        done += 1
        say(f"  step {index}: d = {1e3 * model.step_load(index):.4g} mm, "
            f"{int(np.max(record['iterations']))} iterations, clamp force "
            f"{float(record['clamp_force']):.4g} N")
    wall = time.perf_counter() - started
    kept = getattr(solver.backend, "kept", None)
    return {"steps": done, "iterations": iterations, "wall_s": wall, "stopped": stop,
            "factorisations": getattr(kept, "factorisations", None),
            "krylov_solves": getattr(kept, "krylov_solves", None),
            "state": state, "solver": solver}


def _pardiso_factor(H):
    """(analysis and factorisation [s], factorisation on the analysis [s], negatives,
    nnz(L)) of PARDISO's symmetric indefinite L D L^T of H (`dynfab.linalg.pardiso`), or
    None without MKL."""
    if not pardiso.available():
        return None
    started = time.perf_counter()
    factor = pardiso.SymmetricFactor(H)
    first = time.perf_counter() - started
    started = time.perf_counter()
    factor.refactor(H)
    return first, time.perf_counter() - started, factor.negatives, factor.fill


def factorisations(solver, state, colamd: bool = True) -> dict:
    """The three factorisations of the Hessian at `state` (module docstring); SuperLU's
    COLAMD one only if `colamd` (a minute or more at 60,000 unknowns)."""
    backend = solver.backend
    pos = state.positions
    H = backend.hessian(pos, state.anchors, backend.friction_limits(pos))
    order = ordering.fabric_order(backend.structure, backend.pattern)
    out = {"unknowns": int(H.shape[0]), "nonzeros": int(H.nnz)}
    # each factorisation of the matrix its Newton solves factor (`SparseNewton._direction`):
    # SuperLU without the explicit zeros, PARDISO with them (they keep its analysis)
    A = (0.5 * (H + H.T)).tocsc()  # the sum drops explicit zeros
    started = time.perf_counter()
    lu = ordering.OrderedLU(A, order)
    out["superlu_nested_dissection_s"] = time.perf_counter() - started
    out["superlu_negatives"] = int(np.count_nonzero(lu.lu.U.diagonal() < 0.0))
    out["superlu_fill"] = lu.fill
    if colamd:
        started = time.perf_counter()
        scipy.sparse.linalg.splu(H.tocsc())
        out["superlu_colamd_s"] = time.perf_counter() - started
    found = _pardiso_factor(H.tocsc())
    if found is not None:
        (out["pardiso_with_analysis_s"], out["pardiso_s"], out["pardiso_negatives"],
         out["pardiso_fill"]) = found
    return out


def scaling(sides, steps: int) -> list[dict]:
    rows = []
    for side in sides:
        scene = with_key(with_key(load_scene(FRAME), "specimen.fabric_side", side),
                         "specimen.side", side)
        scene = with_key(scene, "load.values", tuple(0.01 * side * k for k in range(1, steps + 1)))
        model = build_model(scene)
        print(f"picture frame of side {1e3 * side:g} mm: {model.structure.tie_a.size} crossings")
        run = _path(model, steps)
        row = {"side_m": side, "crossings": int(model.structure.tie_a.size),
               "nodes": int(model.structure.rest_position.shape[0]),
               **{k: run[k] for k in ("steps", "iterations", "wall_s", "stopped",
                                      "factorisations", "krylov_solves")}}
        row["s_per_iteration"] = run["wall_s"] / max(run["iterations"], 1)
        row["factorisations"] = factorisations(run["solver"], run["state"])
        print(f"  {row['iterations']} iterations in {row['wall_s']:.2f} s: "
              f"{1e3 * row['s_per_iteration']:.1f} ms per iteration; factorisations "
              + ", ".join(f"{k} {v:.3g}" for k, v in row["factorisations"].items()
                          if k.endswith("_s")))
        rows.append(row)
    return rows


def exponent(rows) -> float | None:
    """Slope of log(time per iteration) against log(crossings); None below two sizes."""
    if len({r["crossings"] for r in rows}) < 2:
        return None
    x = np.log([r["crossings"] for r in rows])
    y = np.log([r["s_per_iteration"] for r in rows])
    return float(np.polyfit(x, y, 1)[0])


def say_exponent(label: str, value: float | None) -> None:
    """Print the exponent, or that there are too few sizes for one."""
    print(f"{label}time per Newton iteration ~ crossings^{value:.2f}" if value is not None
          else f"{label}time per Newton iteration: fewer than two sizes, no exponent")


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sides", default="0.03,0.06,0.09,0.12")
    parser.add_argument("--steps", type=int, default=4)
    parser.add_argument("--scenes", default="")
    parser.add_argument("--scene-steps", type=int, default=None)
    parser.add_argument("--friction-beta", type=float, default=None)
    parser.add_argument("--factor-scenes", action="store_true",
                        help="factor each scene's last Hessian by SuperLU and PARDISO too")
    parser.add_argument("--out", default=str(ROOT / "benchmarks" / "shear.json"))
    args = parser.parse_args(argv)
    factoriser = "pardiso" if pardiso.available() else "superlu"
    print(f"the Newton solves factor by {factoriser} (DYNFAB_PARDISO=0: SuperLU alone)")
    rows = scaling([float(s) for s in args.sides.split(",") if s], args.steps)
    result = {"factoriser": factoriser, "scaling": rows, "exponent_per_iteration": exponent(rows),
              "scenes": []}
    say_exponent("", result["exponent_per_iteration"])
    for path in [p for p in args.scenes.split(",") if p]:
        print(f"{path}:")
        scene = load_scene(path)
        if args.friction_beta is not None:
            scene = with_key(scene, "friction.beta", args.friction_beta)
        model = build_model(scene)
        run = _path(model, args.scene_steps)
        entry = {"scene": path, "friction_beta": args.friction_beta,
                 "crossings": int(model.structure.tie_a.size),
                 "nodes": int(model.structure.rest_position.shape[0]),
                 **{k: run[k] for k in ("steps", "iterations", "wall_s", "stopped",
                                        "factorisations", "krylov_solves")}}
        entry["s_per_iteration"] = run["wall_s"] / max(run["iterations"], 1)
        if args.factor_scenes:
            entry["factorisations_at_end"] = factorisations(run["solver"], run["state"], False)
            print("  its last Hessian: " + ", ".join(
                f"{k} {v:.3g}" for k, v in entry["factorisations_at_end"].items()))
        print(f"  {entry['steps']} steps, {entry['iterations']} iterations, "
              f"{entry['wall_s']:.1f} s, {entry['factorisations']} factorisations, "
              f"{entry['krylov_solves']} kept-factor solves"
              + (f"; stopped: {entry['stopped']}" if entry["stopped"] else ""))
        result["scenes"].append(entry)
        Path(args.out).write_text(json.dumps(result, indent=2) + "\n")  # each scene kept
    rows = rows + [s for s in result["scenes"]]
    result["exponent_per_iteration_with_scenes"] = exponent(rows)
    say_exponent("with the scenes: ", result["exponent_per_iteration_with_scenes"])
    Path(args.out).write_text(json.dumps(result, indent=2) + "\n")
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
