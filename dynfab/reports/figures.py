"""Figures report (`dynfab figures`): the paper's Fig. 3a, 3b and 5, static and dynamic.

`run_figures(out_dir, quick=False)` solves the paper scenes ``runs/paper_fig3.toml`` (Kawabata
K = 0.02, 0.2, 1.0 m/N on both yarns, frictionless) and ``runs/paper_fig5.toml`` (Gralen
friction on and off, K = 0.2 m/N), both prestressed, end displacement to 10 mm in 40 steps,
with the static Newton reference and with the dynamic solver at its default quasi-static
settings (`run(scene, solver="dynamic")`: explicit, kinetic damping, fictitious masses,
residual 1e-8 N). Into `out_dir` it writes:

* the four standard dynfab result files ``fig3_static.h5``, ``fig3_dynamic.h5``,
  ``fig5_static.h5``, ``fig5_dynamic.h5`` (`dynfab.results.file` layout, so ``dynfab plot``
  draws its standard figures from each; a run writes its ParaView view ``.xdmf`` beside
  it, `dynfab.results.xdmf`). A file is solved again only when it is missing
  or stale (unreadable, written from another scene, by another solver or dynfab
  version, or with fewer load steps than the scene has);
* the report's figures, drawn by `draw_figures` from those four files alone:
  ``fig3a_traction.png``, ``fig3b_contact_force.png``, ``fig5_friction.png``,
  ``shapes.png`` and ``friction_states.png``, static solutions as lines and dynamic
  ones as markers;
* ``trends.json``: the machine, the solve times, the paper's trends (docs/model.md section 8)
  checked on the data of each solver (`check_trends`), and the static-vs-dynamic differences
  against their bound (`compare_solvers`); both read only the files too.

The static-vs-dynamic bound. Each solver stops at a residual r (largest free force
component). Linearising the step's residual map g at the static solution,
x_dyn - x_static = J^-1 (g(x_dyn) - g(x_static)), with J the Jacobian of the step's problem
on the free dofs (the Hessian; with friction the coupled friction Jacobian, at the anchors
the step started from, i.e. the previous step's). With friction the two solvers also start
a step from slightly different anchors xi: a sticking crossing's force -k_t (x - xi) then
differs by k_t |delta xi| (a sliding one carries F_T whatever its anchor). So

    |x_dyn - x_static|_inf <= ||J^-1||_inf (r_dyn + r_static + k_t max_sticking |delta xi|),
    |P_dyn - P_static|     <= ||J_e J^-1||_1 (the same bracket),

J_e the row of the end node's x (the reaction P = dV/dx_N). ||J^-1||_inf is computed
exactly (numpy, dense inverse) at every load step and yarn.

``quick=True`` cuts both yarns to 4 crossings at the same spacing (L = 25 mm, N = 56, the
same weft), end displacement to 2.5 mm (the same 10 % strain) in 20 steps: the same Warp
kernel variants as the paper scenes (kinetic damping, displacement control, with and
without friction), and a few seconds. Errors for user mistakes are `UserError`s.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import numba
import numpy as np

from dynfab.model import assembly
from dynfab.linalg.banded import BANDWIDTH, constrain, lu_factor, lu_solve, to_dense
from dynfab.errors import UserError
from dynfab.model.builders import build_model
from dynfab.reports.common import (cut_yarn, output_folder, paper_scene_file, report_header,
                                   with_path, write_json)
from dynfab.reports.figures_data import (FIGURES, SOLVERS, STRAIN_STAGE, at_strain,
                                         force_per_width, friction_gap, friction_split,
                                         k_order, kawabata_K, mean_contact_force,
                                         read_figure_data, result_name, scene_of, solver_pair,
                                         state_codes, strain_percent, width)
from dynfab.reports.figures_plots import draw_figures
from dynfab.results.file import Results, dynfab_version, read_results
from dynfab.run import run
from dynfab.scene import Scene, parse_scene_text, scene_to_toml
from dynfab.model.terms.friction import INDEX as FRICTION
from dynfab.results.xdmf import xdmf_path


# Thresholds of the trend checks (see `check_trends` for the reasons).
SATURATION_SHARE = 0.10
"""Largest share of the contact force's growth allowed in the last quarter of the path."""
SHRINK_SHARE = 0.25
"""Largest K spread at the end of the path, as a share of its largest value along it."""
GAP_GROWTH = 1.10
"""Smallest ratio gap(5 % strain) / gap(first step) for 'the gap grows'."""
GAP_FLAT = 0.10
"""Largest relative change of the gap between 5 % strain and the end: 'nearly constant'."""
GAP_HALF_SUM = 0.05
"""Largest relative deviation of the end gap from half the summed friction limits."""


