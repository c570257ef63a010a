"""Stability report table: ``stability.md``, one row per case, then the numbered notes.

Written from the summary `dynfab.reports.stability.run_stability` builds.
"""

from __future__ import annotations

from dynfab.reports.stability_cases import METHODS, short_number


def _dt_us(value) -> str:
    return "-" if value is None else f"{1e6 * value:.3g}"


def _load_text(case: dict) -> str:
    if case["load"] is None:
        return "-"
    if case["control"] == "force":
        return f"P = {case['load']:.3g} N"
    return f"u = {1e3 * case['load']:.3g} mm"


def _note(notes: list[str], text: str) -> int:
    """The number of note `text`, added if new."""
    if text not in notes:
        notes.append(text)
    return notes.index(text) + 1


def _relaxation_cell(stability: dict, notes: list[str]) -> str:
    relaxation = stability.get("relaxation_at_measured_dt")
    if not relaxation:
        return "-"
    if relaxation["verdict"] == "converged":
        return f"yes, {relaxation['time_steps']} st"
    if relaxation["verdict"] == "failed":
        return f"**no** [{_note(notes, relaxation['message'])}]"
    return relaxation["verdict"]


def _cell(method: dict, notes: list[str]) -> str:
    """One method's verdict in the table; long messages go to numbered notes."""
    verdict = method.get("verdict")
    if verdict == "converged":
        error = method.get("error_over_A_wa")
        bound = method.get("bound_over_A_wa")
        text = f"{method['time_steps']} st, {method['wall_time_s']:.2g} s"
        if error is not None:
            text += f", err {error:.1e}" + (f" (bound {bound:.0e})" if bound is not None else "")
        return text + (" (floor)" if method.get("rounding_floor") else "")
    if verdict is None:
        return "-"
    number = _note(notes, method.get("message", ""))
    label = {"failed": "**FAILED**", "skipped": "skipped",
             "extrapolated: converges": f"~{method.get('predicted_time_steps', 0):.2g} st "
                                        "(extrapolated)",
             "extrapolated: max_steps": f"**~{method.get('predicted_time_steps', 0):.2g} st > "
                                        "max_steps** (extrapolated)"}.get(verdict, verdict)
    return f"{label} [{number}]"


