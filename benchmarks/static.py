"""Benchmark of the static Newton solver (docs/model.md section 6) against scipy on the same energy.

Run:  python benchmarks/static.py            (prints a table, writes benchmarks/static.json)

Measured in one run, warm (every solver runs once to compile before timing;
each figure is the best of several repeats, `dynfab.timing.best_time`):

- one equilibrium: the paper's yarn (runs/paper_fig3.toml, entry K = 0.2 m/N,
  N = 224, 16 crossings, prestressed), one force step P = 0.3 N from the
  as-woven state, through `StaticSolver.step`, to 1e-11 N;
- the same equilibrium by scipy's L-BFGS-B on the same energy and gradient
  (dynfab.model.assembly), which stalls where energy differences reach rounding:
  timed to the residual it reaches, and dynfab timed to that residual too;
- the same equilibrium by a plain (line-search-free) Newton iteration with
  the model's Hessian converted to scipy.sparse and `spsolve`, from the same
  start, to 1e-11 N;
- the certificate of that equilibrium (`dynfab.solvers.certificate.certify_yarn`: one LDL^T
  with inertia, Lanczos for the lowest eigenvalue and its inertia proof, Hager's
  norm estimate), timed alone, as a share of the step that includes it;
- the 40-step traction curves of runs/paper_fig5.toml: friction on (entry 0),
  friction off (entry 1: the [friction] table with alpha = beta = 0), and
  without any [friction] table, for reference.

Aims: one equilibrium in at most 0.5 ms and at least 300x faster than
L-BFGS-B; the friction curve at most 3x the frictionless one; the certificate at
most 20 % of the step.
"""

from __future__ import annotations

import json
import platform
from dataclasses import replace
from pathlib import Path

import numpy as np
import scipy
import scipy.sparse as sparse
from scipy.optimize import minimize
from scipy.sparse.linalg import spsolve

from dynfab.model import assembly
from dynfab.linalg.banded import BANDWIDTH
from dynfab.solvers.certificate import certify_yarn
from dynfab.model.yarn import initial_state
from dynfab.model.builders import build_model
from dynfab.scene import Load, expand_sweep, load_scene, validate_scene, with_key
from dynfab.solvers.static import StaticSolver
from dynfab.timing import best_time

ROOT = Path(__file__).resolve().parent.parent
RUNS = ROOT / "runs"
OUTPUT = Path(__file__).resolve().parent / "static.json"
LOAD = 0.3
"""End force of the single equilibrium [N]."""
TOLERANCE = 1e-11
"""Residual of the reference solve [N] (docs/model.md section 6)."""


def equilibrium_scene():
    """The paper's yarn, K = 0.2 m/N, one force step P = 0.3 N."""
    entry = next(e for e in expand_sweep(load_scene(RUNS / "paper_fig3.toml"))
                 if e.warp.kawabata_K == 0.2)
    return validate_scene(replace(entry, load=Load(control="force", values=(LOAD,))))


class Energy:
    """V and dV/dq over the free dofs q of one yarn (no friction), through dynfab.model.assembly."""

    def __init__(self, model):
        self.yarn = model.yarns[0]
        self.free = ~model.fixed_dofs()
        self.start = model.per_yarn(initial_state(model).positions)[0].copy()
        c = self.yarn.crossing_node.size
        self.none = np.zeros(c)
        self.terms = np.zeros(6)
        self.grad = np.zeros_like(self.start)
        self.work = self.start.copy()

    def positions(self, q):
        flat = self.work.reshape(-1)
        flat[self.free] = q
        return self.work

    def energy(self, q):
        assembly.energies(self.positions(q), self.yarn, LOAD, self.none, self.none, self.terms)
        return self.terms.sum()

    def gradient(self, q):
        assembly.gradient(self.positions(q), self.yarn, LOAD, self.none, self.none, self.grad)
        return self.grad.reshape(-1)[self.free].copy()

    def residual(self, q):
        return np.abs(self.gradient(q)).max()


def lbfgs(energy: Energy):
    """scipy L-BFGS-B to its own stopping point; returns the result."""
    return minimize(energy.energy, energy.start.reshape(-1)[energy.free], jac=energy.gradient,
                    method="L-BFGS-B",
                    options={"maxiter": 200_000, "maxfun": 400_000, "maxcor": 20,
                             "ftol": 0.0, "gtol": 1e-13})


