"""The look and the writing of every figure of dynfab: resolution, font size, the fabric's
family styles, a new figure, the axes' style, a legend; the --out folder checked and the PNG
written, each a one-line UserError when it cannot be (`dynfab.plots.figures`, the reports and the
study's figures draw with them)."""

from __future__ import annotations

import os
from pathlib import Path

from matplotlib.figure import Figure

from dynfab.errors import UserError

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


def legend(ax, **kwargs) -> None:
    """A legend in the report font size, if anything is labelled."""
    if ax.get_legend_handles_labels()[0] or kwargs.get("handles"):
        kwargs.setdefault("loc", "best")
        ax.legend(fontsize=FONT_SIZE - 2, **kwargs)


def output_folder(out_dir: str | os.PathLike | None) -> Path:
    """`out_dir` as an existing, writable folder (created if needed); UserError (one line)
    if it cannot be. The one check of every command's --out folder (plots and reports)."""
    if out_dir is None or str(out_dir) == "":
        raise UserError("--out: give a folder for the files")
    out = Path(out_dir)
    if out.exists() and not out.is_dir():
        raise UserError(f"--out '{out}' is a file, not a folder")
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as error:
        raise UserError(f"cannot create the folder '{out}': {error.strerror or error}") from None
    if not os.access(out, os.W_OK):
        raise UserError(f"cannot write into the folder '{out}'")
    return out


def save_png(fig: Figure, path: Path) -> Path:
    """Save ``fig`` as a PNG at ``path`` and return the path; UserError if it cannot be written."""
    try:
        fig.savefig(path, dpi=DPI)
    except OSError as error:
        raise UserError(f"cannot write '{path}': {error.strerror or error}") from None
    return path
