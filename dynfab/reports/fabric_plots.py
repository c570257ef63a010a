"""Fabric report drawings: biaxial load-strain curves, crimp interchange, the deformed cell
(`dynfab.plots.cell`, which `dynfab plot` draws with too).

`draw_figures` writes the report's PNGs from the data dict of
`dynfab.reports.fabric_data` (the numbers ``fabric.json`` holds) alone. Each curve's line
carries a gid "<path> <family>" (e.g. "2:1 warp"), so a test can read back what was drawn.
"""

from __future__ import annotations

from pathlib import Path

from matplotlib.figure import Figure
from matplotlib.lines import Line2D

from dynfab.plots import cell
from dynfab.plots.cell import FONT, style_axes
from dynfab.plots.style import DPI, FAMILY_ALPHA, FAMILY_STYLE, FAMILY_WIDTH, new_figure
from dynfab.reports.fabric_data import (PATHS, crimp_percent, larger_load, load_per_width,
                                        strain_percent)

ZOOM_SHARE = 0.15
"""The zoomed panel of the biaxial figure shows loads up to this share of the largest."""


def draw_figures(out_dir, data: dict) -> list[Path]:
    """Write ``fabric_biaxial.png``, ``fabric_crimp.png`` and ``fabric_cell.png``; their paths."""
    out = Path(out_dir)
    figures = {"fabric_biaxial.png": plot_biaxial(data), "fabric_crimp.png": plot_crimp(data),
               "fabric_cell.png": cell.plot_cell(
                   data, _heading(data, "The deformed cell at the last load step"))}
    for name, fig in figures.items():
        fig.savefig(out / name, dpi=DPI)
    return [out / name for name in figures]


def path_colors(names=PATHS) -> dict:
    """A colour per path (the report's PATHS, `dynfab.plots.cell.path_colors`)."""
    return cell.path_colors(names)


def _legend_handles(colors: dict, what: str = "direction") -> list:
    """A line per path in its colour, then one per family in its style ("warp <what>")."""
    handles = [Line2D([], [], color=c, label=f"warp:weft = {name}") for name, c in colors.items()]
    handles += [Line2D([], [], color="k", linestyle=style, linewidth=FAMILY_WIDTH[family],
                       alpha=FAMILY_ALPHA[family], label=f"{family} {what}")
                for family, style in FAMILY_STYLE.items()]
    return handles


def _heading(data: dict, what: str) -> str:
    """A report figure's title: `what` and the report's cell."""
    size = data["cell"]
    return (f"{what}\nperiodic {size['warps']} x {size['wefts']} cell of the paper's yarns "
            f"(balanced), {size['segments']} segments per yarn,\nforce control, no friction")


def _title(fig: Figure, data: dict, what: str) -> None:
    fig.suptitle(_heading(data, what), fontsize=9)


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
