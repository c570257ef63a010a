"""Convergence report (`dynfab convergence`): is N = 224 enough, and how much do the answers
depend on the load increment and on the stick stiffness?

`run_convergence(out_dir, quick=False)` solves the paper's scenes with the static
Newton reference (docs/model.md section 6) under displacement control and writes, into `out_dir`:

* ``mesh.csv``, ``load_steps.csv``, ``stick_stiffness.csv``: tidy rows (study, scene,
  parameter, parameter value, load, quantity, value, with the units of each);
* ``summary.json``: the machine, the wall times, every solve, the observed orders and
  the check of the paper's eq. 27 at the sliding crossings;
* ``orders.md``: the observed orders as markdown tables;
* ``mesh.png``, ``load_steps.png``, ``stick_stiffness.png``: log-log error against the
  study's parameter, with a reference slope line.

The three studies (scenes from ``runs/paper_fig3.toml``, entry K = 0.2 m/N, and
``runs/paper_fig5.toml``, entry 0 with friction; both prestressed, end displacement
to 10 mm in 40 steps):

1. mesh: N = 224 ... 3584 on the same load path (the same end displacements at every
   N). For the friction scene the stick stiffness is held at its default for N = 224,
   EA / (L / 224), at every N, so that only the discretisation changes (the default
   k_t = EA / (L / N) would change the regularisation with N as well);
2. load increment: the friction scene with 10 ... 160 steps to the same 10 mm;
3. stick stiffness: the friction scene with k_t = 10 ... 1000 x EA / (L / N).

Observed order: minus the slope of a least-squares line through
log |q(p) - q(p_finest)| against log p (the finest p excluded), p = N, the step count or
k_t (an error O(1/k_t) is order 1 in 1/k_t). Because q(p_finest) carries an error of
its own, this estimator over-reads an exact order (by +0.13 for order 2 and +0.29 for
order 1 on five levels of ratio 2); each order is therefore reported with
``expected_fit``, what the same estimator gives for an exact power law of the
expected order on the same parameter values, and with ``order_successive``, the slope
through the differences of neighbours |q(p_i) - q(p_i+1)|, which has no such bias on
a geometric sequence. Differences below ``NOISE`` x |q| (the solver's precision, well
above its 1e-11 N residual) are not an error signal: a quantity whose every difference
is below it is reported as independent of the parameter (order None).

``quick=True`` solves the same yarn cut to 4 crossings (L / 4, the same crossing
spacing, weft and mesh density, end displacements / 4), N = 32 ... 512, 10 ... 160 load
steps: a few seconds. Errors for user mistakes are `UserError`s.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Callable

import numpy as np
from matplotlib.figure import Figure
from matplotlib.lines import Line2D

from dynfab.model import assembly
from dynfab.model.builders import build_model
from dynfab.plots.style import FONT_SIZE, new_figure, save_png, style_axes
from dynfab.reports.common import (cut_yarn, default_stick_stiffness, output_folder, paper_yarns,
                                   report_header, with_path, write_csv, write_summary, write_text)
from dynfab.run import run
from dynfab.scene import Scene, with_key

NOISE = 1e-9
"""Relative difference [-] below which two solves count as equal (solver precision)."""


CSV_COLUMNS = ("study", "scene", "parameter", "parameter_value", "parameter_units",
               "load", "load_units", "quantity", "value", "units")

QUANTITIES = {
    # name: (units, label, value of yarn 0 at step i)
    "end_force": ("N", "end force P", lambda s, i: s["end_force"][i, 0]),
    "max_contact_force": ("N", "largest contact force",
                          lambda s, i: s["contact_force"][i, 0].max()),
    "crimp": ("-", "crimp", lambda s, i: s["crimp"][i, 0]),
    "dissipated_energy": ("J", "dissipated energy", lambda s, i: s["dissipated"][i, 0]),
}

SCENE_LABELS = {"frictionless": "frictionless, K = 0.2 m/N", "friction": "friction (Gralen)"}


@dataclass(frozen=True)
class Plan:
    """The scenes' size and the values each study solves."""

    name: str
    crossings: int
    """Crossings of the yarn (the paper's 16, or fewer, at the same spacing)."""
    base_segments: int
    """N of the load-increment and stick-stiffness studies: the paper's mesh density."""
    max_displacement: float
    """Final end displacement [m] (10 mm on the paper's 0.1 m yarn: 10 % strain)."""
    steps: int
    """Load steps of the mesh and stick-stiffness studies."""
    mesh_segments: tuple[int, ...]
    mesh_loads: tuple[float, ...]
    """End displacements [m] where the mesh study compares."""
    step_counts: tuple[int, ...]
    step_loads: tuple[float, ...]
    stick_factors: tuple[float, ...]
    """k_t as multiples of the default EA / (L / N)."""
    stick_loads: tuple[float, ...]
    """Early loads (some crossings still stick) and late ones (all slide)."""


