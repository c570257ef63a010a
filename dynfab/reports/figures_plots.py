"""Figures report drawings: the paper's Fig. 3a, 3b and 5, the shapes and the friction states.

`draw_figures` writes the report's PNGs from its four result files alone (read with
`dynfab.reports.figures_data.read_figure_data`), static solutions as lines and dynamic ones as
markers.
"""

from __future__ import annotations

import math
from functools import partial
from pathlib import Path

import numpy as np
from matplotlib import colormaps
from matplotlib.colors import BoundaryNorm, ListedColormap
from matplotlib.figure import Figure
from matplotlib.lines import Line2D
from matplotlib.patches import Patch

from dynfab.results.friction_states import FRICTION_STATES
from dynfab.plots.style import DPI, FONT_SIZE, new_figure
from dynfab.plots.style import style_axes as _plot_style
from dynfab.reports.figures_data import (STRAIN_STAGE, force_per_width, friction_gap,
                                         friction_split, k_order, kawabata_K, length,
                                         mean_contact_force, read_figure_data, scene_of,
                                         solver_pair, state_codes, strain_percent, width)
from dynfab.results.file import Results

FONT = 8.5
"""Smallest font size [pt] of the report's figures (legends, ticks); labels are 9 pt."""


def draw_figures(out_dir, data=None) -> list[Path]:
    """Write the report's PNGs into `out_dir` from its four result files; their paths."""
    out = Path(out_dir)
    data = read_figure_data(out) if data is None else data
    figures = {"fig3a_traction.png": plot_fig3a(data), "fig3b_contact_force.png": plot_fig3b(data),
               "fig5_friction.png": plot_fig5(data), "shapes.png": plot_shapes(data),
               "friction_states.png": plot_friction_states(data)}
    for name, fig in figures.items():
        fig.savefig(out / name, dpi=DPI)
    return [out / name for name in figures]


# dynfab.plots.figures's axis style with this report's tick labels (FONT) and titles (9 pt)
style_axes = partial(_plot_style, tick_size=FONT, title_size=FONT_SIZE)


def _title(fig: Figure, results: Results, what: str) -> None:
    """Suptitle: what is shown, the reference state, and the scene's size."""
    scene = scene_of(results)
    reference = results.attrs.get("reference_state", scene.geometry.reference)
    fig.suptitle(f"{what}\nreference state: {reference}; {scene.geometry.crossings} crossings, "
                 f"N = {scene.geometry.segments}, L = {1e3 * scene.geometry.length:g} mm",
                 fontsize=9)


def _solver_handles() -> list:
    return [Line2D([], [], color="k", ls="-", label="static (Newton)"),
            Line2D([], [], color="k", ls="", marker="o", mfc="none", ms=4,
                   label="dynamic (relaxation)")]


