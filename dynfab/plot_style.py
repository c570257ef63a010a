"""The look every figure of dynfab shares: resolution, font size, the fabric's family
styles, a new figure, the axes' style (`dynfab.plot` and the reports draw with them)."""

from __future__ import annotations

from matplotlib.figure import Figure

DPI = 200
"""Resolution of the PNGs [dots per inch]."""
FONT_SIZE = 9
"""Font size [pt], readable on a printed page at the figure sizes used."""
FAMILY_STYLE = {"warp": "-", "weft": "--"}
FAMILY_WIDTH = {"warp": 3.0, "weft": 1.2}
"""Line widths [pt] of a fabric's families: wide translucent warp lines under thin dashed weft
lines, so that curves which coincide (a balanced fabric under equal loads) both stay visible."""
FAMILY_ALPHA = {"warp": 0.55, "weft": 1.0}


def new_figure(width: float, height: float) -> Figure:
    """A new figure of the given size [in] with the report font size."""
    fig = Figure(figsize=(width, height), layout="constrained")
    fig.set_dpi(DPI)
    return fig


def style_axes(ax, *, tick_size: float = FONT_SIZE, title_size: float = FONT_SIZE + 1) -> None:
    """Apply the common axis style (font sizes, grid); `tick_size` and `title_size` let a
    report keep its own tick-label and title sizes."""
    ax.tick_params(labelsize=tick_size)
    ax.xaxis.label.set_size(FONT_SIZE)
    ax.yaxis.label.set_size(FONT_SIZE)
    ax.title.set_size(title_size)
    ax.grid(True, alpha=0.3)
