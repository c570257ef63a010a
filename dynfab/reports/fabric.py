"""Fabric report (`dynfab fabric`): biaxial loads on the balanced periodic cell
(docs/model.md section 10).

`run_fabric(out_dir, quick=False)` solves the 2 x 2 periodic cell of the paper's yarns
(`dynfab.reports.fabric_data`) with the static Newton solver under force control along
four proportional paths, warp:weft = 2:1, 1:1, 1:2 and 1:0.05 (the weft held at a small
tension), the larger load rising to 1 N per yarn (160 N/m), and writes into `out_dir`:

* ``fabric_biaxial.png``: load per unit width [N/m] against strain [%] of both directions
  along every path (the presentation of Kawabata, Niwa and Kawai 1973), with a zoom on the
  crimp-interchange region;
* ``fabric_crimp.png``: the mean crimp of both families against the path's load (crimp
  interchange: the loaded family's crimp falls, the other's rises);
* ``fabric_cell.png``: side views of warp 1 and weft 1 at the last step of every path over
  the as-woven shapes, and top views of the cell with the crossings coloured by contact force;
* ``fabric.json``: every number the figures show (per path and step: loads per width,
  strains, crimps, contact forces, residuals, stability, and a bound on the positions'
  error from the residual), the checks below, the machine and the wall time;
* ``fabric.md``: a short summary.

The checks (`check_physics`): at equal loads warp and weft respond alike, and the 2:1 and
1:2 paths mirror each other (a balanced fabric, docs/model.md section 10), within the error bound;
along the near-uniaxial path the warp's crimp falls and the weft's rises; at the same warp load
the warp stretches more when the weft carries less (2:1 against 1:1).

The error bound of a step: a residual r (largest free force component) leaves the positions
within ||H^-1||_inf r of the exact solution (H the Hessian on the unknowns); we take
4 ||H^-1||_inf max(r, tolerance), as tests/test_fabric_periodic.py does, ||H^-1||_inf exact
(dense inverse: the cell has a few hundred unknowns).

``quick=True``: 8 segments per crossing and 8 load steps (seconds once numba is compiled).
"""

from __future__ import annotations

import time
from typing import Callable

import numpy as np

from dynfab.model.fabric.model import FabricModel
from dynfab.reports.common import machine, output_folder, write_json, write_text
from dynfab.reports.fabric_data import (eq4_against_beam, FULL, PATHS, QUICK, YARNS, Plan, cell_scene, crimp_percent,
                                        load_per_width, strain_percent, width_per_yarn,
                                        yarn_nodes)
from dynfab.reports.fabric_plots import draw_figures
from dynfab.solvers.static import StaticSolver


def run_fabric(out_dir, *, quick: bool = False,
               progress: Callable[[str], None] | None = None) -> dict:
    """Solve the paths, draw the figures, check the physics; return the summary.

    The summary (also written as ``fabric.json``) has "files" (every path written) and
    "wall_time_s". `progress` receives one line per path and one per check (None: silent).
    """
    started = time.perf_counter()
    out = output_folder(out_dir)
    plan = QUICK if quick else FULL
    data = solve_paths(plan, progress)
    figures = draw_figures(out, data)
    data["checks"] = check_physics(data)
    data["all_checks_hold"] = all(c["passed"] for c in data["checks"].values())
    if progress is not None:
        for name, check in data["checks"].items():
            progress(f"{name}: {'holds' if check['passed'] else 'FAILS'} ({check['what']})")
    data["machine"] = machine()
    data["files"] = [str(p) for p in figures] + [str(out / "fabric.json"), str(out / "fabric.md")]
    data["wall_time_s"] = time.perf_counter() - started
    write_json(out / "fabric.json", data)
    write_text(out / "fabric.md", summary_text(data))
    return data


# --------------------------------------------------------------------------
# Solves.