FULL = Plan(name="full", crossings=16, base_segments=224, max_displacement=10e-3, steps=40,
            mesh_segments=(224, 448, 896, 1792, 3584), mesh_loads=(2.5e-3, 5e-3, 10e-3),
            step_counts=(10, 20, 40, 80, 160), step_loads=(1e-3, 5e-3, 10e-3),
            stick_factors=(10.0, 30.0, 100.0, 300.0, 1000.0),
            stick_loads=(0.25e-3, 0.5e-3, 1e-3, 5e-3, 10e-3))
QUICK = Plan(name="quick", crossings=4, base_segments=56, max_displacement=2.5e-3, steps=40,
             mesh_segments=(32, 64, 128, 256, 512), mesh_loads=(0.625e-3, 1.25e-3, 2.5e-3),
             step_counts=(10, 20, 40, 80, 160), step_loads=(0.25e-3, 1.25e-3, 2.5e-3),
             stick_factors=(10.0, 30.0, 100.0, 300.0, 1000.0),
             stick_loads=(0.0625e-3, 0.125e-3, 1.25e-3, 2.5e-3))

STUDIES = {
    # name: (parameter, parameter units, axis label, expected order, quantities)
    "mesh": ("segments", "-", "segments N (-)", 2.0, ("end_force", "max_contact_force", "crimp")),
    "load_steps": ("load_steps", "-", "load steps to the final displacement (-)", 1.0,
                   ("end_force", "max_contact_force", "dissipated_energy")),
    "stick_stiffness": ("stick_stiffness", "N/m", "stick stiffness k_t (N/m)", 1.0,
                        ("end_force", "max_contact_force")),
}


def run_convergence(out_dir, *, quick: bool = False,
                    progress: Callable[[str], None] | None = None) -> dict:
    """Run the three studies, write the CSVs, JSON, markdown and PNGs; return the summary.

    `progress` receives one line per solve (None: silent). Raises UserError when
    `out_dir` cannot be a folder or the paper scenes are missing.
    """
    out = output_folder(out_dir)
    plan = QUICK if quick else FULL
    started = time.perf_counter()
    scenes = paper_scenes(plan)
    total = (2 * len(plan.mesh_segments) + len(plan.step_counts) + len(plan.stick_factors))
    solver = _Solver(total, progress)
    rows = {"mesh": mesh_study(plan, scenes, solver),
            "load_steps": load_step_study(plan, scenes["friction"], solver),
            "stick_stiffness": stick_study(plan, scenes["friction"], solver)}
    studies = {name: analyse(name, study_rows) for name, study_rows in rows.items()}
    summary = {
        **report_header("convergence", plan.name, quick),
        "solve_time_s": solver.solve_time,
        "solves": solver.log,
        "studies": studies,
        "eq27": solver.friction_check(),
    }
    files = [write_csv(out / f"{name}.csv", CSV_COLUMNS, study_rows)
             for name, study_rows in rows.items()]
    files.append(write_text(out / "orders.md", orders_markdown(summary)))
    files += [save_png(plot_study(name, studies[name]), out / f"{name}.png") for name in rows]
    return write_summary(out, summary, files, started)


# --------------------------------------------------------------------------
# Scenes and solves.


def paper_scenes(plan: Plan) -> dict[str, Scene]:
    """The frictionless (K = 0.2 m/N) and friction paper yarns, cut to `plan.crossings`."""
    frictionless, friction = paper_yarns("the convergence report")
    return {label: cut_yarn(scene, plan.crossings, plan.base_segments)
            for label, scene in (("frictionless", frictionless), ("friction", friction))}


