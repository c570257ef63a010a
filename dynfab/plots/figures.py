"""Figures from a result file (`dynfab.results.file` layout): PNGs for a report.

`plot_results` draws, with one line per yarn labelled by the root attribute
``yarn_labels``:

* ``traction.png``: force per unit width against strain, and P against end
  displacement, with markers at the computed load steps;
* ``contact_force.png``: largest (solid) and mean (dashed) contact force per
  yarn against end displacement (skipped without crossings);
* ``shape.png``: the first yarn's shape at about four loads, z exaggerated;
* ``friction.png``: open / sticking / sliding state of each crossing (numbered
  from 1) at each load step, one panel per yarn with friction (only if the
  file has friction).

A fabric's file (docs/model.md section 10) gets ``fabric.png`` (each family's load per unit
width against its strain, and its crimp against the load, from the as-woven state; each curve
a family's mean over its loaded yarns, or a pull-out's pulled warp), ``shape.png`` (the
deformed patch or cell, side and top views, as the ``dynfab fabric`` report draws it), and
a pull-out's also ``pullout.png`` (the pull force on the pulled warp against its end
displacement, and the slip front along it). An in-plane shear specimen's file (docs/model.md
section 11) gets ``shear_force.png``, ``shear_field.png`` and ``contact_field.png``
(`dynfab.plots.specimen`).

Matplotlib figures are built with `matplotlib.figure.Figure`, so the global
pyplot state and backend are never touched; PNGs are written with Agg.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Callable, NamedTuple

import numpy as np
from matplotlib import colormaps
from matplotlib.colors import BoundaryNorm, ListedColormap
from matplotlib.figure import Figure
from matplotlib.lines import Line2D
from matplotlib.patches import Patch

from dynfab.errors import UserError
from dynfab.results.friction_states import FRICTION_STATES, crossing_count, friction_states
from dynfab.plots.style import (FAMILY_ALPHA, FAMILY_STYLE, FAMILY_WIDTH, FONT_SIZE, legend,
                               new_figure, output_folder, save_png, style_axes)
from dynfab.plots import specimen
from dynfab.plots.measured import Measured, draw_measured, measured_points
from dynfab.results.file import Results, read_results


def plot_results(path: str | os.PathLike, out_dir: str | os.PathLike,
                 data: str | os.PathLike | None = None) -> list[Path]:
    """Write the figures of the result file ``path`` into ``out_dir`` (created if needed).

    Returns the paths of the PNGs written. Raises UserError for a missing
    file, a file that is not a dynfab result, or one without a load step. A study's table
    (``study.nc``) gets the study's figures (`dynfab.studies.plots`). `data`: a measured curve
    (CSV, the columns of `dynfab fit --data`, `dynfab.results.measured_curve`) drawn over the computed one
    (`measured_points`), labelled with its file's name.
    """
    from dynfab.studies.plots import is_study_table, plot_study

    if is_study_table(path):
        if data is not None:
            raise UserError(f"--data draws a measured curve over a run's file, not over a "
                            f"study's table ('{path}'): plot one of its cases/*.h5")
        return plot_study(path, out_dir)
    results = read_results(path)
    measured = None if data is None else measured_points(results, data)
    kind = KINDS.get(results.attrs.get("model", "yarn"))
    if kind is None:
        raise UserError(f"result file '{path}' holds a model this dynfab does not draw "
                        f"({results.attrs.get('model')!r}; it draws {', '.join(KINDS)})")
    if results.step_count == 0 and results.frame_count > 0:
        return kind.transient(results, output_folder(out_dir))
    if results.step_count == 0:
        raise UserError(f"result file '{path}' has no finished load step to plot")
    return kind.steps(results, path, out_dir, measured)


def _fabric_figures(results: Results, path, out_dir, measured: Measured | None) -> list[Path]:
    """A fabric's figures (docs/model.md section 10): its strains and stresses, its shape, a
    pull-out's curves."""
    if "stress" not in results.steps:
        raise UserError(f"result file '{path}' lacks dataset steps/stress (written by an "
                        f"earlier dynfab): run its scene again to plot it")
    out = output_folder(out_dir)
    written = [save_png(plot_fabric(results, measured), out / "fabric.png"),
               save_png(plot_fabric_shape(results), out / "shape.png")]
    if "pullout_warp" in results.attrs:
        written.append(save_png(plot_pullout(results), out / "pullout.png"))
    return written