@dataclass(frozen=True)
class Plan:
    """The size of the scenes the report solves."""

    name: str
    crossings: int
    segments: int
    max_displacement: float
    """Final end displacement [m]."""
    steps: int
    """Load steps to `max_displacement`."""


FULL = Plan("full", crossings=16, segments=224, max_displacement=10e-3, steps=40)
QUICK = Plan("quick", crossings=4, segments=56, max_displacement=2.5e-3, steps=20)


def run_figures(out_dir, *, quick: bool = False,
                progress: Callable[[str], None] | None = None) -> dict:
    """Solve what is missing or stale, draw the figures and check the trends; return the summary.

    The summary (also written as ``trends.json``) has "files" (every path written) and
    "wall_time_s". `progress` receives one line per solve and one per trend (None: silent).
    """
    started = time.perf_counter()
    out = output_folder(out_dir)
    plan = QUICK if quick else FULL
    solves = [ensure_result(scene, solver, out / result_name(name, solver), progress)
              for name, scene in paper_scenes(plan).items() for solver in SOLVERS]
    data = read_figure_data(out)
    figures = draw_figures(out, data)
    comparison = compare_solvers(data)
    trends = check_trends(data, comparison)
    summary = {
        **report_header("figures", plan.name, quick),
        "reference_state": sorted({str(r.attrs.get("reference_state")) for r in data.values()}),
        "solves": solves,
        "trends": trends,
        "static_vs_dynamic": comparison,
    }
    if progress is not None:
        for line in trend_lines(summary):
            progress(line)
    summary["all_trends_hold"] = all(t["passed"] for t in trends.values())
    summary["files"] = [str(out / result_name(n, s)) for n in FIGURES for s in SOLVERS]
    summary["files"] += [str(xdmf_path(f)) for f in summary["files"] if xdmf_path(f).exists()]
    summary["files"] += [str(p) for p in figures] + [str(out / "trends.json")]
    summary["wall_time_s"] = time.perf_counter() - started
    write_json(out / "trends.json", summary)
    return summary


# --------------------------------------------------------------------------
# Scenes and solves.


def paper_scenes(plan: Plan) -> dict[str, Scene]:
    """The report's scenes: the paper files as they are (FULL) or cut to `plan` (QUICK).

    A cut scene is written as TOML text and parsed, so the ``scene`` attribute of its
    result file describes exactly what was solved.
    """
    scenes = {}
    for name, file in FIGURES.items():
        scene = paper_scene_file(file, "the figures report")
        if plan is not FULL:
            scene = parse_scene_text(cut_scene_text(scene, plan), source=f"{file} ({plan.name})")
        scenes[name] = scene
    return scenes


def cut_scene_text(scene: Scene, plan: Plan) -> str:
    """TOML of `scene` with `plan.crossings` crossings at the same spacing and mesh density
    (`common.cut_yarn`: L and N scaled, the same weft, whose length and count
    `scene_to_toml` writes out), and the end displacement to `plan.max_displacement` in
    `plan.steps` (values = max k / steps, as the scene file's max and steps)."""
    title = (f"{scene.title} [{plan.name}: {plan.crossings} crossings, N = {plan.segments}, "
             f"{1e3 * plan.max_displacement:g} mm in {plan.steps} steps]")
    cut = with_path(cut_yarn(scene, plan.crossings, plan.segments), plan.max_displacement,
                    plan.steps, title=title)
    header = (f"# {plan.name} cut of the paper scene: {plan.crossings} of its "
              f"{scene.geometry.crossings} crossings at the same spacing, the same weft.\n")
    return header + scene_to_toml(cut)


