"""Fabric report drawings: biaxial load-strain curves, crimp interchange, the deformed cell.

`draw_figures` writes the report's PNGs from the data dict of
`dynfab.reports.fabric_data` (the numbers ``fabric.json`` holds) alone. Each curve's line
carries a gid "<path> <family>" (e.g. "2:1 warp"), so a test can read back what was drawn.
"""

from __future__ import annotations

from functools import partial
from pathlib import Path

import numpy as np
from matplotlib import colormaps
from matplotlib.cm import ScalarMappable
from matplotlib.colors import Normalize
from matplotlib.figure import Figure
from matplotlib.lines import Line2D
from matplotlib.patches import Rectangle

from dynfab.plots.style import DPI, FAMILY_ALPHA, FAMILY_STYLE, FAMILY_WIDTH, FONT_SIZE, new_figure
from dynfab.plots.style import style_axes as _plot_style
from dynfab.reports.fabric_data import (PATHS, crimp_percent, larger_load, load_per_width,
                                        strain_percent)

FONT = 8.5
"""Tick-label and legend font size [pt]."""
ZOOM_SHARE = 0.15
"""The zoomed panel of the biaxial figure shows loads up to this share of the largest."""

style_axes = partial(_plot_style, tick_size=FONT, title_size=FONT_SIZE)


def draw_figures(out_dir, data: dict) -> list[Path]:
    """Write ``fabric_biaxial.png``, ``fabric_crimp.png`` and ``fabric_cell.png``; their paths."""
    out = Path(out_dir)
    figures = {"fabric_biaxial.png": plot_biaxial(data), "fabric_crimp.png": plot_crimp(data),
               "fabric_cell.png": plot_cell(data)}
    for name, fig in figures.items():
        fig.savefig(out / name, dpi=DPI)
    return [out / name for name in figures]


def path_colors(names=PATHS) -> dict:
    """A colour per path (the report's PATHS, or the steps `dynfab plot` draws)."""
    return {name: colormaps["tab10"](i) for i, name in enumerate(names)}


def _legend_handles(colors: dict, what: str = "direction") -> list:
    """A line per path in its colour, then one per family in its style ("warp <what>")."""
    handles = [Line2D([], [], color=c, label=f"warp:weft = {name}") for name, c in colors.items()]
    handles += [Line2D([], [], color="k", linestyle=style, linewidth=FAMILY_WIDTH[family],
                       alpha=FAMILY_ALPHA[family], label=f"{family} {what}")
                for family, style in FAMILY_STYLE.items()]
    return handles


def _title(fig: Figure, data: dict, what: str) -> None:
    cell = data["cell"]
    fig.suptitle(f"{what}\nperiodic {cell['warps']} x {cell['wefts']} cell of the paper's yarns "
                 f"(balanced), {cell['segments']} segments per yarn,\nforce control, no friction",
                 fontsize=9)


def plot_biaxial(data: dict) -> Figure:
    """Load per unit width against strain, warp and weft directions, every path; the right
    panel zooms on the low loads, where the crimp interchanges."""
    fig = new_figure(8.0, 3.8)
    full, zoom = fig.subplots(1, 2)
    colors = path_colors()
    largest = 0.0
    for name, path in data["paths"].items():
        for family, style in FAMILY_STYLE.items():
            q, e = load_per_width(path, family), strain_percent(path, family)
            largest = max(largest, q.max())
            for ax in (full, zoom):
                ax.plot(e, q, style, color=colors[name], linewidth=FAMILY_WIDTH[family],
                        alpha=FAMILY_ALPHA[family], marker=".", markersize=3,
                        gid=f"{name} {family}")
    for ax in (full, zoom):
        ax.axvline(0.0, color="0.6", linewidth=0.6)
        ax.set_xlabel("strain [%]")
        ax.set_ylabel("load per unit width [N/m]")
        style_axes(ax)
    full.set_title("whole path")
    zoom.set_title(f"loads below {ZOOM_SHARE:.0%} of the largest")
    zoom.set_ylim(0.0, ZOOM_SHARE * largest)
    low = [e for path in data["paths"].values() for family in FAMILY_STYLE
           for e, q in zip(strain_percent(path, family), load_per_width(path, family))
           if q <= ZOOM_SHARE * largest]
    span = max(low) - min(low)
    zoom.set_xlim(min(low) - 0.05 * span, max(low) + 0.05 * span)
    full.legend(handles=_legend_handles(colors), fontsize=FONT - 1.5, loc="lower right")
    _title(fig, data, "Biaxial tension (Kawabata, Niwa and Kawai 1973's presentation; "
                      "mirror paths' curves coincide)")
    return fig