def _yarn_figures(results: Results, path, out_dir, measured: Measured | None) -> list[Path]:
    """The one-yarn model's figures (docs/model.md sections 1-9): traction, contact forces,
    shapes, friction."""
    for key in ("end_force", "end_displacement", "positions"):
        if key not in results.steps:
            raise UserError(f"result file '{path}' lacks dataset steps/{key}")
    out = output_folder(out_dir)
    written = [save_png(plot_traction(results, path, measured), out / "traction.png")]
    if crossing_count(results) > 0 and "contact_force" in results.steps:
        written.append(save_png(plot_contact_force(results), out / "contact_force.png"))
    written.append(save_png(plot_shape(results, path), out / "shape.png"))
    if has_friction(results):
        written.append(save_png(plot_friction(results), out / "friction.png"))
    return written


def family_names(results: Results) -> dict:
    """What each family's curve of a fabric's file shows (docs/model.md section 10): the
    mean over its loaded yarns, or in a pull-out the pulled warp and the wefts' mean."""
    pulled = results.attrs.get("pullout_warp")
    if pulled is not None:
        return {"warp": f"warp {pulled} (pulled)", "weft": "wefts (mean)"}
    return {"warp": "warps (mean of the loaded)", "weft": "wefts (mean of the loaded)"}


def as_woven_crimps(results: Results) -> np.ndarray:
    """(warp, weft) mean crimp [-] of a fabric's as-woven reference (`dynfab.model.yarn.crimp`),
    as `steps/crimp` averages it."""
    from dynfab.model.geometry import crimp

    return np.array([crimp(np.asarray(results.reference[name], float)).mean()
                     for name in ("positions", "weft_positions")])


def plot_fabric(results: Results, measured: Measured | None = None) -> Figure:
    """A fabric's run (docs/model.md section 10): each family's load per unit width
    (`steps/stress`) against its nominal strain, and each family's mean crimp against the
    larger of the two loads per unit width, both from the as-woven state (0 load, 0 strain);
    the legend says whose each curve is (`family_names`)."""
    steps = results.steps
    stress = np.vstack([np.zeros(2), np.asarray(steps["stress"], float)])
    strain = np.vstack([np.zeros(2), np.asarray(steps["strain"], float)])
    crimp = np.vstack([as_woven_crimps(results), np.asarray(steps["crimp"], float)])
    larger = stress.max(axis=1)
    fig = new_figure(10, 4)
    traction, crimp_ax = fig.subplots(1, 2)
    for column, (family, name) in enumerate(family_names(results).items()):
        style = dict(linestyle=FAMILY_STYLE[family], linewidth=FAMILY_WIDTH[family],
                     alpha=FAMILY_ALPHA[family], marker="o" if family == "warp" else "x", ms=3,
                     label=name)
        traction.plot(100 * strain[:, column], stress[:, column], gid=family, **style)
        crimp_ax.plot(larger, 100 * crimp[:, column], gid=family, **style)
    if measured is not None:
        draw_measured(traction, None if measured.strain is None else 100 * measured.strain,
                      measured.stress, measured)
    traction.set(xlabel="nominal strain [%]", ylabel="load per unit width [N/m]")
    crimp_ax.set(xlabel="larger of the two loads per unit width [N/m]", ylabel="mean crimp [%]")
    return _styled(fig, results, "woven fabric, from the as-woven state (docs/model.md section 10)",
                   traction, crimp_ax)


