"""Benchmark of the fabric's explicit time step in Warp (docs/model.md sections 5, 10): cost per
node and step.

The case: clamped balanced patches of the paper's yarn, n x n yarns for n = 4 to 64,
8 segments per half-wave (N = M = 8 n, 2 n (8 n + 1) nodes), every yarn loaded with
0.3 N along itself, viscous damping c dt = 0.05, a fixed number of time steps from the
as-woven state (tolerance 0: every step is taken), chosen so one run does about
STEP_WORK node-steps. Three implementations of the same step, warm (a first untimed run
compiles), fastest of REPEATS runs:

1. Warp, layout "persistent" (the CPU default): one launch, one thread looping over
   steps and nodes (`dynfab.kernels.fabric_explicit`), each term evaluated once and
   scattered to its nodes.
2. The same persistent loop in the gather order (a per-crossing pass, then every node
   gathering its forces: the per-step layout's arithmetic, done by one thread).
3. Warp, layout "per_step" (the GPU layout) run on the CPU: two launches per step
   (a thread per crossing, then a thread per node) of the same gather work as 2, so
   their difference per step is the cost of the two launches (and the buffer swap).
4. A plain numba loop of the same forces: contact per crossing, stretch per segment and
   bending per inner node scattered into the force array, then the same update.

Reported: ns per node and step of each, the per-step launch cost (3 - 2), the ratio
persistent / numba (aim: at most 1.5x), the exponent of a least-squares fit of
log(time per step) against log(nodes) for the persistent layout (aim: at most 1.1), and
the largest position difference between Warp and numba after the same steps (the same
arithmetic up to the order of the sums).

Run: python benchmarks/fabric_dynamic.py   (prints the table, writes benchmarks/fabric_dynamic.json)
"""

import json
import math
import os
import platform
import time
from pathlib import Path

import numba
import numpy as np
import warp as wp

from dynfab.kernels import fabric_arrays, fabric_explicit

HERE = Path(__file__).resolve().parent
SIZES = (4, 8, 16, 32, 64)
"""n of the n x n patches."""
SEGMENTS_PER_HALF_WAVE = 8
LOAD = 0.3
"""End load of every yarn [N]."""
DAMPING = 0.05
"""Viscous c [1/s] at dt = 1 s (fictitious masses)."""
STEP_WORK = 2e7
"""Node-steps of one timed run (about 1 s at 50 ns per node and step)."""
PER_STEP_WORK = 4e6
"""Node-steps of one timed run of the per-step layout (slower on small patches)."""
REPEATS = 3
AIMS = {"persistent_over_numba": 1.5, "exponent_per_step_vs_nodes": 1.1}
"""The limit of each aim (at most)."""


@numba.njit(cache=True)
def numba_contact(g, law):
    """R(g) [N] of R/k_c + sum_m C_m (1 - exp(-a_m R)) = g, Newton from the lower bound."""
    if g <= 0.0:
        return 0.0
    R = max(0.0, law[0] * (g - law[1] - law[3]))
    for _ in range(64):
        decay_wa, decay_we = math.exp(-law[2] * R), math.exp(-law[4] * R)
        value = R / law[0] + law[1] * (1.0 - decay_wa) + law[3] * (1.0 - decay_we)
        tangent = 1.0 / (1.0 / law[0] + law[1] * law[2] * decay_wa + law[3] * law[4] * decay_we)
        step = (g - value) * tangent
        if not step > 4e-16 * R:
            break
        R += step
    return R


