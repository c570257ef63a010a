"""Precision report figures: the work-precision and error-against-residual panels.

Drawn from the summary `dynfab.reports.precision.run_precision` builds (matplotlib Figure +
Agg, as dynfab.plots.figures), one panel per case: ``work_precision_time.png``,
``work_precision_evaluations.png`` and ``error_vs_residual.png``.
"""

from __future__ import annotations

import numpy as np
from matplotlib.figure import Figure
from matplotlib.lines import Line2D
from matplotlib.ticker import NullFormatter

from dynfab.plots.style import FONT_SIZE, new_figure, style_axes
from dynfab.reports.precision_points import (METHODS, method_label, pareto_front,
                                             shown_error, usable_points)

STATIC_STYLES = {"static_reference": ("k", "*", ""), "static_newton": ("k", "X", "")}
LBFGS_STYLE = ("0.35", "P", ":")


def _panels(cases: list[dict]):
    """A figure with one panel per case: scenes in rows, steps in columns."""
    scenes = list(dict.fromkeys(c["scene"] for c in cases))
    columns = max(sum(c["scene"] == s for c in cases) for s in scenes)
    fig = new_figure(3.3 * columns + 3.2, 2.9 * len(scenes) + 0.6)
    axes = fig.subplots(len(scenes), columns, squeeze=False)
    where = {}
    for row, scene in enumerate(scenes):
        mine = [c for c in cases if c["scene"] == scene]
        for column, case in enumerate(mine):
            where[case["case"]] = axes[row, column]
        for column in range(len(mine), columns):
            axes[row, column].set_axis_off()
    return fig, axes, where


def _case_panels(summary: dict):
    """The figure of `_panels` and, per case, (case, its axes, its points, its rounding floor)."""
    cases = summary["cases"]
    fig, _, where = _panels(cases)
    return fig, [(case, where[case["case"]],
                  [p for p in summary["points"] if p["case"] == case["case"]],
                  case["rounding_floor_relative"]) for case in cases]


def _finish_panel(ax, case: dict, floor: float, xlabel: str) -> None:
    """A case's panel after its curves: the rounding-floor band, log axes, title, labels, style."""
    ax.axhspan(floor / 10, floor, color="0.88", zorder=0)
    _log_axes(ax, floor)
    ax.set_title(case["title"], fontsize=FONT_SIZE)
    ax.set(xlabel=xlabel, ylabel=f"relative error (max |x - x_ref| / {case['scale_name']})")
    style_axes(ax, tick_size=FONT_SIZE - 1, title_size=FONT_SIZE)


def _curves(points: list[dict]) -> dict[str, list[dict]]:
    """Points by method, in legend order, each sorted by tolerance (loosest first)."""
    order = [*STATIC_STYLES, *METHODS, "lbfgs"]
    groups: dict[str, list[dict]] = {}
    for p in usable_points(points):
        groups.setdefault(p["method"], []).append(p)
    return {key: sorted(groups[key], key=lambda p: -p["tolerance"]) for key in order
            if key in groups}


def _style_of(key: str):
    """(colour, marker, line style) of a method: a static solve's, L-BFGS-B's or METHODS'."""
    if key in STATIC_STYLES:
        return STATIC_STYLES[key]
    if key == "lbfgs":
        return LBFGS_STYLE
    return METHODS[key].style


def _method_handles(keys, lines: bool) -> list:
    """Legend entries of the methods `keys`: markers, and their line styles if `lines`."""
    handles = []
    for k in keys:
        color, marker, line = _style_of(k)
        handles.append(Line2D([], [], color=color, marker=marker,
                              ls=(line or "none") if lines else "none",
                              ms=8 if k in STATIC_STYLES else 4,
                              mfc="white" if k == "lbfgs" else color, label=method_label(k)))
    return handles