def plot_fabric_shape(results: Results) -> Figure:
    """The deformed patch or cell at about four load steps (`shape_steps`), drawn as the
    `dynfab fabric` report draws its cell (`dynfab.plots.cell.plot_cell`): side
    views of one warp (a pull-out's pulled warp, else warp 1) and weft 1 over their
    as-woven shapes, z exaggerated, and top views with the crossings coloured by contact
    force, the planes where each step leaves them."""
    from dynfab.plots.cell import plot_cell

    steps, reference = results.steps, results.reference
    warp = int(results.attrs.get("pullout_warp", 1)) - 1
    woven_warps = np.asarray(reference["positions"], float)
    woven_wefts = np.asarray(reference["weft_positions"], float)
    nodes = np.asarray(reference["crossing_nodes"], int)
    weft_nodes = np.asarray(reference["weft_crossing_nodes"], int)
    above = woven_warps[:, nodes, 1] > woven_wefts[:, weft_nodes, 1].T  # (n_wa, n_we)
    stress = np.asarray(steps["stress"], float)
    paths = {}
    for step in shape_steps(results.step_count):
        warps = np.asarray(steps["positions"][step])
        wefts = np.asarray(steps["weft_positions"][step])
        paths[f"step {step + 1}"] = {
            "label": f"step {step + 1}: {stress[step, 0]:.3g}, {stress[step, 1]:.3g} N/m",
            "last": {"warp": warps[warp], "weft": wefts[0], "warp_above": above,
                     "cell_m": [warps[:, -1, 0].max(), wefts[:, -1, 0].max()],
                     "planes_m": [steps["weft_planes"][step], steps["warp_planes"][step]]},
            "contact_force_N": [np.asarray(steps["contact_force"][step])]}
    data = {"as_woven": {"warp": woven_warps[warp], "weft": woven_wefts[0]}, "paths": paths,
            "shown": {"warp": f"warp {warp + 1}", "weft": "weft 1"}}
    title = str(results.attrs.get("title", "") or "")
    what = "the deformed fabric at four load steps: loads per unit width (warp, weft)"
    return plot_cell(data, heading=f"{title}\n{what}" if title else what)


def pullout_curves(results: Results) -> dict:
    """The pulled warp's (`pullout_warp`, 1-based) end displacement [m] and pull force [N]
    per step, the sum of its crossings' friction limits sum_j F_T,j [N] (the force's bound,
    reached once every crossing slides along x), and per crossing (numbered from the free
    end) the share |F_x,j| / F_T,j of the limit its friction carries along the warp, and
    whether the return map moved its anchor (docs/model.md sections 4, 10)."""
    steps, k = results.steps, int(results.attrs["pullout_warp"]) - 1
    warps, wefts = np.asarray(steps["contact_force"]).shape[1:]
    friction = np.asarray(steps["friction_force"], float).reshape(-1, warps, wefts, 2)[:, k]
    limit = np.asarray(steps["friction_limit"], float)[:, k]
    share = np.divide(np.abs(friction[..., 0]), limit, out=np.zeros_like(limit),
                      where=limit > 0)
    return {"displacement": _per_yarn(results, "end_displacement")[:, k],
            "force": _per_yarn(results, "end_force")[:, k], "limit_sum": limit.sum(axis=1),
            "share": share, "sliding": np.asarray(steps["sliding"], bool)[:, k]}


def plot_pullout(results: Results) -> Figure:
    """A pull-out (docs/model.md section 10): the pull force against the pulled warp's end
    displacement with the bound sum_j F_T,j, and the slip front: each crossing's share of
    its friction limit carried along the warp, at each load step, sliding ones marked."""
    curves = pullout_curves(results)
    fig = new_figure(10, 4)
    force_ax, front_ax = fig.subplots(1, 2)
    k = results.attrs["pullout_warp"]
    mm = 1e3 * curves["displacement"]
    force_ax.plot(np.append(0.0, mm), np.append(0.0, 1e3 * curves["force"]), "o-", ms=3,
                  label=f"pull force on warp {k}, from the as-woven state")
    force_ax.plot(mm, 1e3 * curves["limit_sum"], "--", color="0.4",
                  label=f"sum of the friction limits F_T on warp {k}")
    force_ax.set(xlabel=f"end displacement of warp {k} (pulled) [mm], linear below 0.01",
                 ylabel="force [mN]")
    force_ax.set_xscale("symlog", linthresh=1e-2)  # the slip front: the first 0.1 mm
    share, sliding = curves["share"], curves["sliding"]
    steps, count = share.shape
    image = front_ax.imshow(share.T, cmap="viridis", vmin=0.0, vmax=1.0, origin="lower",
                            aspect="auto", interpolation="nearest",
                            extent=(0.5, steps + 0.5, 0.5, count + 0.5))
    step, crossing = np.nonzero(sliding)
    front_ax.plot(step + 1, crossing + 1, "x", color="w", ms=3, label="anchor moved (sliding)")
    fig.colorbar(image, ax=front_ax, label="|F_x| / F_T")
    front_ax.set(xlabel="load step", ylabel=f"crossing of warp {k} (1 = nearest its free end)")
    front_ax.xaxis.get_major_locator().set_params(integer=True)
    front_ax.yaxis.get_major_locator().set_params(integer=True)
    style_axes(force_ax)
    legend(force_ax)
    style_axes(front_ax)
    legend(front_ax, loc="lower right")
    front_ax.grid(False)
    _suptitle(fig, results, f"pull-out of warp {results.attrs['pullout_warp']}")
    return fig