def stability_markdown(summary: dict) -> str:
    """The table: one row per case, the stable dt and each method's verdict; then the notes."""
    notes: list[str] = []
    settings = summary["settings"]
    lines = [f"## Stability of the dynamic methods ({summary['plan']} plan)", "",
             "Stable dt [us]: *predicted* is the solver's Gershgorin bound on the stiffest tangent "
             "of the load step (every contact at k_we, every crossing sticking); *measured* the "
             f"largest dt whose {settings['bisection_steps']} undamped steps from the perturbed "
             "relaxed state stay bounded (bisection to "
             f"{100 * (settings['bisection_ratio'] - 1):g} %, physical masses); *linear* the exact "
             "2/omega_max of the actual tangent at the relaxed state. *Relaxes at measured dt*: "
             "the load step from the as-woven state with the physical masses, kinetic damping "
             "and the measured dt. Methods: time steps (st) and wall time of the "
             "load step, the largest position error against the static reference / A_wa and its "
             f"bound ||K^-1|| (r + r_s) / A_wa. max_steps: {settings['explicit_max_steps']} "
             f"(explicit), {settings['semi_implicit_max_steps']} (semi_implicit).", "",
             "| case | load | stable dt: predicted | measured | measured / predicted | linear | "
             "relaxes at measured dt | " + " | ".join(METHODS) + " |",
             "|---|---|---|---|---|---|---|" + "---|" * len(METHODS)]
    for case in summary["cases"]:
        stability = case.get("stability") or {}
        if case["refused"] is not None:
            cells = [f"**refused** [{_note(notes, case['refused'])}]"] + ["-"] * (len(METHODS) - 1)
            lines.append(f"| {case['case']} | - | - | - | - | - | - | " + " | ".join(cells) + " |")
            continue
        ratio = stability.get("measured_over_predicted")
        kinetic_note = " (k)" if stability.get("measured_with") == "kinetic damping" else ""
        cells = [_cell(case["methods"].get(name, {}), notes) for name in METHODS]
        lines.append(f"| {case['case']} | {_load_text(case)} | "
                     f"{_dt_us(stability.get('predicted_dt_s'))} | "
                     f"{_dt_us(stability.get('measured_dt_s'))}{kinetic_note} | "
                     f"{short_number(ratio, 3)} | {_dt_us(stability.get('linear_dt_s'))} | "
                     f"{_relaxation_cell(stability, notes)} | " + " | ".join(cells) + " |")
    lines.append("")
    if any((c.get("stability") or {}).get("measured_with") == "kinetic damping"
           for c in summary["cases"]):
        lines += ["(k): measured with kinetic damping instead of undamped (--quick: the undamped "
                  "friction variant is not compiled). An unstable mode's kinetic energy rises "
                  "every step and is never reset, so it is caught as when undamped; but the "
                  "resets also remove the energy that stick/slip switching slowly pumps into an "
                  "undamped motion, so with friction this threshold is higher than the undamped "
                  "one (the full report measures both: 1.0 to 4.3 x).", ""]
    if summary["mesh_fit"]:
        lines += ["Explicit step counts against N, fitted (least squares) as steps = c N^p: "
                  + "; ".join(
                      f"{name} p = {fit['exponent']:.2f} (N = {', '.join(map(str, fit['segments']))}"
                      f": {', '.join(map(str, fit['time_steps']))} steps; between the two finest "
                      f"meshes p = {fit['local_exponent']:.2f})"
                      for name, fit in summary["mesh_fit"].items()) + ".", ""]
    lines += path_markdown(summary.get("paths", []), notes)
    lines += ["Notes:", ""]
    lines += [f"{k}. {text}" for k, text in enumerate(notes, start=1)]
    lines.append("")
    return "\n".join(lines)


def _path_cell(method: dict, notes: list[str]) -> str:
    """One method along a load path: total time steps, wall time and the largest difference
    from the static reference; or where it stopped, with its message as a note."""
    verdict = method.get("verdict")
    if verdict == "converged":
        return (f"{sum(method['time_steps'])} st, {method['wall_time_s']:.2g} s, "
                f"diff {method['largest_difference']:.1e} {method['largest_difference_units']}")
    if verdict == "failed":
        return (f"**FAILED** at step {method['failed_load_step']} after "
                f"{method['time_steps'][-1]} st [{_note(notes, method['message'])}]")
    if verdict is None:
        return "-"
    return f"{verdict} [{_note(notes, method.get('message', ''))}]"


def path_markdown(paths: list[dict], notes: list[str]) -> list[str]:
    """The friction load path table: one row per mesh, the static reference and each method."""
    if not paths:
        return []
    lines = ["Friction load paths (paper_fig5.toml entry 0, end force "
             f"{', '.join(f'{1e3 * v:g}' for v in paths[0]['values'])} mN; each method from its "
             "own last state; diff: the largest end displacement (force control) or end force "
             "(displacement control) difference from the static reference):", "",
             "| path | control | static | " + " | ".join(METHODS) + " |",
             "|---|---|---|" + "---|" * len(METHODS)]
    for path in paths:
        static = path["static"] or {}
        static_cell = (f"**FAILED** [{_note(notes, static['failed'])}]" if "failed" in static
                       else f"{sum(static['iterations'])} it")
        cells = [_path_cell(path["methods"].get(name, {}), notes) for name in METHODS]
        lines.append(f"| {path['case']} | {path['control']} | {static_cell} | "
                     + " | ".join(cells) + " |")
    return lines + [""]