@numba.njit(cache=True)
def numba_forces(pos, nxt, rest_length, stretch, bend, rest_angle, free, cw, cwe, side, offset,
                 law, external, force):
    """force = -dV/dr on the free dofs, scattered term by term (docs/model.md sections 2, 10)."""
    n = pos.shape[0]
    force[:, :] = external
    for i in range(n):
        j = nxt[i]
        if j < 0:
            continue
        ex, ez = pos[j, 0] - pos[i, 0], pos[j, 1] - pos[i, 1]
        length = math.sqrt(ex * ex + ez * ez)
        t = stretch[i] * (length - rest_length[i]) / length
        force[i, 0] += t * ex
        force[i, 1] += t * ez
        force[j, 0] -= t * ex
        force[j, 1] -= t * ez
        k = nxt[j]
        if k < 0 or bend[j] == 0.0:
            continue
        bx, bz = pos[k, 0] - pos[j, 0], pos[k, 1] - pos[j, 1]
        moment = bend[j] * (math.atan2(ex * bz - ez * bx, ex * bx + ez * bz) - rest_angle[j])
        a2, b2 = ex * ex + ez * ez, bx * bx + bz * bz
        gax, gaz = moment * ez / a2, -moment * ex / a2
        gbx, gbz = -moment * bz / b2, moment * bx / b2
        force[i, 0] += gax
        force[i, 1] += gaz
        force[j, 0] += gbx - gax
        force[j, 1] += gbz - gaz
        force[k, 0] -= gbx
        force[k, 1] -= gbz
    for c in range(cw.shape[0]):
        g = offset[c] - side[c] * (pos[cw[c], 1] - pos[cwe[c], 1])
        R = numba_contact(g, law)
        force[cw[c], 1] += side[c] * R
        force[cwe[c], 1] -= side[c] * R
    for i in range(n):
        force[i, 0] *= free[i, 0]
        force[i, 1] *= free[i, 1]


@numba.njit(cache=True)
def numba_steps(pos, vel, mass, nxt, rest_length, stretch, bend, rest_angle, free, cw, cwe, side,
                offset, law, external, dt, coefficient, steps):
    """`steps` centred viscous symplectic Euler steps; the residual at the last positions."""
    force = np.zeros_like(pos)
    half = 0.5 * coefficient * dt
    residual = 0.0
    for step in range(steps + 1):
        numba_forces(pos, nxt, rest_length, stretch, bend, rest_angle, free, cw, cwe, side, offset,
                     law, external, force)
        residual = np.abs(force).max()
        if step == steps:
            break
        for i in range(pos.shape[0]):
            for c in range(2):
                v = ((1.0 - half) * vel[i, c] + (dt / mass[i]) * force[i, c]) / (1.0 + half)
                vel[i, c] = v
                pos[i, c] += dt * v
    return residual


def best_time(function):
    """(fastest wall time [s], last result) of REPEATS warm calls after one untimed call."""
    result = function()
    times = []
    for _ in range(REPEATS):
        began = time.perf_counter()
        result = function()
        times.append(time.perf_counter() - began)
    return min(times), result


def warp_run(arrays, layout, steps, order="scatter"):
    """Positions after `steps` steps of one layout, as a callable for best_time."""
    solver = fabric_explicit.FabricExplicit(arrays, layout=layout, damping="viscous",
                                            coefficient=DAMPING, check_interval=1 << 30,
                                            order=order)
    external = LOAD * (arrays.load_direction + arrays.weft_load_direction)
    return lambda: solver.relax(arrays.rest_position, external, 0.0, steps)[0]


def numba_run(arrays, steps):
    """Positions after `steps` steps of the numba loop, as a callable for best_time."""
    mass = fabric_arrays.gershgorin_masses(arrays, 1.0)
    external = LOAD * (arrays.load_direction + arrays.weft_load_direction)

    def run():
        pos, vel = arrays.rest_position.copy(), np.zeros_like(arrays.rest_position)
        numba_steps(pos, vel, mass, arrays.next, arrays.rest_length, arrays.stretch_stiffness,
                    arrays.bend_stiffness, arrays.rest_angle, arrays.free, arrays.crossing_warp,
                    arrays.crossing_weft, arrays.crossing_side, arrays.crossing_offset,
                    arrays.contact_law, external, 1.0, DAMPING, steps)
        return pos
    return run