def sparse_newton(energy: Energy, tolerance: float, max_iterations: int = 100):
    """Plain Newton q -= H_ff^-1 g_f with the model's Hessian as scipy.sparse (CSR) and spsolve.

    Returns (q, iterations, residual).
    """
    yarn, free = energy.yarn, energy.free
    c = yarn.crossing_node.size
    R, limit, tangent = np.zeros(c), np.zeros(c), np.zeros(c)
    n = energy.start.size
    band = np.zeros((n, 2 * BANDWIDTH + 1))
    rows = np.repeat(np.arange(n), 2 * BANDWIDTH + 1)
    cols = rows + np.tile(np.arange(-BANDWIDTH, BANDWIDTH + 1), n)
    inside = (cols >= 0) & (cols < n)
    rows, cols = rows[inside], cols[inside]
    index = np.flatnonzero(free)
    q = energy.start.reshape(-1)[free].copy()
    for iteration in range(max_iterations + 1):
        g = energy.gradient(q)
        residual = np.abs(g).max()
        if residual <= tolerance or iteration == max_iterations:
            return q, iteration, residual
        pos = energy.positions(q)
        assembly.contact_state(pos, yarn, R, limit, tangent)
        assembly.hessian(pos, yarn, energy.none, energy.none, tangent, False, band)
        values = band.reshape(-1)[inside]
        H = sparse.csr_matrix((values, (rows, cols)), shape=(n, n))[index][:, index]
        q = q - spsolve(H.tocsc(), g)
    return q, max_iterations, residual


def traction_curve(scene):
    """A function solving the scene's whole load path from the as-woven state; and its model."""
    model = build_model(scene)
    solver = StaticSolver(model)

    def solve():
        state = initial_state(model)
        iterations = 0
        for value in model.load_values:
            state, record = solver.step(state, value)
            iterations += int(record["iterations"].sum())
        return iterations

    return solve, model


def first_step_iterations(scene) -> int:
    """Newton iterations of the scene's first load step (iteration limit raised to 5000)."""
    model = build_model(with_key(scene, "static.max_iterations", 5000))
    _, record = StaticSolver(model).step(initial_state(model), float(model.load_values[0]))
    return int(record["iterations"][0])


def main() -> dict:
    results = {"machine": platform.processor() or platform.machine(),
               "python": platform.python_version(), "numpy": np.__version__,
               "scipy": scipy.__version__}

    # one equilibrium through StaticSolver
    scene = equilibrium_scene()
    model = build_model(scene)
    start = initial_state(model)
    solver = StaticSolver(model, tolerance=TOLERANCE)
    _, record = solver.step(start, LOAD)
    t_newton = best_time(lambda: solver.step(start, LOAD), 200, warm=True)[0]
    results["equilibrium"] = {"time_s": t_newton, "iterations": int(record["iterations"][0]),
                              "residual_N": float(record["residual"][0])}
    reference = record["positions"][0]

    # the step's certificate (dynfab/solvers/certificate.py): its share of the step's time
    yarn, fixed = model.yarns[0], model.fixed_dofs()
    anchors = model.per_crossing(start.anchors)[0]
    t_certificate = best_time(lambda: certify_yarn(reference, yarn, anchors, fixed,
                                                   record["residual"][0]), 200, warm=True)[0]
    results["certificate"] = {"time_s": t_certificate, "step_time_s": t_newton,
                              "step_time_without_s": t_newton - t_certificate,
                              "share_of_step": t_certificate / t_newton}

    # scipy L-BFGS-B on the same energy
    energy = Energy(model)
    result = lbfgs(energy)
    reached = energy.residual(result.x)
    t_lbfgs = best_time(lambda: lbfgs(energy), 3, warm=True)[0]
    error = np.abs(energy.positions(result.x) - reference).max()
    loose = StaticSolver(model, tolerance=reached)
    _, loose_record = loose.step(start, LOAD)
    t_newton_loose = best_time(lambda: loose.step(start, LOAD), 200, warm=True)[0]
    results["lbfgs"] = {"time_s": t_lbfgs, "residual_N": float(reached), "iterations": int(result.nit),
                        "evaluations": int(result.nfev), "message": str(result.message),
                        "max_position_error_m": float(error),
                        "dynfab_time_to_same_residual_s": t_newton_loose,
                        "dynfab_iterations_to_same_residual": int(loose_record["iterations"][0])}

    # plain Newton with scipy.sparse and spsolve on the same energy and Hessian
    q, iterations, residual = sparse_newton(energy, TOLERANCE)
    t_sparse = best_time(lambda: sparse_newton(energy, TOLERANCE), 20, warm=True)[0]
    results["scipy_sparse_newton"] = {
        "time_s": t_sparse, "iterations": iterations, "residual_N": float(residual),
        "max_position_difference_m": float(np.abs(energy.positions(q) - reference).max())}

    # 40-step traction curves
    fig5 = load_scene(RUNS / "paper_fig5.toml")
    on, off = expand_sweep(fig5)
    curves = {"friction_on": on, "friction_off": off,
              "no_friction_table": validate_scene(replace(off, friction=None))}
    results["traction_curve"] = {}
    for name, curve_scene in curves.items():
        solve, curve_model = traction_curve(curve_scene)
        iterations = solve()
        results["traction_curve"][name] = {"time_s": best_time(solve, 20, warm=True)[0],
                                           "steps": len(curve_model.load_values),
                                           "newton_iterations": iterations}

    # Newton iterations of the first friction step (stick/slip active set) against k_t
    default_stick = on.warp.EA / (on.geometry.length / on.geometry.segments)
    results["first_friction_step_iterations"] = {
        f"{factor:g}": first_step_iterations(with_key(on, "friction.stick_stiffness",
                                                      factor * default_stick))
        for factor in (1, 10, 100, 1000)}

    curve = results["traction_curve"]
    results["ratios"] = {
        "lbfgs_over_dynfab_1e-11": t_lbfgs / t_newton,
        "lbfgs_over_dynfab_same_residual": t_lbfgs / t_newton_loose,
        "sparse_newton_over_dynfab": t_sparse / t_newton,
        "friction_on_over_off": curve["friction_on"]["time_s"] / curve["friction_off"]["time_s"],
        "friction_on_over_no_table": curve["friction_on"]["time_s"] / curve["no_friction_table"]["time_s"],
    }
    results["aims"] = {
        "equilibrium_at_most_0.5_ms": t_newton <= 0.5e-3,
        "at_least_300x_faster_than_lbfgs": t_lbfgs / t_newton >= 300,
        "friction_curve_at_most_3x_frictionless": results["ratios"]["friction_on_over_off"] <= 3,
        "certificate_at_most_20_percent_of_a_step": results["certificate"]["share_of_step"] <= 0.2,
    }
    return results