def yarn_labels(results: Results) -> list[str]:
    """One label per yarn: the ``yarn_labels`` attribute, else "yarn 1", "yarn 2", ..."""
    if results.step_count:
        count = results.steps["end_force"].reshape(results.step_count, -1).shape[1]
    else:
        count = np.asarray(results.frames["positions"]).shape[1]
    labels = results.attrs.get("yarn_labels")
    if isinstance(labels, str):
        labels = [labels]
    if not labels or len(labels) != count:
        return [f"yarn {k + 1}" for k in range(count)]
    return [str(label) for label in labels]


def _per_yarn(results: Results, name: str) -> np.ndarray:
    """A ``steps/<name>`` dataset as a (steps, yarns) array."""
    return np.asarray(results.steps[name], dtype=float).reshape(results.step_count, -1)


def _attr(results: Results, name: str, path) -> float:
    """A positive float root attribute; UserError naming it if absent or not positive."""
    value = results.attrs.get(name)
    if not isinstance(value, (int, float)) or isinstance(value, bool) or not value > 0:
        raise UserError(f"result file '{path}' lacks a positive root attribute {name!r}")
    return float(value)


def has_friction(results: Results) -> bool:
    """True if the file has crossings with a non-zero friction limit at some step."""
    limit = results.steps.get("friction_limit")
    return crossing_count(results) > 0 and limit is not None and bool(np.any(limit != 0))


def plot_traction(results: Results, path="", measured: Measured | None = None) -> Figure:
    """Force per unit width [N/m] vs strain [%], and P [N] vs end displacement [mm].

    A plain rod (no weft, no `width_per_yarn` attribute) shows P against strain instead.
    """
    length = _attr(results, "projected_length", path)
    rod = "width_per_yarn" not in results.attrs
    width = 1.0 if rod else _attr(results, "width_per_yarn", path)
    force = _per_yarn(results, "end_force")
    displacement = _per_yarn(results, "end_displacement")
    fig = new_figure(7.0, 3.0)
    left, right = fig.subplots(1, 2)
    for k, label in enumerate(yarn_labels(results)):
        left.plot(100 * displacement[:, k] / length, force[:, k] / width, "o-", ms=3, label=label)
        right.plot(1e3 * displacement[:, k], force[:, k], "o-", ms=3, label=label)
    if measured is not None and measured.end_displacement is not None:
        u, P = measured.end_displacement, measured.end_force
        draw_measured(left, 100 * u / length, None if P is None else P / width, measured)
        draw_measured(right, 1e3 * u, P, measured)
    left.set(xlabel="strain (%)", ylabel="end force P (N)" if rod else "force per unit width (N/m)")
    right.set(xlabel="end displacement (mm)", ylabel="end force P (N)")
    return _styled(fig, results, "traction", left, right)


def plot_contact_force(results: Results) -> Figure:
    """Largest (solid) and mean (dashed) contact force over the crossings vs end displacement."""
    contact = np.asarray(results.steps["contact_force"], dtype=float)
    contact = contact.reshape(results.step_count, -1, contact.shape[-1])
    displacement = 1e3 * _per_yarn(results, "end_displacement")
    fig = new_figure(5.0, 3.5)
    ax = fig.subplots()
    for k, label in enumerate(yarn_labels(results)):
        (line,) = ax.plot(displacement[:, k], contact[:, k].max(axis=1), "o-", ms=3, label=label)
        ax.plot(displacement[:, k], contact[:, k].mean(axis=1), "--", color=line.get_color())
    ax.set(xlabel="end displacement (mm)", ylabel="contact force (N)")
    style_axes(ax)
    handles = ax.get_legend_handles_labels()[0] + [
        Line2D([], [], color="k", ls="-", label="max over crossings"),
        Line2D([], [], color="k", ls="--", label="mean over crossings"),
    ]
    legend(ax, handles=handles)
    _suptitle(fig, results, "contact force at the crossings")
    return fig