def plot_work_precision(summary: dict, cost: str) -> Figure:
    """Relative error against `cost` (wall time or force evaluations), one panel per case."""
    fig, panels = _case_panels(summary)
    used = {}
    for case, ax, points, floor in panels:
        for key, curve in _curves(points).items():
            colour, marker, line = _style_of(key)
            x = [p[cost] for p in curve]
            y = [shown_error(p, floor) for p in curve]
            size = {"static_reference": 11, "static_newton": 8}.get(key, 4)
            ax.plot(x, y, color=colour, marker=marker, ls=line or "none", ms=size, lw=1.1,
                    mfc="white" if key == "lbfgs" else colour, zorder=3)
            used[key] = True
        front = pareto_front(points, cost, floor)
        fx = [p[cost] for p in front]
        fy = [shown_error(p, floor) for p in front]
        if fx:
            ax.plot(fx, fy, drawstyle="steps-post", color="#ffd92f", lw=5, alpha=0.8, zorder=1)
            ax.plot(fx, fy, ls="none", marker="o", ms=9, mfc="none", mec="#b8860b", mew=1.2,
                    zorder=4)
        for target in summary["targets"]:
            ax.axhline(target, color="0.5", lw=0.7, ls=(0, (4, 3)), zorder=0)
        _finish_panel(ax, case, floor, "warm wall time (s)" if cost == "wall_time_s" else
                      "force evaluations (-)")
    handles = _method_handles(used, lines=True)
    handles += [Line2D([], [], color="#ffd92f", lw=5, alpha=0.8, marker="o", ms=9, mfc="none",
                       mec="#b8860b", label="Pareto front of\nthe dynamic methods"),
                Line2D([], [], color="0.5", lw=0.7, ls=(0, (4, 3)),
                       label="targets 1e-3, 1e-5, 1e-7"),
                Line2D([], [], color="0.88", lw=6, label="below the position\nrounding floor")]
    fig.legend(handles=handles, loc="outside right upper", fontsize=FONT_SIZE - 2)
    what = "warm wall time" if cost == "wall_time_s" else "force evaluations"
    fig.suptitle(f"Work-precision: error of one relaxed load step against {what} "
                 f"(tolerances {_tolerance_span(summary)})", fontsize=FONT_SIZE + 1)
    return fig


def _log_axes(ax, floor: float) -> None:
    """Log-log axes, minor ticks unlabelled, the error axis from just below the floor."""
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.xaxis.set_minor_formatter(NullFormatter())
    ax.yaxis.set_minor_formatter(NullFormatter())
    ax.set_ylim(floor / 3, None)


def _tolerance_span(summary: dict) -> str:
    tolerances = summary["plan"]["tolerances_N"] + summary["plan"]["float32_tolerances_N"]
    return f"{max(tolerances):.0e} to {min(tolerances):.0e} N"


def plot_error_vs_residual(summary: dict) -> Figure:
    """Relative error against the float64 residual, with the bound ||K^-1||_inf (r + r_ref)."""
    fig, panels = _case_panels(summary)
    used = {}
    for case, ax, points, floor in panels:
        residuals = []
        for key, curve in _curves(points).items():
            colour, marker, _ = _style_of(key)
            x = [p["residual_N"] for p in curve]
            residuals += x
            ax.plot(x, [shown_error(p, floor) for p in curve], color=colour, marker=marker,
                    ls="none", ms=9 if key in STATIC_STYLES else 4,
                    mfc="white" if key == "lbfgs" else colour, zorder=3)
            used[key] = True
        norm = case["inverse_stiffness_norm_m_per_N"]
        if norm is not None and residuals:
            r = np.geomspace(max(min(residuals), 1e-16), max(residuals) * 2, 50)
            ax.plot(r, norm * (r + case["reference_residual_N"]) / case["scale_m"], color="k",
                    lw=1.0, ls="--", zorder=2)
        _finish_panel(ax, case, floor, "force residual, float64 (N)")
    handles = _method_handles(used, lines=False)
    handles += [Line2D([], [], color="k", lw=1.0, ls="--",
                       label="bound ||K^-1||_inf (r + r_ref),\nrelative"),
                Line2D([], [], color="0.88", lw=6, label="below the position\nrounding floor")]
    fig.legend(handles=handles, loc="outside right upper", fontsize=FONT_SIZE - 2)
    fig.suptitle("Position error left by a force residual: every solve, with its bound",
                 fontsize=FONT_SIZE + 1)
    return fig
