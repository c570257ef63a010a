"""Benchmark of the dynamic solver (MODEL.md 5): one load step of the paper yarn, per method.

The paper yarn (runs/paper_fig3.toml at K = 0.2 m/N, prestressed) under force
control is relaxed by the static solver at P = 0.2 N; each dynamic method then
relaxes it to P = 0.3 N at the 1e-8 N tolerance. Reported per method: time
steps, force evaluations and the warm wall time (the second of two runs, so no
compilation). Then the cost of one explicit time step per node [ns], Warp's
kernel beside a plain numba loop doing the same step (the `dynfab.assembly`
forces, the residual and the kinetic-damping update) in the same process.

Run: python benchmarks/dynamic.py   (prints a table, writes benchmarks/dynamic.json)
"""

import json
import platform
import time
from dataclasses import replace
from pathlib import Path

import numba
import numpy as np
import warp as wp

from dynfab import assembly
from dynfab.dynamic import DynamicSolver
from dynfab.kernels import explicit, settings as settings_module
from dynfab.model import build_model, initial_state
from dynfab.scene import Dynamic, load_scene, with_key
from dynfab.static import StaticSolver

HERE = Path(__file__).resolve().parent
METHODS = {
    "explicit, kinetic damping": Dynamic(damping="kinetic"),
    "explicit, viscous (adaptive c)": Dynamic(damping="viscous"),
    "explicit, FIRE 2.0": Dynamic(damping="fire"),
    "semi_implicit": Dynamic(method="semi_implicit"),
}
STEPS_TIMED = 20_000
"""Time steps of the per-step cost measurement."""
REPEATS = 5
"""Timed repetitions of each per-step measurement; the fastest is kept (the least disturbed
by other processes on the machine)."""


def paper_yarn():
    """The model of one paper yarn (K = 0.2 m/N, prestressed) under force control."""
    scene = replace(load_scene(HERE.parent / "runs" / "paper_fig3.toml"), sweep=())
    scene = with_key(with_key(scene, "load.control", "force"), "load.values", [0.2, 0.3])
    return build_model(scene)


def time_methods(model, start):
    """Per method: time steps, force evaluations, warm wall time [s] of the step to 0.3 N."""
    rows = {}
    for name, options in METHODS.items():
        solver = DynamicSolver(model, options)
        solver.step(start, 0.3)
        began = time.perf_counter()
        _, record = solver.step(start, 0.3)
        rows[name] = {"time_steps": int(record["time_steps"][0]),
                      "force_evaluations": int(record["force_evaluations"][0]),
                      "wall_time_s": time.perf_counter() - began,
                      "residual_N": float(record["residual"][0])}
    return rows


def warp_step_cost(model, start) -> float:
    """ns per node per explicit kinetic-damping time step of the Warp kernel (one launch of
    STEPS_TIMED steps from the load step's start), fastest of REPEATS."""
    solver = DynamicSolver(model, Dynamic(damping="kinetic"))
    kernel = explicit.relaxation_kernel(solver.configuration)
    settings = settings_module.fill(solver.scalar, end_load=0.3, tolerance=0.0, safety=0.9,
                                    fixed_dt=0.0, fictitious=1, damping_coefficient=-1.0,
                                    max_steps=STEPS_TIMED, chunk=STEPS_TIMED)
    costs = []
    for _ in range(1 + REPEATS):  # the first launch loads the kernel
        solver.predicted_stable_dt(start, 0.3)  # the state, forces, masses and dt
        began = time.perf_counter()
        wp.launch(kernel, dim=1, inputs=[solver.yarn, solver.motion, settings])
        wp.synchronize()
        elapsed = time.perf_counter() - began
        steps = int(solver.motion.steps.numpy()[0])  # fewer if it stalled at the rounding floor
        costs.append(elapsed / (steps * (model.segments + 1)) * 1e9)
    return min(costs[1:])