def stale_reason(path: Path, scene: Scene, solver: str) -> str | None:
    """Why the result file at `path` cannot be reused for (scene, solver); None if it can."""
    if not path.exists():
        return "missing"
    try:
        results = read_results(path)
    except UserError as error:
        return f"unreadable ({error})"
    if results.attrs.get("scene") != scene_to_toml(scene):
        return "written from another scene"
    if results.attrs.get("solver") != solver:
        return f"written by the {results.attrs.get('solver')!r} solver"
    if results.attrs.get("dynfab_version") != dynfab_version():
        return f"written by dynfab {results.attrs.get('dynfab_version')}"
    if results.step_count != len(scene.load.values):
        return f"{results.step_count} of {len(scene.load.values)} load steps"
    return None


def ensure_result(scene: Scene, solver: str, path: Path,
                  progress: Callable[[str], None] | None = None) -> dict:
    """Solve (scene, solver) into `path` unless a current result is there; the solve's log."""
    reason = stale_reason(path, scene, solver)
    elapsed = None
    if reason is not None:
        started = time.perf_counter()
        run(scene, solver=solver, out=path, overwrite=True)
        elapsed = time.perf_counter() - started
    steps = read_results(path).steps
    entry = {"file": path.name, "solver": solver, "solved": reason is not None,
             "reason": reason or "current", "solve_wall_time_s": elapsed,
             "recorded_step_time_s": float(steps["wall_time"].sum()),
             "load_steps": int(steps["load"].shape[0]),
             "yarns": int(steps["load"].shape[1]),
             "max_residual_N": float(steps["residual"].max())}
    if "time_steps" in steps:
        entry["time_steps"] = int(steps["time_steps"].sum(axis=0).max())
    else:
        entry["newton_iterations"] = int(steps["iterations"].sum())
    if progress is not None:
        what = (f"solved in {elapsed:.2f} s ({reason})" if elapsed is not None
                else "current, reused")
        progress(f"{path.name}: {entry['load_steps']} load steps x {entry['yarns']} yarns, "
                 f"residual <= {entry['max_residual_N']:.1e} N, {what}")
    return entry


# --------------------------------------------------------------------------
# Static against dynamic.


def jacobian_norms(yarn, positions, anchors, fixed) -> tuple[float, float]:
    """(||J^-1||_inf [m/N], ||J_e J^-1||_1 [-]) of one yarn: J the Hessian on the free dofs
    (with friction the coupled friction Jacobian) at `positions` with the step's `anchors`,
    J_e the row of the end node's x dof (the end reaction's sensitivity) on the free dofs.

    Exact: J^-1 column by column from the banded LU (O(n^2) per yarn); a dense numpy
    inverse where the LU meets a pivot that is not positive."""
    band = assembly.tangent(positions, yarn, anchors, bool(yarn.active[FRICTION]))
    n = band.shape[0]
    end = n - 2  # x of the end node
    end_row = np.zeros(n)
    for j in range(max(0, end - BANDWIDTH), n):
        end_row[j] = band[end, j - end + BANDWIDTH]
    end_row[fixed] = 0.0
    factors = band.copy()
    constrain(factors, np.zeros(n), fixed)
    if lu_factor(factors) < 0:
        return _inverse_norms(factors, fixed, end_row)
    free = ~fixed
    inverse = np.linalg.inv(to_dense(band)[np.ix_(free, free)])
    return float(np.abs(inverse).sum(axis=1).max()), float(np.abs(end_row[free] @ inverse).sum())


@numba.njit(cache=True)
def _inverse_norms(factors, fixed, end_row):
    """Max free row sum of |J^-1| and sum_j |end_row . J^-1 e_j| over free columns j, from
    the LU factors of J with the fixed dofs constrained to the identity."""
    n = factors.shape[0]
    rows = np.zeros(n)
    force = 0.0
    column = np.zeros(n)
    for j in range(n):
        if fixed[j]:
            continue
        column[:] = 0.0
        column[j] = 1.0
        lu_solve(factors, column)
        for i in range(n):
            if not fixed[i]:
                rows[i] += abs(column[i])
        force += abs(np.dot(end_row, column))
    return rows.max(), force