def shape_steps(step_count: int) -> list[int]:
    """About four step indices to draw: first, 1/3, 2/3 and last (no repeats)."""
    return sorted(set(np.round(np.linspace(0, step_count - 1, 4)).astype(int).tolist()))


def _plot_transient(results: Results, out: Path) -> list[Path]:
    """A transient run's figures: energies against time, shapes at a few frames."""
    return [save_png(plot_energy_history(results), out / "energy.png"),
            save_png(plot_frame_shapes(results), out / "shape.png")]


def plot_energy_history(results: Results) -> Figure:
    """Every frames/energy/<term> [J] of the first yarn against time [ms]."""
    time_ms = 1e3 * np.asarray(results.frames["time"], dtype=float)
    fig = new_figure(6.0, 3.2)
    ax = fig.subplots()
    for name, value in results.frames.items():
        if name.startswith("energy/"):
            energy = np.asarray(value, dtype=float).reshape(time_ms.size, -1)[:, 0]
            ax.plot(time_ms, energy, label=name.split("/", 1)[1])
    ax.set(xlabel="time (ms)", ylabel="energy (J)")
    return _styled(fig, results, f"energies of {yarn_labels(results)[0]}", ax)


def plot_frame_shapes(results: Results) -> Figure:
    """The first yarn's z [mm] against x [mm] at about four frames, z exaggerated."""
    time_ms = 1e3 * np.asarray(results.frames["time"], dtype=float)
    positions = np.asarray(results.frames["positions"], dtype=float)
    nodes = np.asarray(results.reference.get("crossing_nodes", []), dtype=int).ravel()
    fig = new_figure(7.0, 3.2)
    ax = fig.subplots()
    ref = np.asarray(results.reference["positions"], dtype=float)[0]
    ax.plot(1e3 * ref[:, 0], 1e3 * ref[:, 1], "--", color="0.5", lw=1, label="as woven")
    frames = shape_steps(time_ms.size)
    for n, frame in enumerate(frames):
        color = colormaps["viridis"](n / max(len(frames) - 1, 1) * 0.85)
        xz = 1e3 * positions[frame, 0]
        ax.plot(xz[:, 0], xz[:, 1], "-", color=color, lw=1.2, label=f"t = {time_ms[frame]:.3g} ms")
        if nodes.size:
            ax.plot(xz[nodes, 0], xz[nodes, 1], "o", color=color, ms=4)
    ax.set(xlabel="x (mm)", ylabel="z (mm, exaggerated)")
    style_axes(ax)
    legend(ax, loc="upper left", bbox_to_anchor=(1.01, 1.0), borderaxespad=0)
    _suptitle(fig, results, f"shape of {yarn_labels(results)[0]} (z exaggerated; dots: crossings)")
    return fig


def plot_shape(results: Results, path="") -> Figure:
    """The first yarn's z [mm] against x [mm] at about four loads, z exaggerated."""
    positions = np.asarray(results.steps["positions"], dtype=float)
    positions = positions.reshape(results.step_count, -1, *positions.shape[-2:])
    nodes = np.asarray(results.reference.get("crossing_nodes", []), dtype=int).ravel()
    sliding = results.steps.get("sliding")
    fig = new_figure(7.0, 3.2)
    ax = fig.subplots()
    reference = results.reference.get("positions")
    if reference is not None:
        ref = np.asarray(reference, dtype=float).reshape(-1, *positions.shape[-2:])[0]
        ax.plot(1e3 * ref[:, 0], 1e3 * ref[:, 1], "--", color="0.5", lw=1, label="reference")
    load = _per_yarn(results, "load") if "load" in results.steps else None
    load_units = results.units.get("steps/load", "")
    cmap = colormaps["viridis"]
    steps = shape_steps(results.step_count)
    for n, step in enumerate(steps):
        color = cmap(n / max(len(steps) - 1, 1) * 0.85)
        xz = 1e3 * positions[step, 0]
        label = f"step {step + 1}"
        if load is not None:
            label += f": load {load[step, 0]:.4g} {load_units}"
        ax.plot(xz[:, 0], xz[:, 1], "-", color=color, lw=1.2, label=label)
        if nodes.size:
            slide = np.zeros(nodes.size, bool)
            if sliding is not None:
                slide = np.asarray(sliding).reshape(results.step_count, -1, nodes.size)[step, 0]
                slide = slide.astype(bool)
            ax.plot(xz[nodes[~slide], 0], xz[nodes[~slide], 1], "o", color=color, ms=4)
            ax.plot(xz[nodes[slide], 0], xz[nodes[slide], 1], "o", mfc="white", mec=color,
                    mew=1.2, ms=6)
    handles = ax.get_legend_handles_labels()[0]
    if nodes.size:
        handles.append(Line2D([], [], marker="o", ls="", color="k", ms=4, label="crossing"))
        if sliding is not None:
            handles.append(Line2D([], [], marker="o", ls="", mfc="white", mec="k", ms=6,
                                  label="sliding crossing"))
    ax.set(xlabel="x (mm)", ylabel="z (mm, exaggerated)")
    ax.set_aspect("auto")
    style_axes(ax)
    legend(ax, handles=handles, loc="upper left", bbox_to_anchor=(1.01, 1.0), borderaxespad=0)
    labels = yarn_labels(results)
    _suptitle(fig, results, f"shape of {labels[0]} (z exaggerated)")
    return fig