class _Solver:
    """Runs scenes with the static solver, one progress line each; keeps the log and the
    eq. 27 check of every friction solve."""

    def __init__(self, total: int, progress):
        self.total, self.progress = total, progress
        self.log: list[dict] = []
        self.checks: list[dict] = []
        self.solve_time = 0.0

    def solve(self, scene: Scene, study: str, label: str, value) -> dict:
        started = time.perf_counter()
        steps = run(scene, solver="static").steps
        elapsed = time.perf_counter() - started
        self.solve_time += elapsed
        entry = {"study": study, "scene": label, "parameter_value": value,
                 "segments": scene.geometry.segments, "load_steps": int(steps["load"].shape[0]),
                 "newton_iterations": int(steps["iterations"].sum()),
                 "max_residual_N": float(steps["residual"].max()),
                 "steps_at_rounding_floor": int(steps["rounding_floor"].sum()),
                 "wall_time_s": elapsed}
        self.log.append(entry)
        if scene.friction is not None:
            self.checks.append({"study": study, "parameter_value": value,
                                **friction_check(build_model(scene), steps)})
        if self.progress is not None:
            floor = entry["steps_at_rounding_floor"]
            note = f", {floor} at the rounding floor" if floor else ""
            mesh = "" if study == "mesh" else f", N = {entry['segments']}"
            self.progress(
                f"[{len(self.log):>2}/{self.total}] {study}: {label}, "
                f"{_parameter_text(study, value)}{mesh}: {entry['load_steps']} load steps, "
                f"{entry['newton_iterations']} Newton iterations, residual <= "
                f"{entry['max_residual_N']:.1e} N{note}, {elapsed:.2f} s")
        return steps

    def friction_check(self) -> dict:
        """The worst of every friction solve's eq. 27 check."""
        worst = {key: max(c[key] for c in self.checks) for key in self.checks[0]
                 if key not in ("study", "parameter_value")}
        worst["sliding_crossing_steps"] = sum(c["sliding_crossing_steps"] for c in self.checks)
        worst["solves"] = len(self.checks)
        return worst


def friction_check(model, steps: dict) -> dict:
    """Eq. 27 at the sliding (closed) crossings of yarn 0, at every step of a solve.

    A sliding crossing must carry exactly F_T, against the slip s = x - xi:

    * equilibrium: the force the rest of the yarn puts on the node, dV/dx of the
      elastic and contact terms (the paper's dV/du), must be -sign(s) F_T to within
      the step's Newton residual (the residual is the largest such imbalance);
    * the record: |friction force| = F_T, to rounding (exactly, as -sign(s) F_T; a
      record computed as the stick spring k_t (x - xi) would round by up to
      k_t eps |x|, given as `stick_force_rounding_N`);
    * F_T = Gralen's law at the step's R (docs/model.md section 4: to 1e-12 N);
    * a sticking crossing's force within the limit (`max_stick_excess_N` <= 0).
    """
    yarn = model.yarns[0]
    nodes = yarn.crossing_node
    no_friction = np.zeros(nodes.size)
    grad = np.zeros_like(steps["positions"][0, 0])
    out = {"sliding_crossing_steps": 0, "max_equilibrium_deviation_N": 0.0,
           "max_residual_N": 0.0, "max_abs_force_minus_limit_N": 0.0,
           "stick_force_rounding_N": 0.0, "max_gralen_deviation_N": 0.0,
           "max_stick_excess_N": -np.inf}

    def keep_max(key: str, value) -> None:
        """out[key]: the larger of it and `value` (a float)."""
        out[key] = max(out[key], float(value))

    for i in range(steps["load"].shape[0]):
        positions, anchors = steps["positions"][i, 0], steps["anchors"][i, 0]
        R, limit = steps["contact_force"][i, 0], steps["friction_limit"][i, 0]
        force = steps["friction_force"][i, 0]
        sliding = steps["sliding"][i, 0].astype(bool) & (R > 0)
        x = positions[nodes, 0]
        gralen = np.where(R > 0, yarn.friction_alpha * R + yarn.friction_constant, 0.0)
        keep_max("max_gralen_deviation_N", np.abs(limit - gralen).max())
        sticking = ~steps["sliding"][i, 0].astype(bool)
        if sticking.any():
            keep_max("max_stick_excess_N", (np.abs(force) - limit)[sticking].max())
        if not sliding.any():
            continue
        assembly.gradient(np.ascontiguousarray(positions), yarn, 0.0,
                          np.ascontiguousarray(anchors), no_friction, grad)
        pull = grad[nodes, 0]  # dV/dx without friction: balances the friction force
        carried = -np.sign(x - anchors) * limit  # eq. 27 (anchors return-mapped: sign kept)
        out["sliding_crossing_steps"] += int(sliding.sum())
        keep_max("max_equilibrium_deviation_N", np.abs(pull - carried)[sliding].max())
        keep_max("max_residual_N", steps["residual"][i, 0])
        keep_max("max_abs_force_minus_limit_N", np.abs(np.abs(force) - limit)[sliding].max())
        keep_max("stick_force_rounding_N",
                 yarn.stick_stiffness * np.finfo(float).eps * np.abs(x).max())
    return out