def print_table(results: dict) -> None:
    eq, lb, sn = results["equilibrium"], results["lbfgs"], results["scipy_sparse_newton"]
    ms = 1e3
    print(f"Static solver benchmark ({results['machine']}, Python {results['python']}, "
          f"numpy {results['numpy']}, scipy {results['scipy']}); warm, best of repeats\n")
    print(f"{'case':58s} {'time [ms]':>10s} {'iters':>7s} {'residual [N]':>13s}")
    rows = [
        ("one equilibrium, dynfab Newton (P = 0.3 N, N = 224)", eq["time_s"], eq["iterations"], eq["residual_N"]),
        ("  same, dynfab to L-BFGS-B's residual", lb["dynfab_time_to_same_residual_s"],
         lb["dynfab_iterations_to_same_residual"], lb["residual_N"]),
        ("  scipy L-BFGS-B (stalls)", lb["time_s"], lb["iterations"], lb["residual_N"]),
        ("  scipy.sparse Newton + spsolve, no line search", sn["time_s"], sn["iterations"], sn["residual_N"]),
    ]
    for name, data in results["traction_curve"].items():
        rows.append((f"traction curve, 40 steps, {name.replace('_', ' ')}", data["time_s"],
                     data["newton_iterations"], None))
    for name, t, it, res in rows:
        shown = "-" if res is None else f"{res:.2e}"  # a curve has one residual per step
        print(f"{name:58s} {t * ms:10.3f} {it:7d} {shown:>13s}")
    print(f"\nL-BFGS-B position error vs dynfab: {lb['max_position_error_m']:.2e} m; "
          f"sparse Newton vs dynfab: {sn['max_position_difference_m']:.2e} m")
    cert = results["certificate"]
    print(f"\ncertificate of the equilibrium (LDL^T inertia, Lanczos, Hager): "
          f"{cert['time_s'] * ms:.3f} ms = {100 * cert['share_of_step']:.1f} % of the step "
          f"({cert['step_time_without_s'] * ms:.3f} ms without it)")
    print("\nNewton iterations of the first friction step (runs/paper_fig5.toml), k_t x default:")
    for factor, iterations in results["first_friction_step_iterations"].items():
        print(f"  k_t x {factor:>5s}: {iterations}")
    print("\nratios (this run):")
    for name, value in results["ratios"].items():
        print(f"  {name:36s} {value:10.1f}")
    print("\naims:")
    for name, met in results["aims"].items():
        print(f"  {name:42s} {'met' if met else 'NOT met'}")


if __name__ == "__main__":
    results = main()
    print_table(results)
    OUTPUT.write_text(json.dumps(results, indent=2) + "\n")
    print(f"\nwrote {OUTPUT.relative_to(ROOT)}")
