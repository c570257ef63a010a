"""Figures of a study's table (`study.nc`, `dynfab.studies.table`): `dynfab plot study.nc`.

For every observable ``NAME``:

* ``NAME.png``: its value against each varied key, one panel a key. A grid's cases with
  equal values of the other keys are joined by a line (labelled by those values); a Latin
  hypercube's are points. An observable of the whole path is drawn at each case's last
  step; one with further axes (a yarn, a family) gets a line style per component.
* ``NAME_path.png`` (a path observable): its value against the load path, a curve a case,
  coloured by the first varied key.
* ``NAME_map.png`` (a study of two keys): the value over the plane of the two keys, a
  coloured mesh for a grid, coloured points for a Latin hypercube (first component).

A failed case has no value (NaN) and draws nothing. Figures are built without pyplot.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from dynfab.errors import UserError
from dynfab.plots.style import FONT_SIZE, legend, new_figure, output_folder, save_png, style_axes

BOOKKEEPING = ("load", "status", "message", "steps_done", "solver_time")
"""The table's variables that are not observables."""
MAX_LINES = 8
"""Most lines a panel labels (more combinations of the other keys: points, unlabelled)."""
STYLES = ("-", "--", ":", "-.")


def plot_study(path: str | os.PathLike, out_dir: str | os.PathLike) -> list[Path]:
    """Write the figures of the study table `path` into `out_dir`; their paths."""
    table = _open(Path(path))
    out = output_folder(out_dir)
    keys = [k for k in table.attrs["parameters"].split("\n") if k]
    written = []
    for name in [n for n in table.data_vars if n not in BOOKKEEPING]:
        variable = table[name]
        values = _per_case(table, variable)
        written.append(save_png(_against_keys(table, keys, name, variable, values),
                                out / f"{name}.png"))
        if "step" in variable.dims:
            written.append(save_png(_along_path(table, keys, name, variable),
                                    out / f"{name}_path.png"))
        if len(keys) == 2:
            written.append(save_png(_map(table, keys, name, variable, values[:, 0]),
                                    out / f"{name}_map.png"))
    return written


def is_study_table(path: str | os.PathLike) -> bool:
    """True for a study's table (a netCDF file, `.nc`)."""
    return Path(path).suffix == ".nc"


def _open(path: Path):
    import xarray as xr

    if not path.is_file():
        raise UserError(f"study table '{path}' does not exist")
    try:
        table = xr.open_dataset(path, engine="h5netcdf").load()
    except (OSError, ValueError) as error:
        raise UserError(f"cannot read study table '{path}': {str(error).splitlines()[0]}") \
            from None
    if "parameters" not in table.attrs:
        raise UserError(f"'{path}' is not a dynfab study table (no attribute parameters)")
    return table


def _per_case(table, variable) -> np.ndarray:
    """(cases, components): each case's value, a path observable's at its last step."""
    data = np.asarray(variable.values, float)
    if "step" in variable.dims:
        last = np.asarray(table["steps_done"].values) - 1
        finished = np.asarray(table["status"].values) == "finished"
        data = np.stack([data[i, max(last[i], 0)] if finished[i] else
                         np.full(data.shape[2:], np.nan) for i in range(data.shape[0])])
    return data.reshape(data.shape[0], -1)


def _with_units(text: str, units) -> str:
    """`text [units]`, "-" for a number without units (every axis says its units)."""
    return f"{text} [{units or '-'}]"


def _label(variable, name: str) -> str:
    at = variable.attrs.get("at", "path")
    where = {"path": ", last step", "last": ", last step"}.get(str(at), f" at load {at}")
    return _with_units(f"{name}{where}", variable.attrs.get("units", ""))


def _axis_label(table, key: str) -> str:
    return _with_units(key, table[key].attrs.get("units", ""))


FAMILY_DATASETS = ("steps/strain", "steps/crimp", "steps/stress")
"""A fabric's per-family datasets: their components are the warps' and the wefts'."""


def _component_names(variable) -> list[str]:
    """A name for each component of an observable with further axes (a fabric's family, else
    its axis and index): the line styles' legend."""
    extra = [d for d in variable.dims if d not in ("case", "step")]
    if not extra:
        return [""]
    if variable.attrs.get("dataset") in FAMILY_DATASETS and variable.shape[-1] == 2:
        return ["warp", "weft"]
    sizes = [variable.sizes[d] for d in extra]
    return [", ".join(f"{d} = {i}" for d, i in zip(extra, index))
            for index in np.ndindex(*sizes)]


def _style_legend(ax, names: list[str], **kwargs) -> None:
    """A legend of every labelled line, and where an observable has several components, one
    entry per line style saying whose component it draws."""
    from matplotlib.lines import Line2D

    handles, labels = ax.get_legend_handles_labels()
    if len(names) > 1:
        handles += [Line2D([], [], color="k", linestyle=STYLES[c % len(STYLES)], label=name)
                    for c, name in enumerate(names)]
    legend(ax, handles=handles, **kwargs)