def compare_solvers(data) -> dict:
    """Largest static-vs-dynamic differences of each figure's files, and their bound."""
    return {figure: compare_pair(*solver_pair(data, figure)) for figure in FIGURES}


def compare_pair(static: Results, dynamic: Results) -> dict:
    """End force and positions, static against dynamic, at every step and yarn, with the
    bound of the module docstring; friction states compared crossing by crossing."""
    model = build_model(scene_of(static))
    fixed = model.fixed_dofs()
    s, d = static.steps, dynamic.steps
    steps, yarns = s["load"].shape
    nodes = np.asarray(static.reference["crossing_nodes"], int)
    start = np.asarray(static.reference["positions"])[:, nodes, 0]  # the as-woven anchors
    dx = np.abs(s["positions"] - d["positions"]).max(axis=(2, 3))
    dP = np.abs(s["end_force"] - d["end_force"])
    inv_norm, force_norm, bracket = (np.zeros((steps, yarns)) for _ in range(3))
    for i in range(steps):
        anchors = start if i == 0 else s["anchors"][i - 1]
        other = start if i == 0 else d["anchors"][i - 1]
        for k, yarn in enumerate(model.yarns):
            inv_norm[i, k], force_norm[i, k] = jacobian_norms(yarn, s["positions"][i, k],
                                                      np.ascontiguousarray(anchors[k]), fixed)
            anchor_term = 0.0
            if yarn.active[FRICTION]:
                sticking = ~s["sliding"][i, k].astype(bool)
                if sticking.any():
                    anchor_term = yarn.stick_stiffness * float(
                        np.abs(anchors[k] - other[k])[sticking].max())
            bracket[i, k] = s["residual"][i, k] + d["residual"][i, k] + anchor_term
    x_bound, P_bound = inv_norm * bracket, force_norm * bracket
    worst_x = np.unravel_index(np.argmax(dx / x_bound), dx.shape)
    worst_P = np.unravel_index(np.argmax(dP / P_bound), dP.shape)
    states = [np.stack([state_codes(r, k) for k in range(yarns)], axis=1) for r in (static, dynamic)]
    return {
        "max_end_force_difference_N": float(dP.max()),
        "max_force_per_width_difference_N_per_m": float(dP.max() / width(static)),
        "max_relative_end_force_difference": float((dP / np.abs(s["end_force"]).max()).max()),
        "max_position_difference_m": float(dx.max()),
        "max_residual_static_N": float(s["residual"].max()),
        "max_residual_dynamic_N": float(d["residual"].max()),
        "inverse_stiffness_norm_m_per_N": {"min": float(inv_norm.min()),
                                           "max": float(inv_norm.max())},
        "max_position_bound_m": float(x_bound.max()),
        "max_position_over_bound": float((dx / x_bound).max()),
        "position_at_worst": {"step": int(worst_x[0]) + 1, "yarn": int(worst_x[1]),
                              "difference_m": float(dx[worst_x]),
                              "bound_m": float(x_bound[worst_x])},
        "max_end_force_bound_N": float(P_bound.max()),
        "max_end_force_over_bound": float((dP / P_bound).max()),
        "end_force_at_worst": {"step": int(worst_P[0]) + 1, "yarn": int(worst_P[1]),
                               "difference_N": float(dP[worst_P]),
                               "bound_N": float(P_bound[worst_P])},
        "max_anchor_term_N": float((bracket - s["residual"] - d["residual"]).max()),
        "friction_state_mismatches": int((states[0] != states[1]).sum()),
        "within_bound": bool((dx <= x_bound).all() and (dP <= P_bound).all()),
    }


# --------------------------------------------------------------------------
# The paper's trends (docs/model.md section 8), checked on the data of each solver.