# --------------------------------------------------------------------------
# The three studies: tidy rows.


def _rows(study: str, scene_label: str, value, steps: dict, loads) -> list[dict]:
    """One row per (load, quantity of the study) of one solve."""
    parameter, units, _, _, quantities = STUDIES[study]
    rows = []
    for load in loads:
        i = step_at(steps, load)
        for name in quantities:
            unit, _, get = QUANTITIES[name]
            rows.append({"study": study, "scene": scene_label, "parameter": parameter,
                         "parameter_value": value, "parameter_units": units, "load": load,
                         "load_units": "m", "quantity": name, "value": float(get(steps, i)),
                         "units": unit})
    return rows


def step_at(steps: dict, load: float) -> int:
    """The index of the step whose end displacement is `load` [m] (exactly one)."""
    found = np.flatnonzero(np.abs(steps["end_displacement"][:, 0] - load) <= 1e-12)
    if found.size != 1:
        raise RuntimeError(f"no single load step at end displacement {load!r} m")
    return int(found[0])


def mesh_study(plan: Plan, scenes: dict[str, Scene], solver: _Solver) -> list[dict]:
    """Both scenes at every N, on the same load path; friction at a fixed k_t."""
    rows = []
    for label, base in scenes.items():
        base = with_path(base, plan.max_displacement, plan.steps)
        if base.friction is not None:
            base = with_key(base, "friction.stick_stiffness", default_stick_stiffness(base))
        for n in plan.mesh_segments:
            steps = solver.solve(with_key(base, "geometry.segments", n), "mesh", label, n)
            rows += _rows("mesh", label, n, steps, plan.mesh_loads)
    return rows


def load_step_study(plan: Plan, scene: Scene, solver: _Solver) -> list[dict]:
    """The friction scene with each step count to the same final displacement."""
    rows = []
    for count in plan.step_counts:
        steps = solver.solve(with_path(scene, plan.max_displacement, count), "load_steps",
                             "friction", count)
        rows += _rows("load_steps", "friction", count, steps, plan.step_loads)
    return rows


def stick_study(plan: Plan, scene: Scene, solver: _Solver) -> list[dict]:
    """The friction scene with k_t = factor x EA / (L / N)."""
    base = with_path(scene, plan.max_displacement, plan.steps)
    default = default_stick_stiffness(base)
    rows = []
    for factor in plan.stick_factors:
        value = factor * default
        steps = solver.solve(with_key(base, "friction.stick_stiffness", value),
                             "stick_stiffness", "friction", value)
        rows += _rows("stick_stiffness", "friction", value, steps, plan.stick_loads)
    return rows


# --------------------------------------------------------------------------
# Observed orders.


def fitted_order(parameters, errors) -> float:
    """Minus the least-squares slope of log error against log parameter."""
    slope = np.polyfit(np.log(parameters), np.log(errors), 1)[0]
    return float(-slope)


def analyse(study: str, rows: list[dict]) -> dict:
    """Observed orders of every (scene, quantity, load) of a study."""
    parameter, units, _, expected, _ = STUDIES[study]
    groups: dict[tuple, list[dict]] = {}
    for row in rows:
        groups.setdefault((row["scene"], row["quantity"], row["load"]), []).append(row)
    orders = []
    for (scene, quantity, load), group in groups.items():
        group = sorted(group, key=lambda r: r["parameter_value"])
        p = np.array([r["parameter_value"] for r in group], float)
        q = np.array([r["value"] for r in group], float)
        orders.append({"scene": scene, "quantity": quantity, "load": load,
                       "units": group[0]["units"], **order_of(p, q, expected)})
    measured = [o["order"] for o in orders if o["order"] is not None]
    return {"parameter": parameter, "parameter_units": units,
            "parameter_values": sorted({r["parameter_value"] for r in rows}),
            "expected_order": expected,
            "median_order": float(np.median(measured)) if measured else None,
            "orders": orders}