def plot_crimp(data: dict) -> Figure:
    """Mean crimp of both families against the path's larger load per unit width."""
    fig = new_figure(7.0, 4.2)
    ax = fig.subplots()
    colors = path_colors()
    for name, path in data["paths"].items():
        for family, style in FAMILY_STYLE.items():
            ax.plot(larger_load(path), crimp_percent(path, family), style, color=colors[name],
                    linewidth=FAMILY_WIDTH[family], alpha=FAMILY_ALPHA[family], marker=".",
                    markersize=3, gid=f"{name} {family}")
    ax.set_xlabel("larger of the two loads per unit width [N/m]")
    ax.set_ylabel("mean crimp [%]")
    style_axes(ax)
    ax.legend(handles=_legend_handles(colors, "crimp"), fontsize=FONT - 1.5)
    _title(fig, data, "Crimp interchange")
    return fig


def plot_cell(data: dict, heading: str | None = None) -> Figure:
    """Side views of one warp and one weft (`data["shown"]`, default warp 1 and weft 1) at
    the last step of every path over their as-woven shapes (z exaggerated), and a top view
    of each path's last step, crossings coloured by contact force (the upper yarn drawn over
    the crossing). `heading`: the figure's title (default: the report's cell, `_title`);
    `dynfab plot` draws a result file's steps as the paths
    (`dynfab.plots.figures.plot_fabric_shape`), each with its curves' `label`."""
    paths = data["paths"]
    fig = new_figure(8.0, 7.2)
    grid = fig.add_gridspec(3, len(paths))
    colors = path_colors(paths)
    shown = data.get("shown", {"warp": "warp 1", "weft": "weft 1"})
    for row, family in enumerate(("warp", "weft")):
        ax = fig.add_subplot(grid[row, :])
        woven = 1e3 * np.asarray(data["as_woven"][family])
        ax.plot(woven[:, 0], woven[:, 1], ":", color="k", label="as woven")
        for name, path in paths.items():
            nodes = 1e3 * np.asarray(path["last"][family])
            ax.plot(nodes[:, 0], nodes[:, 1], color=colors[name], marker=".", markersize=2,
                    label=path.get("label", f"{name}, last step"),
                    gid=f"{name} {family} shape")
        along = "x" if family == "warp" else "y"
        ax.set_xlabel(f"{along} [mm]")
        ax.set_ylabel("z [mm]")
        ax.set_title(f"side view of {shown[family]} (z exaggerated)")
        style_axes(ax)
        # the as-woven crest's quarter away from the curves: below on the warp, above on the weft
        ax.legend(fontsize=FONT - 2, ncols=2,
                  loc="lower left" if family == "warp" else "upper left")
    limit = max(np.max(p["contact_force_N"][-1]) for p in paths.values())
    norm = Normalize(0.0, limit)
    for column, (name, path) in enumerate(paths.items()):
        ax = fig.add_subplot(grid[2, column])
        _top_view(ax, path, norm)
        ax.set_title(f"top view, {name}", fontsize=FONT)
    fig.colorbar(ScalarMappable(norm=norm, cmap=colormaps["viridis"]), ax=fig.axes[-len(paths):],
                 label="contact force [N]", shrink=0.9)
    if heading is None:
        _title(fig, data, "The deformed cell at the last load step")
    else:
        fig.suptitle(heading, fontsize=9)
    return fig


def _top_view(ax, path: dict, norm) -> None:
    """The cell in plan [mm]: warps along x at Y_k, wefts along y at X_j (the planes moving
    with the cell, docs/model.md section 10, or where `path["last"]["planes_m"]` = (X_j, Y_k)
    puts them), grey bands; each crossing's upper yarn drawn over it in the colour of its
    contact force."""
    length_x, length_y = (1e3 * c for c in path["last"]["cell_m"])
    forces = np.asarray(path["contact_force_N"][-1])
    above = np.asarray(path["last"]["warp_above"])
    warps, wefts = forces.shape
    band = 0.5 * min(length_x / wefts, length_y / warps)
    plane_y = (np.arange(warps) + 0.5) * length_y / warps
    plane_x = (np.arange(wefts) + 0.5) * length_x / wefts
    if "planes_m" in path["last"]:
        plane_x, plane_y = (1e3 * np.asarray(p) for p in path["last"]["planes_m"])
    for y in plane_y:
        ax.add_patch(Rectangle((0.0, y - band / 2), length_x, band, color="0.8"))
    for x in plane_x:
        ax.add_patch(Rectangle((x - band / 2, 0.0), band, length_y, color="0.6"))
    cmap = colormaps["viridis"]
    for k, y in enumerate(plane_y):
        for j, x in enumerate(plane_x):
            # the upper yarn's piece: longer along that yarn than across it
            w, h = (1.4 * band, band) if above[k][j] else (band, 1.4 * band)
            ax.add_patch(Rectangle((x - w / 2, y - h / 2), w, h, facecolor=cmap(norm(forces[k, j])),
                                   edgecolor="k", linewidth=0.5, gid=f"crossing {k} {j}"))
    ax.set_xlim(0.0, length_x)
    ax.set_ylim(0.0, length_y)
    ax.set_aspect("equal")
    ax.set_xlabel("x [mm]", fontsize=FONT)
    ax.set_ylabel("y [mm]", fontsize=FONT)
    ax.tick_params(labelsize=FONT - 1)