def solve_paths(plan: Plan, progress=None) -> dict:
    """Every path of PATHS on the cell of `plan`: the data dict the figures and JSON hold."""
    first = FabricModel.from_scene(cell_scene(plan, PATHS["1:1"]))
    rest = first.structure.rest_position
    data = {"report": "fabric", "plan": plan.name,
            "cell": {"warps": YARNS, "wefts": YARNS, "boundary": "periodic", "control": "force",
                     "length_m": first.warp.length, "segments": first.warp.segments,
                     "width_per_yarn_m": width_per_yarn(), "steps": plan.steps,
                     "largest_load_N": plan.largest_load_N, "yarn": _family_dict(first.warp),
                     "core_stiffness_N_per_m": float(first.structure.tie_contact_law[0, 0]),
                     "friction": None, "tolerance_N": first.scene.static.tolerance},
            "as_woven": {"warp": yarn_nodes(rest, first.structure.chain_start, 0).tolist(),
                         "weft": yarn_nodes(rest, first.structure.chain_start, YARNS).tolist()},
            "paths": {}}
    for name, ratio in PATHS.items():
        started = time.perf_counter()
        data["paths"][name] = solve_path(plan, ratio)
        if progress is not None:
            path = data["paths"][name]
            progress(f"path {name}: {plan.steps} steps in {time.perf_counter() - started:.2f} s, "
                     f"strain warp {path['warp_strain_percent'][-1]:.3f} %, "
                     f"weft {path['weft_strain_percent'][-1]:.3f} %")
    return data


def _family_dict(family) -> dict:
    return {"EA_N": family.EA, "EI_N_m2": family.EI, "amplitude_m": family.amplitude,
            "kawabata_C_m": family.kawabata_C, "kawabata_K_m_per_N": family.kawabata_K}


def solve_path(plan: Plan, ratio: tuple[float, float]) -> dict:
    """One proportional path: per step (as woven first) loads, strains, crimps, contact
    forces, residual, stability and the positions' error bound; the last shapes and plan."""
    solver = StaticSolver(FabricModel.from_scene(cell_scene(plan, ratio)))
    f, path = solver.model.structure, solver.model.load_values
    state = solver.initial_state()
    warp_loads, weft_loads = (np.concatenate([[0.0], v]) for v in path.T)
    strain, crimp = [np.zeros(2)], [solver.model.crimps(state.positions)]
    contact, residual, stable, bound = [np.zeros((YARNS, YARNS))], [0.0], [True], [0.0]
    for warp_value, weft_value in path:
        state, record = solver.step(state, (warp_value, weft_value))
        strain.append(record["strain"])
        crimp.append(record["crimp"])
        contact.append(record["contact_force"])
        residual.append(float(record["residual"]))
        stable.append(bool(record["stable"]))
        bound.append(position_bound(solver, state, record))
    strain, crimp = 100 * np.array(strain), 100 * np.array(crimp)
    weft0 = YARNS  # the first weft yarn follows the warps
    cell = (state.positions[f.load_node[0], 0], state.positions[f.load_node[weft0], 0])
    return _lists({"ratio": list(ratio),
            "warp_load_N_per_m": warp_loads / width_per_yarn(),
            "weft_load_N_per_m": weft_loads / width_per_yarn(),
            "warp_strain_percent": strain[:, 0], "weft_strain_percent": strain[:, 1],
            "warp_crimp_percent": crimp[:, 0], "weft_crimp_percent": crimp[:, 1],
            "contact_force_N": np.array(contact), "residual_N": residual, "stable": stable,
            "position_bound_m": bound,
            "last": {"warp": yarn_nodes(state.positions, f.chain_start, 0),
                     "weft": yarn_nodes(state.positions, f.chain_start, weft0),
                     "cell_m": [float(c) for c in cell],
                     "warp_above": (f.tie_side.reshape(YARNS, YARNS) > 0)}})


def _lists(value):
    """numpy arrays to nested lists, through dicts (the JSON and the drawings read lists)."""
    if isinstance(value, dict):
        return {k: _lists(v) for k, v in value.items()}
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, tuple):
        return [_lists(v) for v in value]
    return value


def position_bound(solver: StaticSolver, state, record) -> float:
    """4 ||H^-1||_inf max(r, tolerance) [m]: how far the step's positions may lie from the
    exact solution (module docstring)."""
    H = solver.backend.hessian(state.positions, state.anchors, record["friction_limit"].ravel())
    inverse_norm = np.abs(np.linalg.inv(H.toarray())).sum(axis=1).max()
    return float(4 * inverse_norm * max(record["residual"], solver.tolerance))


# --------------------------------------------------------------------------
# Checks of what the figures show.


def strain_bound_percent(data: dict, name: str) -> np.ndarray:
    """(steps + 1,) bound on a strain's error [%]: an end position within the step's
    position bound, over the cell length."""
    return 100 * np.asarray(data["paths"][name]["position_bound_m"]) / data["cell"]["length_m"]