@numba.njit(cache=True)
def numba_kinetic_steps(pos, vel, mass, yarn, P, anchors, fixed, steps):
    """`steps` explicit kinetic-damping steps (dt = 1 s, fictitious masses) in plain numba:
    the same work per step as the Warp kernel without friction. Returns the last residual."""
    grad = np.zeros_like(pos)
    no_limit = np.zeros(anchors.size)
    flat_fixed = fixed.reshape(pos.shape)
    kinetic, residual = 0.0, 0.0
    for _ in range(steps):
        assembly.gradient(pos, yarn, P, anchors, no_limit, grad)
        residual = 0.0
        trial = 0.0
        for i in range(pos.shape[0]):
            for c in range(2):
                if flat_fixed[i, c]:
                    grad[i, c] = 0.0
                residual = max(residual, abs(grad[i, c]))
                v = vel[i, c] - grad[i, c] / mass[i]
                trial += 0.5 * mass[i] * v * v
        if trial < kinetic:
            for i in range(pos.shape[0]):
                for c in range(2):
                    pos[i, c] -= 0.5 * vel[i, c]
                    vel[i, c] = 0.0
            kinetic = 0.0
        else:
            for i in range(pos.shape[0]):
                for c in range(2):
                    vel[i, c] -= grad[i, c] / mass[i]
                    pos[i, c] += vel[i, c]
            kinetic = trial
    return residual


def numba_step_cost(model, start, masses) -> float:
    """ns per node per time step of `numba_kinetic_steps`, fastest of REPEATS (warm: compiled
    by a first call)."""
    yarn, fixed = model.yarns[0], model.fixed_dofs()
    arguments = (yarn, 0.3, start.anchors[0], fixed)
    numba_kinetic_steps(start.positions[0].copy(), np.zeros_like(start.positions[0]), masses,
                        *arguments, 10)
    costs = []
    for _ in range(REPEATS):
        pos, vel = start.positions[0].copy(), np.zeros_like(start.positions[0])
        began = time.perf_counter()
        numba_kinetic_steps(pos, vel, masses, *arguments, STEPS_TIMED)
        elapsed = time.perf_counter() - began
        costs.append(elapsed / (STEPS_TIMED * (model.segments + 1)) * 1e9)
    return min(costs)


def main() -> None:
    wp.init()
    model = paper_yarn()
    start, _ = StaticSolver(model).step(initial_state(model), 0.2)
    rows = time_methods(model, start)
    probe = DynamicSolver(model, Dynamic(damping="kinetic"))
    probe.predicted_stable_dt(start, 0.3)
    masses = probe.motion.mass.numpy()[0].astype(float)
    warp_ns, numba_ns = warp_step_cost(model, start), numba_step_cost(model, start, masses)
    print(f"paper yarn (N = {model.segments}, K = 0.2 m/N, prestressed), force control, "
          "P = 0.2 -> 0.3 N, tolerance 1e-8 N")
    print(f"{'method':34s} {'time steps':>10s} {'force evals':>11s} {'wall [ms]':>10s}")
    for name, row in rows.items():
        print(f"{name:34s} {row['time_steps']:10d} {row['force_evaluations']:11d} "
              f"{1e3 * row['wall_time_s']:10.2f}")
    print(f"explicit time step per node: Warp {warp_ns:.1f} ns, numba {numba_ns:.1f} ns "
          f"(ratio {warp_ns / numba_ns:.2f})")
    report = {"scene": "runs/paper_fig3.toml, K = 0.2 m/N, force control 0.2 -> 0.3 N",
              "tolerance_N": 1e-8, "methods": rows,
              "step_cost_ns_per_node": {"warp": warp_ns, "numba": numba_ns,
                                        "ratio": warp_ns / numba_ns},
              "machine": {"processor": platform.processor() or platform.machine(),
                          "python": platform.python_version(), "warp": wp.__version__,
                          "numba": numba.__version__}}
    (HERE / "dynamic.json").write_text(json.dumps(report, indent=2) + "\n")


if __name__ == "__main__":
    main()