def check_trends(data, comparison: dict | None = None) -> dict:
    """Each trend of docs/model.md section 8 on the static and on the dynamic data: numbers and
    verdict.

    Thresholds and why:

    * K ordering (Fig. 3a) and friction stiffening (Fig. 5): the curves must be ordered at
      every load step by more than the largest static-vs-dynamic end-force difference, so
      that the ordering is not solver noise;
    * the K effect shrinks (the paper: "the effect of yarn compression decreases with the
      ongoing loss of undulation"): the spread between K = 0.02 and 1.0 at the end is at
      most `SHRINK_SHARE` of its largest value along the path;
    * contact force grows and saturates (Fig. 3b): it rises at every step, and at most
      `SATURATION_SHARE` (10 %) of its growth from the first step to the end happens in the
      last quarter of the displacement; a growth linear in the displacement puts 25 % there;
    * the friction gap (Fig. 5) grows during the first stage: gap(5 % strain) >=
      `GAP_GROWTH` x gap(first step) (a 10 % rise, visible on the figure and far above the
      solver's 1e-6 relative precision); then stays nearly constant: it changes by at most
      `GAP_FLAT` (10 %) of its value between 5 % strain and the end ("nearly parallel");
    * once every crossing slides, the gap is set by the friction limits: with the same mean
      tension (displacement control) the end force exceeds it by sum_j F_T x_j / L, half the
      summed F_T for crossings symmetric about the middle; the end gap must be within
      `GAP_HALF_SUM` (5 %) of that (crimp and stretch make it inexact).
    """
    comparison = comparison if comparison is not None else compare_solvers(data)
    noise = {figure: comparison[figure]["max_end_force_difference_N"] for figure in FIGURES}
    return {
        "fig3a_smaller_K_stiffer": _per_solver(data, "fig3", _k_ordering, noise["fig3"]),
        "fig3a_K_effect_shrinks": _per_solver(data, "fig3", _k_effect_shrinks),
        "fig3b_contact_force_grows_and_saturates": _per_solver(data, "fig3", _saturation),
        "fig3b_smaller_K_larger_contact_force": _per_solver(data, "fig3", _contact_ordering),
        "fig5_friction_stiffens": _per_solver(data, "fig5", _friction_stiffens, noise["fig5"]),
        "fig5_gap_grows_then_nearly_constant": _per_solver(data, "fig5", _gap_shape),
        "fig5_gap_is_half_the_friction_limits": _per_solver(data, "fig5", _gap_half_sum),
    }


def _per_solver(data, figure, check, *args) -> dict:
    results = {solver: check(data[(figure, solver)], *args) for solver in SOLVERS}
    return {"passed": all(r["passed"] for r in results.values()), **results}


def _k_ordering(results: Results, noise_N: float) -> dict:
    """Force per width ordered K = 0.02 > 0.2 > 1.0 at every step, beyond solver noise."""
    order = k_order(results)
    q = force_per_width(results)[:, order]
    gaps = q[:, :-1] - q[:, 1:]
    margin = noise_N / width(results)
    i = np.unravel_index(np.argmin(gaps), gaps.shape)
    return {"K_m_per_N": kawabata_K(results)[order].tolist(),
            "smallest_gap_N_per_m": float(gaps.min()),
            "at_strain_percent": float(strain_percent(results)[i[0], 0]),
            "margin_N_per_m": margin,
            "end_force_per_width_N_per_m": q[-1].tolist(),
            "passed": bool(gaps.min() > margin)}


def _k_effect_shrinks(results: Results) -> dict:
    order = k_order(results)
    q = force_per_width(results)[:, order]
    spread = q[:, 0] - q[:, -1]
    peak = int(np.argmax(spread))
    strain = strain_percent(results)[:, 0]
    return {"largest_spread_N_per_m": float(spread[peak]),
            "at_strain_percent": float(strain[peak]),
            "end_spread_N_per_m": float(spread[-1]),
            "end_spread_relative_to_force": float(spread[-1] / q[-1, 1]),
            "end_over_largest": float(spread[-1] / spread[peak]),
            "threshold": SHRINK_SHARE,
            "passed": bool(spread[-1] <= SHRINK_SHARE * spread[peak])}


