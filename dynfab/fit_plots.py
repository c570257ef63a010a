"""Figures of a fit (`dynfab fit`): the data against the fitted curve, and the correlations.

* ``fit_curve.png``: per measured column, the data (markers, with +-sigma bars
  when given) and the fitted model's curve at the data points, with the
  residuals (data - model) in a panel below;
* ``fit_correlation.png``: the parameters' correlation matrix (blank where a
  parameter has none: not identified, or at a bound).

Built with `matplotlib.figure.Figure` and saved with `dynfab.plot.save_png`,
as every dynfab figure.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from matplotlib.figure import Figure

from dynfab.fit_data import LOAD_COLUMN, MEASURABLE
from dynfab.plot import FONT_SIZE, save_png


def plot_fit(result, out) -> list[Path]:
    """Write both figures of `result` (a FitResult) into the folder `out`."""
    out = Path(out)
    return [save_png(plot_curve(result), out / "fit_curve.png"),
            save_png(plot_correlation(result), out / "fit_correlation.png")]


def plot_curve(result) -> Figure:
    data = result.data
    names = list(data.measured)
    fig = Figure(figsize=(4.2 * len(names), 5.0), layout="constrained")
    grid = fig.add_gridspec(2, len(names), height_ratios=(3, 1))
    control = result.scene.load.control
    load_name, load_unit = LOAD_COLUMN[control]
    for c, name in enumerate(names):
        top = fig.add_subplot(grid[0, c])
        bottom = fig.add_subplot(grid[1, c], sharex=top)
        measured, model = data.measured[name], result.fitted[name]
        sigma = data.sigma.get(name)
        top.errorbar(data.load, measured, yerr=sigma, fmt="o", ms=3, color="k", label="data")
        top.plot(data.load, model, "-", color="C3", label="fitted")
        top.set_ylabel(f"{name} [{MEASURABLE[name]}]", fontsize=FONT_SIZE)
        top.legend(fontsize=FONT_SIZE)
        bottom.axhline(0.0, color="0.6", lw=0.8)
        bottom.errorbar(data.load, measured - model, yerr=sigma, fmt="o", ms=3, color="k")
        bottom.set_ylabel(f"residual [{MEASURABLE[name]}]", fontsize=FONT_SIZE)
        bottom.set_xlabel(f"{load_name} [{load_unit}]", fontsize=FONT_SIZE)
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