def measure(n):
    """Every implementation on the n x n patch."""
    arrays = fabric_arrays.build(fabric_arrays.paper_patch(n, n, SEGMENTS_PER_HALF_WAVE))
    nodes = arrays.nodes
    steps = max(20, int(STEP_WORK / nodes))
    per_step_steps = max(10, int(PER_STEP_WORK / nodes))
    row = {"n": n, "nodes": nodes, "crossings": arrays.crossings, "steps": steps,
           "per_step_steps": per_step_steps}
    time_persistent, warp_positions = best_time(warp_run(arrays, "persistent", steps))
    time_numba, numba_positions = best_time(numba_run(arrays, steps))
    time_gather, _ = best_time(warp_run(arrays, "persistent", per_step_steps, "gather"))
    time_per_step, _ = best_time(warp_run(arrays, "per_step", per_step_steps, "gather"))
    row["persistent_ns_per_node_step"] = 1e9 * time_persistent / (nodes * steps)
    row["numba_ns_per_node_step"] = 1e9 * time_numba / (nodes * steps)
    row["gather_ns_per_node_step"] = 1e9 * time_gather / (nodes * per_step_steps)
    row["per_step_ns_per_node_step"] = 1e9 * time_per_step / (nodes * per_step_steps)
    row["launch_cost_us_per_step"] = 1e6 * (time_per_step - time_gather) / per_step_steps
    row["persistent_s_per_step"] = time_persistent / steps
    row["persistent_over_numba"] = time_persistent / time_numba
    row["warp_minus_numba_positions_m"] = float(np.abs(warp_positions - numba_positions).max())
    row["displacement_m"] = float(np.abs(warp_positions - arrays.rest_position).max())
    return row


def main():
    wp.config.quiet = True
    wp.init()
    rows = []
    print(f"{'n x n':>7} {'nodes':>7} {'steps':>7} {'persistent':>11} {'numba':>8} {'ratio':>6} "
          f"{'gather':>7} {'per_step':>9} {'extra':>9} {'|warp-numba|':>13} {'moved':>9}"
          "   [ns per node and step; extra: per_step - gather, us per step; m]")
    for n in SIZES:
        row = measure(n)
        rows.append(row)
        print(f"{n:>3} x{n:<3} {row['nodes']:>7} {row['steps']:>7} "
              f"{row['persistent_ns_per_node_step']:>11.1f} {row['numba_ns_per_node_step']:>8.1f} "
              f"{row['persistent_over_numba']:>6.2f} {row['gather_ns_per_node_step']:>7.1f} "
              f"{row['per_step_ns_per_node_step']:>9.1f} {row['launch_cost_us_per_step']:>9.1f} "
              f"{row['warp_minus_numba_positions_m']:>13.2e} {row['displacement_m']:>9.2e}", flush=True)
    nodes = np.array([r["nodes"] for r in rows], float)
    exponent = float(np.polyfit(np.log(nodes), np.log([r["persistent_s_per_step"] for r in rows]), 1)[0])
    numba_exponent = float(np.polyfit(np.log(nodes), np.log([r["numba_ns_per_node_step"] * r["nodes"]
                                                               for r in rows]), 1)[0])
    worst_ratio = max(r["persistent_over_numba"] for r in rows)
    summary = {"exponent_per_step_vs_nodes": exponent, "numba_exponent": numba_exponent,
               "launch_cost_us_per_step_smallest": rows[0]["launch_cost_us_per_step"],
               "persistent_over_numba_worst": worst_ratio}
    print(f"fitted exponent of the time per step against the nodes (persistent): {exponent:.3f}"
          f" (numba: {numba_exponent:.3f})")
    first = rows[0]
    print(f"two launches per step (per_step layout on the CPU) cost "
          f"{first['launch_cost_us_per_step']:.1f} us per step on the smallest patch, "
          f"{first['persistent_s_per_step'] * 1e6:.1f} us the whole step of the persistent layout there")
    aims = {"persistent_over_numba": worst_ratio, "exponent_per_step_vs_nodes": exponent}
    for name, value in aims.items():
        verdict = "met" if value <= AIMS[name] else "NOT met"
        print(f"aim {name} <= {AIMS[name]}: {value:.3f} {verdict}")
    result = {"machine": {"platform": platform.platform(), "cpus": os.cpu_count(),
                          "warp": wp.config.version, "numba": numba.__version__},
              "case": {"sizes": SIZES, "segments_per_half_wave": SEGMENTS_PER_HALF_WAVE,
                       "load_N": LOAD, "damping_c_dt": DAMPING, "repeats": REPEATS},
              "rows": rows, "summary": summary, "aims": AIMS,
              "aims_met": {name: aims[name] <= AIMS[name] for name in AIMS}}
    (HERE / "fabric_dynamic.json").write_text(json.dumps(result, indent=2) + "\n")


if __name__ == "__main__":
    main()
