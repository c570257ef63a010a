"""Precision report table: ``precision.md``, the cases, the cheapest methods and the notes.

Written from the summary `dynfab.reports.precision.run_precision` builds.
"""

from __future__ import annotations

from dynfab.reports.precision_points import usable_points


def _timing_rule(plan: dict) -> str:
    """How each wall time was taken, in words (a plan without a minimum total times a fixed
    number of calls)."""
    if plan["min_timed_s"] > 0:
        return (f"the fastest of at least {plan['repeats']} timed calls (more, up to "
                f"{plan['max_repeats']}, until they add up to {plan['min_timed_s']:g} s)")
    calls = "one timed call" if plan["repeats"] == 1 else f"{plan['repeats']} timed calls"
    return f"the fastest of {calls}" if plan["repeats"] > 1 else calls


def _ms(seconds: float) -> str:
    return f"{1e3 * seconds:.3g} ms"


def _cell(point: dict | None, cost: str) -> str:
    if point is None:
        return "none reaches it"
    amount = _ms(point["wall_time_s"]) if cost == "wall_time_s" else \
        f"{point['force_evaluations']} evaluations, {_ms(point['wall_time_s'])}"
    return (f"{point['label']}, tol {point['tolerance']:.0e} N: {amount} "
            f"(error {point['relative_error']:.1e})")


def precision_markdown(summary: dict) -> str:
    """The cases, the cheapest methods per target, and the notes, as markdown."""
    lines = ["## Precision: error against cost", ""]
    m = summary["machine"]
    plan = summary["plan"]
    lines += [f"Plan `{plan['name']}` on {m['machine']}, {m['cpus']} CPUs, Python "
              f"{m['python']}. Relative error: the largest node position error / A_wa (L for "
              f"a straight yarn). Wall "
              f"time: warm, {_timing_rule(plan)}.", ""]
    lines += ["### Cases", "",
              "| case | nodes | reference residual | inf-norm of K^-1 | c_crit | end quantity | "
              "rounding floor (relative) |", "|---|---|---|---|---|---|---|"]
    for c in summary["cases"]:
        norm = c["inverse_stiffness_norm_m_per_N"]
        crit = c["critical_damping_per_s"]
        lines.append(
            f"| {c['title']} | {c['segments'] + 1} | {c['reference_residual_N']:.1e} N | "
            f"{'-' if norm is None else f'{norm:.3g} m/N'} | "
            f"{'-' if crit is None else f'{crit:.3g} 1/s'} | "
            f"{c['end_quantity'].replace('_', ' ')} ({c['end_value']:.4g}) | "
            f"{c['rounding_floor_relative']:.1e} |")
    lines += ["", "### Cheapest method for a relative error", "",
              "The cheapest dynamic solve whose error is at most the target, beside the static "
              "Newton solve at the scene's tolerance and to the rounding floor (the reference "
              "itself), and the cheapest L-BFGS-B solve reaching the target.", "",
              "| case | target | by wall time | by force evaluations | static Newton "
              "(tolerance / floor) | L-BFGS-B |", "|---|---|---|---|---|---|"]
    for row in summary["cheapest"]:
        static, reference, lbfgs = row["static_newton"], row["static_reference"], row["lbfgs"]
        lbfgs_text = ("none reaches it" if lbfgs is None else
                      f"{_ms(lbfgs['wall_time_s'])}, gtol {lbfgs['tolerance']:.0e} N")
        lines.append(f"| {row['title']} | {row['target']:.0e} | "
                     f"{_cell(row['by_wall_time'], 'wall_time_s')} | "
                     f"{_cell(row['by_force_evaluations'], 'force_evaluations')} | "
                     f"{_ms(static['wall_time_s'])} / {_ms(reference['wall_time_s'])} | "
                     f"{lbfgs_text} |")
    lines += ["", "### One setting for every case", "",
              "The (method, tolerance) of least total wall time among those reaching the target "
              "in every case:", "",
              "| target | method | tolerance | total wall time | total force evaluations | "
              "worst error | static Newton, total |", "|---|---|---|---|---|---|---|"]
    for row in summary["one_setting"]:
        best = row["best"]
        static = _ms(row["static_newton_total_wall_time_s"])
        if best is None:
            lines.append(f"| {row['target']:.0e} | none reaches it in every case | | | | | "
                         f"{static} |")
            continue
        lines.append(f"| {row['target']:.0e} | {best['label']} | {best['tolerance']:.0e} N | "
                     f"{_ms(best['total_wall_time_s'])} | {best['total_force_evaluations']} | "
                     f"{best['worst_relative_error']:.1e} | {static} |")
    lines += ["", "### Notes", ""]
    slower = [row["static_speedup"] for row in summary["cheapest"]
              if row["static_speedup"] is not None]
    if slower:
        lines.append(f"- The static Newton solve at the scene's tolerance is {min(slower):.2g} "
                     f"to {max(slower):.2g} times faster than the cheapest dynamic solve "
                     "reaching the target; the Pareto fronts drawn are those of the dynamic "
                     "methods.")
    lines.append("- End error: " + ("the end force (the reaction P), since the end displacement "
                                    "is prescribed." if any(c["end_quantity"] == "end_force"
                                                            for c in summary["cases"])
                                    else "the end displacement, under force control."))
    lines.append("- Force evaluations: the dynamic solver's count (semi_implicit also assembles "
                 "and factors the banded tangent at each); static Newton: iterations + 1 "
                 "gradients, each with a Hessian and line-search energies; L-BFGS-B: its "
                 "energy-and-gradient evaluations.")
    lines.append(f"- Kernel variants used: {'; '.join(summary['kernel_variants'])}.")
    floor = [p for p in summary["points"] if p["status"] == "rounding_floor"
             and p["solver"] == "dynamic"]
    if floor:
        methods = sorted({p["label"] for p in floor})
        lines.append(f"- {len(floor)} dynamic solves met their tolerance at the rounding floor "
                     f"(the residual stopped falling above it): {'; '.join(methods)}.")
    stalled = [p for p in summary["points"] if p["status"] == "stalled"]
    if stalled:
        lines.append(f"- {len(stalled)} L-BFGS-B solves stopped above their gtol (the energy "
                     "no longer decreases in float64); they are plotted where they stopped.")
    if summary["failures"]:
        lines.append(f"- {len(summary['failures'])} solves failed and are left out:")
        for f in summary["failures"]:
            lines.append(f"  - {f['case']}, {f['method']}, tol {f['tolerance']:.0e} N: "
                         f"{f['message']}")
    outside = [p for p in summary["points"] if p.get("within_bound") is False]
    lines.append(f"- Position error above the bound ||K^-1||_inf (r + r_ref): {len(outside)} of "
                 f"{len(usable_points(summary['points']))} solves.")
    return "\n".join(lines) + "\n"
