"""The deformed fabric cell (or patch) drawn from a data dict of paths: side views of one warp
and one weft over their as-woven shapes and a top view per path, crossings coloured by their
contact force. The `dynfab fabric` report (`dynfab.reports.fabric_plots`) and `dynfab plot`
(`dynfab.plots.figures.plot_fabric_shape`) both draw with it."""

from __future__ import annotations

from functools import partial

import numpy as np
from matplotlib import colormaps
from matplotlib.cm import ScalarMappable
from matplotlib.colors import Normalize
from matplotlib.figure import Figure
from matplotlib.patches import Rectangle

from dynfab.plots.style import FONT_SIZE, new_figure
from dynfab.plots.style import style_axes as _plot_style

FONT = 8.5
"""Tick-label and legend font size [pt] of the cell's and the fabric report's figures."""

style_axes = partial(_plot_style, tick_size=FONT, title_size=FONT_SIZE)


def path_colors(names) -> dict:
    """A colour per path (a report's paths, or the steps `dynfab plot` draws)."""
    return {name: colormaps["tab10"](i) for i, name in enumerate(names)}


def plot_cell(data: dict, heading: str) -> Figure:
    """Side views of one warp and one weft (`data["shown"]`, default warp 1 and weft 1) at
    the last step of every path over their as-woven shapes (z exaggerated), and a top view
    of each path's last step, crossings coloured by contact force (the upper yarn drawn over
    the crossing). `heading`: the figure's title. The `dynfab fabric` report draws its paths
    (`dynfab.reports.fabric_plots`), `dynfab plot` a result file's steps as the paths
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
        top_view(ax, path, norm)
        ax.set_title(f"top view, {name}", fontsize=FONT)
    fig.colorbar(ScalarMappable(norm=norm, cmap=colormaps["viridis"]), ax=fig.axes[-len(paths):],
                 label="contact force [N]", shrink=0.9)
    fig.suptitle(heading, fontsize=9)
    return fig


def top_view(ax, path: dict, norm) -> None:
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