def order_of(p: np.ndarray, q: np.ndarray, expected: float) -> dict:
    """The observed order of q(p) against the finest p (the last), and its checks."""
    errors = np.abs(q[:-1] - q[-1])
    neighbours = np.abs(np.diff(q))
    noise = NOISE * max(np.abs(q).max(), np.finfo(float).tiny)
    above = errors > noise
    result = {"parameter_values": p.tolist(), "values": q.tolist(),
              "errors": errors.tolist(), "noise": noise,
              "max_difference": float(np.abs(q - q[-1]).max()),
              "relative_difference_coarsest": float(errors[0] / abs(q[-1])) if q[-1] else None,
              "expected_order": expected,
              "expected_fit": fitted_order(p[:-1], p[:-1] ** -expected - p[-1] ** -expected),
              "order": None, "order_successive": None, "note": ""}
    if above.sum() < 2:
        result["note"] = ("independent of the parameter: every difference from the finest is "
                          f"below {NOISE:g} x the value (largest {result['max_difference']:.2g})")
        return result
    result["order"] = fitted_order(p[:-1][above], errors[above])
    keep = neighbours > noise
    if keep.sum() >= 2:
        result["order_successive"] = fitted_order(p[:-1][keep], neighbours[keep])
    if not above.all():
        result["note"] = f"{int((~above).sum())} difference(s) below the noise level left out"
    return result


# --------------------------------------------------------------------------
# Files.


def _show_order(value) -> str:
    return "-" if value is None else f"{value:.2f}"


def _load_mm(load: float) -> str:
    return f"{1e3 * load:g} mm"


def orders_markdown(summary: dict) -> str:
    """The observed orders: one table per study, one row per (scene, quantity, load)."""
    lines = []
    titles = {"mesh": "Mesh: segments N", "load_steps": "Load increment: number of load steps",
              "stick_stiffness": "Stick stiffness: order in 1/k_t"}
    for name, study in summary["studies"].items():
        parameters = study["parameter_values"]
        values = ", ".join(f"{v:.4g}" for v in parameters)
        first, last = _parameter_text(name, parameters[0]), _parameter_text(name, parameters[-1])
        lines += [f"### {titles[name]} ({values} {study['parameter_units']})", "",
                  f"Expected order {study['expected_order']:g}. Observed: fit of "
                  "|q - q(finest)| (what the same fit gives for an exact power law of the "
                  "expected order); successive: fit of the neighbours' differences.", "",
                  "| scene | quantity | load | observed order | exact-power-law fit | "
                  f"successive | {first} vs {last}: difference | relative | note |",
                  "|---|---|---|---|---|---|---|---|---|"]
        for o in study["orders"]:
            relative = o["relative_difference_coarsest"]
            lines.append(
                f"| {o['scene']} | {o['quantity']} | {_load_mm(o['load'])} | "
                f"{_show_order(o['order'])} | {o['expected_fit']:.2f} | "
                f"{_show_order(o['order_successive'])} | {o['errors'][0]:.3g} {o['units']} | "
                f"{'-' if relative is None else f'{relative:.2g}'} | {o['note']} |")
        lines.append("")
    check = summary["eq27"]
    lines += ["### Eq. 27 at the sliding crossings", "",
              f"{check['sliding_crossing_steps']} sliding crossing-steps over {check['solves']} "
              "friction solves:", "",
              "- equilibrium (eq. 27, dV/du = -F_T): largest deviation of dV/dx at the node "
              f"from -sign(s) F_T: {check['max_equilibrium_deviation_N']:.3g} N (largest Newton "
              f"residual of those steps: {check['max_residual_N']:.3g} N)",
              "- record: largest deviation of the reported friction force's magnitude from "
              f"F_T: {check['max_abs_force_minus_limit_N']:.3g} N (the rounding of a stick-spring "
              f"force k_t (x - xi) would be up to {check['stick_force_rounding_N']:.3g} N)",
              "- largest deviation of F_T from Gralen's law alpha R + beta ell r_f: "
              f"{check['max_gralen_deviation_N']:.3g} N",
              "- sticking crossings: largest (magnitude of the friction force - F_T): "
              f"{check['max_stick_excess_N']:.3g} N (<= 0: within the limit)", ""]
    return "\n".join(lines)


# --------------------------------------------------------------------------
# Figures (matplotlib Figure + Agg, as dynfab.plots.figures).


def _parameter_text(study: str, value: float) -> str:
    return {"mesh": f"N = {value:g}", "load_steps": f"{value:g} steps",
            "stick_stiffness": f"k_t = {value:.3g} N/m"}[study]