def _positions(column: np.ndarray) -> tuple[np.ndarray, list | None]:
    """Numbers to plot a key's values at: themselves, or for text values their rank (and
    the labels)."""
    if column.dtype.kind in "biuf":
        return column.astype(float), None
    labels = sorted(set(column.tolist()))
    return np.array([labels.index(v) for v in column.tolist()], float), labels


def _against_keys(table, keys, name, variable, values):
    fig = new_figure(3.6 * len(keys), 3.0)
    axes = fig.subplots(1, len(keys), squeeze=False)[0]
    grid = table.attrs.get("design") == "grid"
    for ax, key in zip(axes, keys):
        x, labels = _positions(np.asarray(table[key].values))
        others = [k for k in keys if k != key]
        groups = {}
        for i in range(len(x)):
            groups.setdefault(tuple(table[k].values[i].item() for k in others), []).append(i)
        labelled = grid and len(groups) <= MAX_LINES
        for g, (group, members) in enumerate(groups.items()):
            order = sorted(members, key=lambda i: x[i])
            text = ", ".join(f"{k} = {v:g}" if isinstance(v, float) else f"{k} = {v}"
                             for k, v in zip(others, group))
            colour = f"C{g % 10}" if labelled else "C0"  # a group's components one colour
            for c in range(values.shape[1]):
                ax.plot(x[order], values[order, c], STYLES[c % len(STYLES)] if grid else "",
                        marker="o", ms=3, color=colour,
                        label=(text or None) if labelled and c == 0 else None)
        if labels is not None:
            ax.set_xticks(range(len(labels)), labels)
        ax.set_xlabel(_axis_label(table, key))
        ax.set_ylabel(_label(variable, name))
        style_axes(ax)
        _style_legend(ax, _component_names(variable))
    fig.suptitle(f"{table.attrs.get('title') or 'study'}: {name}", fontsize=FONT_SIZE + 1)
    return fig


def _along_path(table, keys, name, variable):
    from matplotlib import colormaps
    from matplotlib.cm import ScalarMappable
    from matplotlib.colors import Normalize

    fig = new_figure(5.0, 3.4)
    ax = fig.subplots()
    load = np.asarray(table["load"].values, float)
    data = np.asarray(variable.values, float).reshape(load.shape[0], load.shape[1], -1)
    colour, labels = _positions(np.asarray(table[keys[0]].values))
    norm = Normalize(np.nanmin(colour), np.nanmax(colour) if np.ptp(colour) else
                     np.nanmin(colour) + 1)
    cmap = colormaps["viridis"]
    for i in range(load.shape[0]):
        for c in range(data.shape[2]):
            ax.plot(load[i], data[i, :, c], STYLES[c % len(STYLES)], lw=1,
                    color=cmap(norm(colour[i])))
    bar = fig.colorbar(ScalarMappable(norm=norm, cmap=cmap), ax=ax)
    bar.set_label(_axis_label(table, keys[0]), fontsize=FONT_SIZE)
    ax.set_xlabel(_with_units("load", table["load"].attrs.get("units")))
    ax.set_ylabel(_with_units(name, variable.attrs.get("units", "")))
    style_axes(ax)
    _style_legend(ax, _component_names(variable))
    return fig


def _map(table, keys, name, variable, values):
    fig = new_figure(4.6, 3.6)
    ax = fig.subplots()
    x, x_labels = _positions(np.asarray(table[keys[0]].values))
    y, y_labels = _positions(np.asarray(table[keys[1]].values))
    if table.attrs.get("design") == "grid":
        xs, ys = np.unique(x), np.unique(y)
        grid = np.full((ys.size, xs.size), np.nan)
        grid[np.searchsorted(ys, y), np.searchsorted(xs, x)] = values
        shown = ax.pcolormesh(_edges(xs), _edges(ys), grid, shading="flat")
    else:
        shown = ax.scatter(x, y, c=values, s=25)
    bar = fig.colorbar(shown, ax=ax)
    bar.set_label(_label(variable, name), fontsize=FONT_SIZE)
    for labels, setter in ((x_labels, ax.set_xticks), (y_labels, ax.set_yticks)):
        if labels is not None:
            setter(range(len(labels)), labels)
    ax.set_xlabel(_axis_label(table, keys[0]))
    ax.set_ylabel(_axis_label(table, keys[1]))
    style_axes(ax)
    return fig


def _edges(centres: np.ndarray) -> np.ndarray:
    """Cell edges around sorted centres (half-way between, the ends mirrored)."""
    if centres.size == 1:
        return np.array([centres[0] - 0.5, centres[0] + 0.5])
    middle = (centres[1:] + centres[:-1]) / 2
    return np.concatenate([[2 * centres[0] - middle[0]], middle, [2 * centres[-1] - middle[-1]]])