def _overlay(ax, x_static, y_static, x_dynamic, y_dynamic, color, label, marker="o"):
    """Static as a line, dynamic as hollow markers of the same colour."""
    ax.plot(x_static, y_static, "-", color=color, lw=1.3, label=label)
    every = max(1, len(x_dynamic) // 20)
    ax.plot(x_dynamic, y_dynamic, ls="", marker=marker, mfc="none", mec=color, ms=4, mew=0.9,
            markevery=every)


def _k_colors(count: int) -> list:
    return [colormaps["viridis"](v) for v in np.linspace(0.0, 0.8, count)]


def plot_fig3a(data) -> Figure:
    """Fig. 3a: force per unit width [N/m] against strain [%] for each K (left), and each
    curve minus the K = 0.2 m/N one (right), where the small K effect is visible."""
    static, dynamic = solver_pair(data, "fig3")
    order = k_order(static)
    K = kawabata_K(static)
    middle = order[len(order) // 2]
    fig = new_figure(7.0, 3.2)
    left, right = fig.subplots(1, 2)
    colors = _k_colors(len(order))
    es, ed = strain_percent(static), strain_percent(dynamic)
    qs, qd = force_per_width(static), force_per_width(dynamic)
    for color, k in zip(colors, order):
        label = f"K = {K[k]:g} m/N"
        _overlay(left, es[:, k], qs[:, k], ed[:, k], qd[:, k], color, label)
        _overlay(right, es[:, k], qs[:, k] - qs[:, middle], ed[:, k], qd[:, k] - qd[:, middle],
                 color, label)
    left.set(xlabel="strain (%)", ylabel="force per unit width (N/m)",
             title="(a) traction curve")
    right.set(xlabel="strain (%)", ylabel=f"difference from K = {K[middle]:g} m/N (N/m)",
              title="(a') the K effect")
    for ax in (left, right):
        style_axes(ax)
    handles = left.get_legend_handles_labels()[0] + _solver_handles()
    fig.legend(handles=handles, fontsize=FONT, loc="outside lower center", ncol=len(handles),
               frameon=False, handletextpad=0.4, columnspacing=1.2)
    _title(fig, static, "Fig. 3a: uniaxial traction, Kawabata K swept on warp and weft")
    return fig


def plot_fig3b(data) -> Figure:
    """Fig. 3b: contact force (mean over the crossings) against end displacement, each K."""
    static, dynamic = solver_pair(data, "fig3")
    order, K = k_order(static), kawabata_K(static)
    fig = new_figure(3.5, 3.9)
    ax = fig.subplots()
    us, ud = 1e3 * static.steps["end_displacement"], 1e3 * dynamic.steps["end_displacement"]
    Rs, Rd = mean_contact_force(static), mean_contact_force(dynamic)
    for color, k in zip(_k_colors(len(order)), order):
        _overlay(ax, us[:, k], 1e3 * Rs[:, k], ud[:, k], 1e3 * Rd[:, k], color, f"K = {K[k]:g} m/N")
    ax.set(xlabel="extension: end displacement (mm)",
           ylabel="contact force R (mN)\n(mean over the crossings)")
    style_axes(ax)
    ax.legend(handles=ax.get_legend_handles_labels()[0] + _solver_handles(), fontsize=FONT,
              loc="upper center", bbox_to_anchor=(0.5, -0.2), ncol=2, frameon=False,
              columnspacing=1.0, handletextpad=0.4)
    scene = scene_of(static)
    fig.suptitle(f"Fig. 3b: contact force at the crossings\nreference state: "
                 f"{static.attrs.get('reference_state')}; {scene.geometry.crossings} crossings",
                 fontsize=9)
    return fig


def plot_fig5(data) -> Figure:
    """Fig. 5: traction with and without friction (left); the gap between them (right),
    with the stick-slip stage shaded, the paper's 5 mm (5 % strain) and half the summed
    friction limits."""
    static, dynamic = solver_pair(data, "fig5")
    on, off = friction_split(static)
    fig = new_figure(7.0, 3.0)
    left, right = fig.subplots(1, 2)
    es, ed = strain_percent(static), strain_percent(dynamic)
    qs, qd = force_per_width(static), force_per_width(dynamic)
    for k, color, label in ((on, "C3", "with friction (Gralen)"), (off, "C0", "without friction")):
        _overlay(left, es[:, k], qs[:, k], ed[:, k], qd[:, k], color, label)
    _overlay(right, es[:, on], friction_gap(static), ed[:, on], friction_gap(dynamic), "C3",
             "with - without friction")
    half = 0.5 * static.steps["friction_limit"][:, on].sum(axis=1) / width(static)
    right.plot(es[:, on], half, ":", color="k", lw=1.2, label="½ Σ F_T per unit width")
    codes = state_codes(static, on)
    sticking = np.flatnonzero((codes == 1).any(axis=1))
    if sticking.size:
        right.axvspan(0, es[sticking[-1], on], color="0.85", zorder=0,
                      label="some crossings stick")
    right.axvline(100 * STRAIN_STAGE, color="0.4", ls="--", lw=1)
    right.text(100 * STRAIN_STAGE, 0.45, " paper: first stage\n ends at 5 mm (5 %)",
               fontsize=FONT, transform=right.get_xaxis_transform(), va="bottom")
    right.set_ylim(0, 1.15 * max(friction_gap(static).max(), half.max()))
    left.set(xlabel="strain (%)", ylabel="force per unit width (N/m)", title="(a) traction curve")
    right.set(xlabel="strain (%)", ylabel="gap in force per unit width (N/m)",
              title="(b) the friction gap")
    for ax in (left, right):
        style_axes(ax)
    left.legend(handles=left.get_legend_handles_labels()[0] + _solver_handles(), fontsize=FONT,
                loc="upper left")
    right.legend(fontsize=FONT, loc="lower right")
    _title(fig, static, "Fig. 5: uniaxial traction with and without yarn-yarn friction "
                        f"(K = {kawabata_K(static)[on]:g} m/N)")
    return fig


def shape_steps(results: Results, yarn: int = 0) -> list[int]:
    """Steps nearest a quarter, half and all of the final end displacement, and the step
    with the most sticking crossings if some stick (no repeats)."""
    u = results.steps["end_displacement"][:, yarn]
    steps = {int(np.argmin(np.abs(u - f * u[-1]))) for f in (0.25, 0.5, 1.0)}
    sticking = (state_codes(results, yarn) == 1).sum(axis=1)
    if sticking.max() > 0:
        steps.add(int(np.argmax(sticking)))
    return sorted(steps)


SNAPSHOT_HEIGHT = 0.62
"""Height [in] per snapshot in `plot_shapes`: sets the z exaggeration."""

STATE_MARKERS = {1: dict(color="C0", mfc="C0"), 2: dict(color="C3", mfc="white"),
                 0: dict(color="0.5", mfc="0.5")}
"""Crossing markers of `plot_shapes` by state code (`dynfab.results.friction_states` order)."""


def plot_shapes(data) -> Figure:
    """The friction yarn of Fig. 5 at its as-woven start (in a prestressed scene not an
    equilibrium: the first load step relaxes it) and at three loads, one above the other,
    z exaggerated (about `SNAPSHOT_HEIGHT` inches a snapshot); crossings marked by state
    (static), dynamic crossings as crosses."""
    static, dynamic = solver_pair(data, "fig5")
    on, _ = friction_split(static)
    nodes = np.asarray(static.reference["crossing_nodes"], int)
    amplitude = 1e3 * scene_of(static).geometry.amplitude  # mm
    spacing = 3.2 * amplitude  # mm between the snapshots' axes
    snapshots = [(None, np.asarray(static.reference["positions"])[on], None)]
    snapshots += [(i, static.steps["positions"][i, on], dynamic.steps["positions"][i, on])
                  for i in shape_steps(static, on)]
    codes = state_codes(static, on)
    L = 1e3 * length(static)
    u_max = 1e3 * static.steps["end_displacement"][-1, on]
    xlim = (-0.02 * L, L + u_max + 0.16 * L)
    ylim = (-(len(snapshots) - 1) * spacing - 1.6 * amplitude, 1.6 * amplitude)
    axes_width = 6.1  # in: 7 in less the tick labels
    exaggeration = _round_1(SNAPSHOT_HEIGHT * len(snapshots) * (xlim[1] - xlim[0])
                            / (axes_width * (ylim[1] - ylim[0])))
    axes_height = (ylim[1] - ylim[0]) * exaggeration * axes_width / (xlim[1] - xlim[0])
    fig = new_figure(7.0, axes_height + 1.25)
    ax = fig.subplots()
    offsets, labels, shown = [], [], set()
    for n, (step, xz, xz_dynamic) in enumerate(snapshots):
        offset = -n * spacing
        xz = 1e3 * np.asarray(xz)
        ax.axhline(offset, color="0.85", lw=0.6, zorder=0)
        ax.plot(xz[:, 0], xz[:, 1] + offset, "-", color="k", lw=1.0)
        if step is None:
            ax.plot(xz[nodes, 0], xz[nodes, 1] + offset, "o", color="k", ms=3.5, ls="")
        else:
            for code, style in STATE_MARKERS.items():
                pick = nodes[codes[step] == code]
                if pick.size:
                    shown.add(code)
                    ax.plot(xz[pick, 0], xz[pick, 1] + offset, "o", ms=4, mew=1.2, ls="",
                            **style)
        if xz_dynamic is not None:
            xzd = 1e3 * np.asarray(xz_dynamic)
            ax.plot(xzd[nodes, 0], xzd[nodes, 1] + offset, "+", color="k", ms=5, mew=0.8)
        offsets.append(offset)
        labels.append("u = 0: as-woven\nstart (not in\nequilibrium)" if step is None else
                      f"u = {1e3 * static.steps['end_displacement'][step, on]:.3g} mm")
    ax.set_yticks(offsets, labels)
    ax.set_xlim(*xlim)
    ax.set_ylim(*ylim)
    ax.set_aspect(exaggeration)
    ax.set_xlabel("x (mm)", fontsize=9)
    ax.tick_params(labelsize=FONT)
    ax.tick_params(axis="y", length=0)
    bar_x = L + u_max + 0.05 * L
    ax.plot([bar_x, bar_x], [-amplitude, amplitude], "k-", lw=2)
    ax.text(bar_x + 0.01 * L, 0.0, f"{2 * amplitude:g} mm\nin z", fontsize=FONT, va="center")
    names = {1: "crossing sticking", 2: "crossing sliding", 0: "crossing open"}
    handles = [Line2D([], [], color="k", lw=1, label="yarn (static)"),
               Line2D([], [], ls="", marker="o", color="k", ms=3.5, label="crossing as woven")]
    handles += [Line2D([], [], ls="", marker="o", ms=4, mew=1.2, label=names[code],
                       **STATE_MARKERS[code]) for code in (1, 2, 0) if code in shown]
    handles.append(Line2D([], [], ls="", marker="+", color="k", ms=5, label="crossing, dynamic"))
    fig.legend(handles=handles, fontsize=FONT, loc="outside lower center", ncol=len(handles),
               frameon=False, handletextpad=0.3, columnspacing=1.0)
    _title(fig, static, f"Shape of the friction yarn of Fig. 5 along the path; z exaggerated "
                        f"{exaggeration:g}x, snapshots offset in z")
    return fig


def _round_1(value: float) -> float:
    """`value` rounded to one significant digit."""
    power = 10 ** math.floor(math.log10(value))
    return round(value / power) * power


def plot_friction_states(data) -> Figure:
    """Open / sticking / sliding state of each crossing of Fig. 5's friction yarn at each
    load step against end displacement: the whole path (static, left) and a zoom on the
    first steps (right), where each cell's dot is the dynamic solver's state."""
    static, dynamic = solver_pair(data, "fig5")
    on, _ = friction_split(static)
    codes, dynamic_codes = state_codes(static, on), state_codes(dynamic, on)
    mismatches = int((codes != dynamic_codes).sum())
    u = 1e3 * static.steps["end_displacement"][:, on]
    du = u[0]
    crossings = codes.shape[1]
    fig = new_figure(7.0, 3.0)
    whole, zoom = fig.subplots(1, 2, sharey=True, width_ratios=(1.0, 1.0))
    cmap = ListedColormap([color for _, color in FRICTION_STATES])
    norm = BoundaryNorm(np.arange(len(FRICTION_STATES) + 1) - 0.5, cmap.N)
    for ax, alpha in ((whole, 1.0), (zoom, 0.35)):  # pale cells under the zoom's dots
        ax.imshow(codes.T, cmap=cmap, norm=norm, origin="lower", aspect="auto",
                  interpolation="nearest", alpha=alpha,
                  extent=(u[0] - du / 2, u[-1] + du / 2, 0.5, crossings + 0.5))
        style_axes(ax)
        ax.grid(False)
        ax.set_xlabel("end displacement (mm)")
    settled = np.flatnonzero((codes == 2).all(axis=1))
    last = min(codes.shape[0], (settled[0] if settled.size else codes.shape[0]) + 3)
    zoom.set_xlim(u[0] - du / 2, u[last - 1] + du / 2)
    steps, rows = np.meshgrid(np.arange(last), np.arange(crossings), indexing="ij")
    zoom.scatter(u[steps.ravel()], rows.ravel() + 1, c=dynamic_codes[:last].ravel(), cmap=cmap,
                 norm=norm, s=22, edgecolors="k", linewidths=0.8, zorder=3)
    whole.set_title("static, whole path", fontsize=9)
    zoom.set_title(f"first {last} steps: static cells pale, dynamic dots", fontsize=9)
    whole.set_ylabel("crossing (1 = fixed end)")
    whole.yaxis.get_major_locator().set_params(integer=True)
    handles = [Patch(facecolor=color, edgecolor="k", label=name) for name, color in FRICTION_STATES]
    handles.append(Line2D([], [], ls="", marker="o", mfc="w", mec="k", ms=4,
                          label="dynamic: dot in\nits state's full\ncolour"))
    zoom.legend(handles=handles, fontsize=FONT, loc="upper left", bbox_to_anchor=(1.02, 1.0),
                borderaxespad=0)
    agreement = ("static and dynamic agree at every crossing and step" if mismatches == 0 else
                 f"static and dynamic differ at {mismatches} crossing-steps")
    _title(fig, static, f"Friction state along the friction yarn of Fig. 5 ({agreement})")
    return fig