def plot_study(study: str, analysis: dict) -> Figure:
    """One panel per quantity: |q(p) - q(finest)| against p, log-log, one line per
    (scene, load), a reference slope of the expected order. A (scene, load) whose
    differences are all below the solver's precision is drawn hollow in a grey band
    (an exact 0 at the band's floor, NOISE x 1e-6 |q|, about the rounding of q)."""
    _, _, xlabel, expected, quantities = STUDIES[study]
    loads = sorted({o["load"] for o in analysis["orders"]})
    scenes = list(dict.fromkeys(o["scene"] for o in analysis["orders"]))
    colors = {load: f"C{k}" for k, load in enumerate(loads)}
    styles = {scene: ("-", "o") if k == 0 else ("--", "s") for k, scene in enumerate(scenes)}
    fig = new_figure(3.3 * len(quantities) + 1.6, 3.4)
    axes = fig.subplots(1, len(quantities), squeeze=False)[0]
    any_flat = False
    for ax, quantity in zip(axes, quantities):
        units, label, _ = QUANTITIES[quantity]
        group = [o for o in analysis["orders"] if o["quantity"] == quantity]
        measured = [o for o in group if o["order"] is not None]
        flat = [o for o in group if o["order"] is None]
        noise = max(o["noise"] for o in group)
        floor = 1e-6 * noise
        for o in measured + flat:
            p = np.array(o["parameter_values"][:-1])
            line, marker = styles[o["scene"]]
            ax.plot(p, np.maximum(o["errors"], floor), ls=line, marker=marker, ms=4,
                    color=colors[o["load"]], mfc="white" if o["order"] is None else None)
        if measured:
            top = max(measured, key=lambda o: o["errors"][0])
            p = np.array(top["parameter_values"][:-1])
            ax.plot(p, 2.0 * top["errors"][0] * (p / p[0]) ** -expected, ":", color="k", lw=1.2)
        if flat or min(min(o["errors"]) for o in group) < 100 * noise:
            ax.axhspan(floor, noise, color="0.88", zorder=0)
        if flat:
            any_flat = True
            where = ", ".join(_load_mm(load) for load in sorted({o["load"] for o in flat}))
            biggest = max(o["max_difference"] for o in flat)
            size = f"<= {biggest:.1g} {units}" if biggest else f"= 0 {units} exactly"
            ax.text(0.03, 0.97 if not measured else 0.1,
                    f"no dependence at {where}:\n|difference| {size}", transform=ax.transAxes,
                    fontsize=FONT_SIZE - 2, va="top" if not measured else "bottom")
            if not measured:
                ax.set_ylim(floor / 10, noise * 1e4)
        ax.set_xscale("log")
        ax.set_yscale("log")
        if study != "stick_stiffness":
            ticks = analysis["parameter_values"][:-1]
            ax.set_xticks(ticks, [f"{t:g}" for t in ticks])
            ax.set_xticks([], minor=True)
        ax.set(xlabel=xlabel, ylabel=f"|{label} - finest| ({units})")
        ax.set_title(label, fontsize=FONT_SIZE)
        style_axes(ax, title_size=FONT_SIZE)
    handles = [Line2D([], [], color=colors[load], marker="o", label=f"u = {_load_mm(load)}")
               for load in loads]
    if len(scenes) > 1:
        handles += [Line2D([], [], color="k", ls=styles[s][0], marker=styles[s][1],
                           label=SCENE_LABELS.get(s, s)) for s in scenes]
    handles.append(Line2D([], [], color="k", ls=":", label=f"slope -{expected:g}"))
    if any_flat:
        handles += [Line2D([], [], color="0.88", lw=6,
                           label=f"below solver precision\n(difference < {NOISE:g} |q|)"),
                    Line2D([], [], color="0.4", marker="o", mfc="white", ls="",
                           label="no dependence")]
    axes[-1].legend(handles=handles, fontsize=FONT_SIZE - 2, loc="upper left",
                    bbox_to_anchor=(1.02, 1.0), borderaxespad=0)
    title = {"mesh": "mesh convergence", "load_steps": "load-increment convergence (friction)",
             "stick_stiffness": "stick-stiffness convergence (friction)"}[study]
    finest = analysis["parameter_values"][-1]
    fig.suptitle(f"{title}: difference from {_parameter_text(study, finest)}; expected order "
                 f"{expected:g}", fontsize=FONT_SIZE + 1)
    return fig
