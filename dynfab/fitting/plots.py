"""Figures of a fit (`dynfab fit`): the data against the fitted curve, and the correlations.

* ``fit_curve.png``: per measured quantity, the data (markers, with +-sigma bars
  when given) and the fitted model's curve at the data points against the load,
  with the residuals (data - model) in a panel below; a fabric's warp and weft
  columns of one quantity (warp_strain and weft_strain, say) share a panel, each
  curve labelled with its family;
* ``fit_correlation.png``: the parameters' correlation matrix (blank where a
  parameter has none: not identified, or at a bound).

Built with `matplotlib.figure.Figure` and saved with `dynfab.plots.figures.save_png`,
as every dynfab figure.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from matplotlib.figure import Figure

from dynfab.results.measured_curve import LOAD_COLUMN, WEFT_LOAD_COLUMN
from dynfab.plots.style import save_png
from dynfab.plots.style import FONT_SIZE

FAMILY_COLOURS = {"": ("k", "C3"), "warp": ("C0", "C0"), "weft": ("C1", "C1")}
"""(data, fitted) colours of a column's family."""


def plot_fit(result, out) -> list[Path]:
    """Write both figures of `result` (a FitResult) into the folder `out`."""
    out = Path(out)
    return [save_png(plot_curve(result), out / "fit_curve.png"),
            save_png(plot_correlation(result), out / "fit_correlation.png")]


def load_axis(data) -> tuple[np.ndarray, str]:
    """The load the curves are drawn against and its label: the first column, or a fabric
    curve's weft column where the warps' load stays 0."""
    if data.weft_load is not None and not data.load.any():
        name, unit = WEFT_LOAD_COLUMN[data.control]
        return data.weft_load, f"{name} [{unit}]"
    name, unit = LOAD_COLUMN[data.control]
    return data.load, f"{name} [{unit}]" + (" (warps)" if data.weft_load is not None else "")


def panels(data) -> dict:
    """(dataset, unit) -> the measured names drawn in that panel, in the curve's order."""
    out = {}
    for name in data.measured:
        column = data.column(name)
        out.setdefault((column.dataset, column.unit), []).append(name)
    return out


def plot_curve(result) -> Figure:
    data = result.data
    groups = panels(data)
    load, load_label = load_axis(data)
    fig = Figure(figsize=(4.2 * len(groups), 5.0), layout="constrained")
    grid = fig.add_gridspec(2, len(groups), height_ratios=(3, 1))
    for c, ((dataset, unit), names) in enumerate(groups.items()):
        top = fig.add_subplot(grid[0, c])
        bottom = fig.add_subplot(grid[1, c], sharex=top)
        bottom.axhline(0.0, color="0.6", lw=0.8)
        for name in names:
            family = data.column(name).family
            data_colour, model_colour = FAMILY_COLOURS[family]
            prefix = f"{family} " if family else ""
            measured, model = data.measured[name], result.fitted[name]
            sigma = data.sigma.get(name)
            top.errorbar(load, measured, yerr=sigma, fmt="o", ms=3, color=data_colour,
                         label=f"{prefix}data")
            top.plot(load, model, "-", color=model_colour, label=f"{prefix}fitted")
            bottom.errorbar(load, measured - model, yerr=sigma, fmt="o", ms=3,
                            color=data_colour, label=family or None)
        quantity = names[0] if len(names) == 1 else dataset
        top.set_ylabel(f"{quantity} [{unit}]", fontsize=FONT_SIZE)
        top.legend(fontsize=FONT_SIZE)
        bottom.set_ylabel(f"residual [{unit}]", fontsize=FONT_SIZE)
        bottom.set_xlabel(load_label, fontsize=FONT_SIZE)
    shown = ", ".join(f"{k} = {v['value']:.4g}" for k, v in result.parameters.items())
    fig.suptitle(f"fit: {shown}", fontsize=FONT_SIZE)
    return fig


def plot_correlation(result) -> Figure:
    keys = list(result.parameters)
    corr = np.array([[np.nan if v is None else v for v in row] for row in result.correlation],
                    float).reshape(len(keys), len(keys))
    fig = Figure(figsize=(1.2 * len(keys) + 3.5, 1.0 * len(keys) + 2.0), layout="constrained")
    ax = fig.add_subplot()
    image = ax.imshow(corr, vmin=-1, vmax=1, cmap="RdBu_r")
    ax.set_xticks(range(len(keys)), keys, rotation=30, ha="right", fontsize=FONT_SIZE)
    ax.set_yticks(range(len(keys)), keys, fontsize=FONT_SIZE)
    for i in range(len(keys)):
        for j in range(len(keys)):
            if np.isfinite(corr[i, j]):
                ax.text(j, i, f"{corr[i, j]:.3f}", ha="center", va="center", fontsize=FONT_SIZE,
                        color="white" if abs(corr[i, j]) > 0.6 else "black")
    fig.colorbar(image, ax=ax, label="correlation")
    ax.set_title("parameter correlation", fontsize=FONT_SIZE)
    return fig