def friction_yarns(results: Results) -> list[int]:
    """The yarns (from 0) whose friction limit is non-zero at some step and crossing."""
    limit = np.asarray(results.steps["friction_limit"], dtype=float)
    limit = limit.reshape(results.step_count, -1, crossing_count(results))
    return [k for k in range(limit.shape[1]) if np.any(limit[:, k] != 0)]


def plot_friction(results: Results) -> Figure:
    """Categorical image of each friction yarn's state: crossing (numbered from 1, the one
    nearest the fixed end first) against load step, one panel per yarn with friction."""
    yarns, labels = friction_yarns(results), yarn_labels(results)
    fig = new_figure(6.0, 0.6 + 2.4 * len(yarns))
    axes = np.atleast_1d(fig.subplots(len(yarns), 1, sharex=True, squeeze=False)[:, 0])
    cmap = ListedColormap([color for _, color in FRICTION_STATES])
    norm = BoundaryNorm(np.arange(len(FRICTION_STATES) + 1) - 0.5, cmap.N)
    for ax, k in zip(axes, yarns):
        states = friction_states(results, k)
        steps, count = states.shape
        ax.imshow(states.T, cmap=cmap, norm=norm, origin="lower", aspect="auto",
                  interpolation="nearest", extent=(0.5, steps + 0.5, 0.5, count + 0.5))
        ax.set(ylabel="crossing", title=labels[k])
        ax.xaxis.get_major_locator().set_params(integer=True)
        ax.yaxis.get_major_locator().set_params(integer=True)
        style_axes(ax)
        ax.grid(False)
    axes[-1].set_xlabel("load step")
    handles = [Patch(facecolor=color, edgecolor="k", label=name) for name, color in FRICTION_STATES]
    axes[0].legend(handles=handles, fontsize=FONT_SIZE - 1, loc="upper left",
                   bbox_to_anchor=(1.01, 1.0), borderaxespad=0)
    _suptitle(fig, results, "friction state at each crossing (1 = nearest the fixed end)")
    return fig


def _styled(fig: Figure, results: Results, what: str, *axes) -> Figure:
    """`fig` with each of `axes` styled and given its legend, under `_suptitle`."""
    for ax in axes:
        style_axes(ax)
        legend(ax)
    _suptitle(fig, results, what)
    return fig


def _suptitle(fig: Figure, results: Results, what: str) -> None:
    """Figure title: the run's ``title`` attribute (if any) and what is shown."""
    title = str(results.attrs.get("title", "") or "")
    fig.suptitle(f"{title}\n{what}" if title else what, fontsize=FONT_SIZE + 1)


class KindFigures(NamedTuple):
    """The figures of one kind of result file (its root attribute "model")."""

    steps: Callable
    """(results, path, out_dir, measured) -> the PNGs of a run's load steps."""
    transient: Callable
    """(results, out) -> the PNGs of a transient run's frames."""


KINDS = {"yarn": KindFigures(_yarn_figures, _plot_transient),
         "fabric": KindFigures(_fabric_figures, _plot_transient),
         "specimen": KindFigures(specimen.plot_steps, specimen.plot_transient)}
"""Each kind of result file's figures (a file without the attribute: the one-yarn model's)."""