def _saturation(results: Results) -> dict:
    order = k_order(results)
    R = mean_contact_force(results)[:, order]
    u = results.steps["end_displacement"][:, 0]
    three_quarters = np.array([np.interp(0.75 * u[-1], u, R[:, k]) for k in range(R.shape[1])])
    growth = R[-1] - R[0]
    share = (R[-1] - three_quarters) / growth
    rising = np.diff(R, axis=0)
    return {"K_m_per_N": kawabata_K(results)[order].tolist(),
            "first_step_N": R[0].tolist(), "end_N": R[-1].tolist(),
            "smallest_increment_N": float(rising.min()),
            "last_quarter_share_of_growth": share.tolist(),
            "threshold": SATURATION_SHARE,
            "passed": bool(rising.min() > 0 and (share <= SATURATION_SHARE).all())}


def _contact_ordering(results: Results) -> dict:
    R = mean_contact_force(results)[:, k_order(results)]
    gaps = R[:, :-1] - R[:, 1:]
    return {"smallest_gap_N": float(gaps.min()), "end_N": R[-1].tolist(),
            "passed": bool(gaps.min() > 0)}


def _friction_stiffens(results: Results, noise_N: float) -> dict:
    gap = friction_gap(results)
    margin = noise_N / width(results)
    return {"smallest_gap_N_per_m": float(gap.min()), "margin_N_per_m": margin,
            "passed": bool(gap.min() > margin)}


def _gap_shape(results: Results) -> dict:
    gap = friction_gap(results)
    on, _ = friction_split(results)
    strain = strain_percent(results)[:, 0]
    at_stage = at_strain(results, gap, STRAIN_STAGE)
    growth = at_stage / gap[0]
    change = abs(gap[-1] - at_stage) / at_stage
    knee = strain[np.argmax(gap >= 0.9 * gap[-1])]
    codes = state_codes(results, on)
    all_sliding = np.flatnonzero((codes == 2).all(axis=1))
    return {"first_step_strain_percent": float(strain[0]),
            "gap_first_step_N_per_m": float(gap[0]),
            "gap_at_5_percent_N_per_m": at_stage,
            "gap_end_N_per_m": float(gap[-1]),
            "growth_first_step_to_5_percent": growth, "growth_threshold": GAP_GROWTH,
            "relative_change_5_percent_to_end": change, "flat_threshold": GAP_FLAT,
            "strain_percent_at_90_percent_of_end_gap": float(knee),
            "strain_percent_when_every_crossing_slides":
                float(strain[all_sliding[0]]) if all_sliding.size else None,
            "passed": bool(growth >= GAP_GROWTH and change <= GAP_FLAT)}


def _gap_half_sum(results: Results) -> dict:
    gap = friction_gap(results)
    on, _ = friction_split(results)
    half_sum = 0.5 * results.steps["friction_limit"][-1, on].sum() / width(results)
    deviation = abs(gap[-1] - half_sum) / half_sum
    return {"gap_end_N_per_m": float(gap[-1]), "half_sum_F_T_N_per_m": float(half_sum),
            "relative_deviation": float(deviation), "threshold": GAP_HALF_SUM,
            "passed": bool(deviation <= GAP_HALF_SUM)}


def trend_lines(summary: dict) -> list[str]:
    """One line per trend and per figure's static-vs-dynamic comparison, for the terminal."""
    lines = []
    for name, trend in summary["trends"].items():
        lines.append(f"{name}: {'holds' if trend['passed'] else 'FAILS'}")
    for figure, c in summary["static_vs_dynamic"].items():
        lines.append(f"{figure} static vs dynamic: end force "
                     f"{c['max_end_force_difference_N']:.2e} N "
                     f"(<= {c['max_end_force_over_bound']:.2f} x its bound), positions "
                     f"{c['max_position_difference_m']:.2e} m "
                     f"(<= {c['max_position_over_bound']:.2f} x the bound "
                     f"||J^-1|| (r_dyn + r_static + ...), at most "
                     f"{c['max_position_bound_m']:.2e} m)")
    return lines