def check_physics(data: dict) -> dict:
    """The checks of the module docstring, each {"passed", "what", and its numbers}."""
    paths = data["paths"]
    equal = paths["1:1"]
    bound = strain_bound_percent(data, "1:1")
    gap = np.abs(strain_percent(equal, "warp") - strain_percent(equal, "weft"))
    mirror_bound = strain_bound_percent(data, "2:1") + strain_bound_percent(data, "1:2")
    mirror = np.abs(strain_percent(paths["2:1"], "warp") - strain_percent(paths["1:2"], "weft"))
    uniaxial = paths["1:0.05"]
    warp_crimp, weft_crimp = crimp_percent(uniaxial, "warp"), crimp_percent(uniaxial, "weft")
    assert np.allclose(load_per_width(paths["2:1"], "warp"), load_per_width(equal, "warp"))
    softer = strain_percent(paths["2:1"], "warp")[1:] - strain_percent(equal, "warp")[1:]
    return {
        "equal_loads_alike": {
            "what": "1:1: warp and weft strains equal within the error bound",
            "passed": bool(np.all(gap <= 2 * bound)), "largest_gap_percent": gap.max(),
            "bound_percent": (2 * bound).max()},
        "mirror_paths": {
            "what": "2:1 warp strain = 1:2 weft strain within the error bound",
            "passed": bool(np.all(mirror <= mirror_bound)), "largest_gap_percent": mirror.max(),
            "bound_percent": mirror_bound.max()},
        "crimp_interchange": {
            "what": "1:0.05: warp crimp falls at every step, weft crimp above its as-woven value",
            "passed": bool(np.all(np.diff(warp_crimp) < 0)
                           and np.all(weft_crimp[1:] > weft_crimp[0])),
            "warp_crimp_percent": [warp_crimp[0], warp_crimp[-1]],
            "weft_crimp_percent": [weft_crimp[0], weft_crimp[-1]]},
        "lateral_tension_stiffens": {
            "what": "at the same warp load, warp strain at 2:1 above that at 1:1",
            "passed": bool(np.all(softer > 0)), "smallest_difference_percent": softer.min()},
    }


def summary_text(data: dict) -> str:
    """``fabric.md``: the cell, a table of the last step of every path, the checks."""
    cell = data["cell"]
    lines = [
        "# Fabric report: biaxial loads on the periodic cell",
        "",
        f"Plan {data['plan']}: the {cell['warps']} x {cell['wefts']} periodic cell "
        f"(docs/model.md section 10) of the paper's yarns, cell length {1e3 * cell['length_m']:g} mm, "
        f"{cell['segments']} segments per yarn, force control, {cell['steps']} load steps per "
        f"path, no friction. Wall time {data['wall_time_s']:.1f} s.",
        "",
        "| path warp:weft | warp load [N/m] | weft load [N/m] | warp strain [%] | "
        "weft strain [%] | warp crimp [%] | weft crimp [%] | contact force [N] |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for name, path in data["paths"].items():
        lines.append(
            f"| {name} | {load_per_width(path, 'warp')[-1]:.1f} | "
            f"{load_per_width(path, 'weft')[-1]:.1f} | {strain_percent(path, 'warp')[-1]:.3f} | "
            f"{strain_percent(path, 'weft')[-1]:.3f} | {crimp_percent(path, 'warp')[-1]:.3f} | "
            f"{crimp_percent(path, 'weft')[-1]:.3f} | "
            f"{np.max(path['contact_force_N'][-1]):.4f} |")
    lines += ["", "Paper eq. 4 against the tensioned beam (docs/model.md section 10), the paper's "
              "weft, both at the stretched length:", "",
              "| weft tension [N] | eq. 4 [N/m] | tensioned beam [N/m] | eq. 4 exceeds it by [%] |",
              "|---|---|---|---|"]
    for row in eq4_against_beam():
        lines.append(f"| {row['tension_N']:g} | {row['eq4_N_per_m']:.4g} | "
                     f"{row['beam_N_per_m']:.4g} | {row['excess_percent']:.2f} |")
    lines += ["", f"As woven, each family's crimp is "
                  f"{crimp_percent(data['paths']['1:1'], 'warp')[0]:.3f} %.", "", "Checks:", ""]
    for name, check in data["checks"].items():
        lines.append(f"- {name}: {'holds' if check['passed'] else 'FAILS'} ({check['what']})")
    return "\n".join(lines) + "\n"
