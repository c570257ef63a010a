"""Figures of an in-plane shear specimen's result file (docs/model.md section 11).

- ``shear_force.png``: the force on the moved clamp (frame corner) along d against d, and
  Cao et al.'s normalised shear force (eq. 10; the bias extension's Harrison normalisation,
  `dynfab.model.shear_force`) against the test's nominal shear angle (eq. 13 for the bias
  extension's zone A, eq. 2 for the picture frame); the bias extension's panels also show each zone's mean
  computed shear angle against d beside eq. 13, the frame's its interior mean;
- ``shear_field.png``: the shear angle of every crossing over the specimen, drawn at the
  crossings' in-plane positions, at about a third, two thirds and the end of the path (the
  zones A, B, C of the bias extension are visible as the diamond, the triangles beside it and
  the triangles on the clamps);
- ``contact_field.png``: the contact force of every crossing after step 0 over the woven-in
  preload R_p, drawn over the specimen, and its median and range against the crossing's rank
  from a free yarn end (docs/model.md section 10, the woven-in contact: where it relaxes).

A transient's file (docs/model.md section 11.12) gets ``clamp_force.png``, ``energy.png`` and
``shear_field.png`` over time instead (`plot_transient`).
"""

from __future__ import annotations

import numpy as np
from matplotlib.figure import Figure

from dynfab.plots.measured import draw_measured
from dynfab.plots.style import FONT_SIZE, legend, new_figure, output_folder, save_png, style_axes
from dynfab.results.file import Results
from dynfab.model.shear_force import bias_normalised_shear_force
from dynfab.model.specimen_layout import nominal_shear_angle, yarns_meet_at

DEGREE = 180.0 / np.pi
ZONES = ("zone A", "zone B", "zone C")


def nominal_angles(results: Results, d: np.ndarray) -> np.ndarray:
    """The nominal shear angle [rad] of the file's test at each clamp displacement d [m]."""
    a = results.attrs
    if a["specimen_test"] == "bias_extension":
        dims = dict(width=float(a["specimen_width"]), height=float(a["specimen_height"]))
    else:
        dims = dict(side=float(a["specimen_side"]))
    return np.array([nominal_shear_angle(a["specimen_test"], float(x), **dims) for x in d])


def plot_shear_force(results: Results, measured=None) -> Figure:
    """Force against d and normalised shear force against the nominal angle, both linear from
    the origin; computed angles against eq. 13 / 2 (module docstring). Where the force past
    the yarns' meeting (`yarns_meet_at`) outgrows the curve before it by more than
    CLIP_RATIO, the first two panels are cut at CLIP_HEAD times the largest value before it
    (the points past it drawn apart, the cut said in a note) and a fourth panel draws the
    whole path on a log axis. A bias extension's force is drawn from step 0 too (a load
    cell zeroed at the start of the test), step 0's point named: the woven state's reaction
    on the clamps. `measured` (`dynfab.plots.measured.Measured`): a measured clamp force drawn over
    the computed one."""
    steps = results.steps
    d = np.asarray(steps["load"], float)[:, 0]
    force = np.asarray(steps["clamp_force"], float)
    gamma = np.asarray(steps["shear_angle"], float)
    nominal = nominal_angles(results, d)
    normalised = _normalised_over_the_path(results, d, force)
    meet = _meeting_angle(results)
    before = nominal < meet
    clipped = _clipped(force, before)
    fig = new_figure(18 if clipped else 14, 4)
    axes = fig.subplots(1, 4 if clipped else 3)
    by_d, by_angle, angles = axes[:3]
    for ax, x, y, unit in ((by_d, 1e3 * d, force, "clamp force along d [N]"),
                           (by_angle, DEGREE * nominal, normalised,
                            "normalised shear force [N/m]")):
        _draw_to_the_meeting(ax, x, y, before, clipped)
        ax.set_ylabel(unit)
    by_d.set_xlabel("clamp displacement d [mm]")
    by_angle.set_xlabel("nominal shear angle [deg]")
    if np.isfinite(meet):
        by_angle.axvline(DEGREE * meet, color="0.4", linestyle=":", linewidth=1,
                         label=f"yarns meet ({DEGREE * meet:.1f} deg)")
        by_angle.set_xlim(right=max(by_angle.get_xlim()[1], 1.05 * DEGREE * meet))
    if results.attrs["specimen_test"] == "bias_extension":
        _draw_from_step_0(by_d, 1e3 * d, force)
    if measured is not None:  # `dynfab.plots.measured.Measured`: a clamp force against d
        draw_measured(by_d, 1e3 * measured.end_displacement, measured.end_force, measured)
    _draw_angles(results, angles, d, nominal, gamma)
    if clipped:
        whole = axes[3]
        whole.plot(1e3 * d[d > 0], force[d > 0], marker="o", ms=3, label="clamp force")
        whole.set(yscale="log", xlabel="clamp displacement d [mm]",
                  ylabel="clamp force along d [N], log", title="the whole path")
    for ax in axes:
        style_axes(ax)
        legend(ax)
    fig.suptitle(f"{results.attrs['specimen_test'].replace('_', ' ')}: force and shear angle "
                 "(docs/model.md section 11)")
    return fig


def _meeting_angle(results: Results) -> float:
    """The nominal angle [rad] at which the yarns meet: the file's `yarns_meet_at`, or from
    the scene it stores (a file written before that attribute); inf where neither says."""
    if "yarns_meet_at" in results.attrs:
        return float(results.attrs["yarns_meet_at"])
    from dynfab.scene import parse_scene_text

    try:
        scene = parse_scene_text(results.attrs["scene"])
        return yarns_meet_at(scene.warp, scene.weft)
    except (KeyError, TypeError, ValueError):
        return np.inf


CLIP_RATIO = 5.0
"""How far the force past the yarns' meeting may outgrow the largest before it on the linear
panels before they are cut (`plot_shear_force`)."""
CLIP_HEAD = 1.5
"""Headroom of a cut panel over the largest value before the meeting."""


def _clipped(values: np.ndarray, before: np.ndarray) -> bool:
    """Whether the values past the meeting outgrow those before it by CLIP_RATIO."""
    head = np.nanmax(np.abs(values[before]), initial=0.0)
    return bool(head > 0 and np.nanmax(np.abs(values), initial=0.0) > CLIP_RATIO * head)


def _draw_to_the_meeting(ax, x, y, before, clipped: bool) -> None:
    """The curve on a linear axis from the origin: its points before the meeting, those past
    it apart; cut at CLIP_HEAD times the largest before it where `clipped`, a note saying
    where the last point lies."""
    ax.plot(x[before], y[before], marker="o", ms=3, label="computed")
    if not before.all():
        last = int(np.flatnonzero(before)[-1]) if before.any() else 0
        past = np.arange(last, x.size)
        ax.plot(x[past], y[past], marker="s", ms=3, color="C3",
                label="past the yarns' meeting")
    top = CLIP_HEAD * np.nanmax(y[before], initial=0.0) if clipped else None
    low = float(np.nanmin(y, initial=0.0))  # a force below zero beyond rounding is drawn
    ax.set_ylim(bottom=low if low < -1e-6 * np.nanmax(np.abs(y), initial=0.0) else 0.0,
                top=top)
    ax.set_xlim(left=min(0.0, float(np.min(x))))
    if clipped:
        ax.annotate(f"cut: {y[-1]:.3g} at the last step (fourth panel)", xy=(0.02, 0.97),
                    xycoords="axes fraction", va="top", fontsize=FONT_SIZE - 2)


def _draw_from_step_0(ax, x, force) -> None:
    """A bias extension's force less step 0's (a load cell zeroed at the start of the test),
    and step 0's point named: the relaxed woven state's reaction on the clamps."""
    ax.plot(x, force - force[0], linestyle="--", color="C2",
            label="from step 0 (load cell zeroed)")
    ax.annotate(f"step 0: the woven state's reaction\non the clamps, {force[0]:.3g} N",
                xy=(x[0], force[0]), xytext=(0.25, 0.25), textcoords="axes fraction",
                fontsize=FONT_SIZE - 2, arrowprops=dict(arrowstyle="->", color="0.4"))


def _draw_angles(results: Results, ax, d, nominal, gamma) -> None:
    """The computed shear angles (zone means, or the interior's) against the kinematics."""
    ax.plot(1e3 * d, DEGREE * nominal, color="k", linestyle="--", label="kinematics")
    if results.attrs["specimen_test"] == "bias_extension":
        zone = np.asarray(results.reference["zone"])
        for z, name in enumerate(ZONES):
            if np.any(zone == z):
                ax.plot(1e3 * d, DEGREE * gamma[:, zone == z].mean(axis=1), marker="o",
                        ms=3, label=f"{name}, mean")
    else:
        interior = np.asarray(results.reference["interior"], bool)
        ax.plot(1e3 * d, DEGREE * gamma[:, interior].mean(axis=1), marker="o", ms=3,
                label="interior crossings, mean")
    ax.set(xlabel="clamp displacement d [mm]", ylabel="shear angle [deg]")


def _normalised_over_the_path(results: Results, d: np.ndarray, force: np.ndarray) -> np.ndarray:
    """The normalised shear force [N/m] of every step: the frame's as recorded (eq. 10, a
    step's own), the bias extension's from the whole path (Harrison's recursion reads the
    curve from d -> 0+, which a step records only once two loaded steps exist: step 0's
    recorded value is 0, `dynfab.model.shear_force`)."""
    if results.attrs["specimen_test"] != "bias_extension":
        return np.asarray(results.steps["normalised_shear_force"], float)
    return bias_normalised_shear_force(d, force, float(results.attrs["specimen_width"]),
                                       float(results.attrs["specimen_height"]))


def plot_shear_field(results: Results) -> Figure:
    """The shear angle of every crossing at its in-plane position, three steps."""
    steps = results.steps
    d = np.asarray(steps["load"], float)[:, 0]
    return _shear_field(np.asarray(steps["crossing_positions"], float),
                        np.asarray(steps["shear_angle"], float),
                        [f"d = {1e3 * value:.4g} mm" for value in d],
                        "shear angle at the crossings (from step 0, the preload relaxed)")


def _shear_field(xy: np.ndarray, gamma: np.ndarray, titles: list[str], title: str) -> Figure:
    """Panels of the crossings' shear angle [deg] at their in-plane positions xy (entries, C,
    2+) [m] at about a third, two thirds and the last of the entries (step or frame)."""
    gamma = DEGREE * gamma
    last = gamma.shape[0] - 1
    chosen = sorted({max(1, round(last / 3)), max(1, round(2 * last / 3)), last}) if last else [0]
    fig = new_figure(4.5 * len(chosen) + 1, 5)
    axes = np.atleast_1d(fig.subplots(1, len(chosen)))
    top = max(float(np.abs(gamma[chosen]).max()), 1e-12)
    for ax, k in zip(axes, chosen):
        shown = ax.scatter(1e3 * xy[k, :, 0], 1e3 * xy[k, :, 1], c=gamma[k], s=12, cmap="viridis",
                           vmin=min(0.0, float(gamma[chosen].min())), vmax=top)
        ax.set(xlabel="x [mm]", ylabel="y [mm]", title=titles[k], aspect="equal")
    fig.colorbar(shown, ax=list(axes), label="shear angle [deg]")
    fig.suptitle(title)
    return fig


def plot_steps(results: Results, path, out_dir, measured=None) -> list:
    """A specimen's figures (docs/model.md section 11): its shear force against d and angle,
    its shear field, and where the file holds its free ends' ranks and preload, its contact
    field."""
    out = output_folder(out_dir)
    written = [save_png(plot_shear_force(results, measured), out / "shear_force.png"),
               save_png(plot_shear_field(results), out / "shear_field.png")]
    if "free_end_rank" in results.reference and "preload" in results.attrs:
        written.append(save_png(plot_contact_field(results), out / "contact_field.png"))
    return written


def plot_transient(results: Results, out) -> list:
    """A specimen's transient figures (docs/model.md section 11.12): ``clamp_force.png`` (the
    clamp force and d against time), ``energy.png`` (every energy and the dissipation against
    time) and ``shear_field.png`` (the crossings' shear angle from the as-woven state at three
    frames)."""
    frames = results.frames
    time_ms = 1e3 * np.asarray(frames["time"], float)
    fig = new_figure(7.0, 3.6)
    ax = fig.subplots()
    ax.plot(time_ms, np.asarray(frames["clamp_force"], float), color="C0")
    ax.set(xlabel="time [ms]", ylabel="clamp force along d [N]")
    twin = ax.twinx()
    twin.plot(time_ms, 1e3 * np.asarray(frames["load"], float)[:, 0], "--", color="C1")
    twin.set_ylabel("d [mm] (dashed)")
    style_axes(ax)
    fig.suptitle("force on the moved clamp (frame corner) during the transient")
    written = [save_png(fig, out / "clamp_force.png")]
    fig = new_figure(7.0, 3.6)
    ax = fig.subplots()
    for name, value in frames.items():
        if name.startswith("energy/") or name == "dissipated":
            ax.plot(time_ms, np.asarray(value, float).reshape(time_ms.size),
                    label=name.split("/", 1)[-1])
    ax.set(xlabel="time [ms]", ylabel="energy [J]")
    style_axes(ax)
    legend(ax)
    fig.suptitle("energies of the specimen, and friction's dissipation")
    written.append(save_png(fig, out / "energy.png"))
    crossing = np.asarray(results.reference["crossing_nodes"], int)[:, 0]
    xy = np.asarray(frames["positions"], float)[:, crossing]
    written.append(save_png(_shear_field(xy, np.asarray(frames["shear_angle"], float),
                                         [f"t = {t:.4g} ms" for t in time_ms],
                                         "shear angle at the crossings (from the as-woven "
                                         "state)"), out / "shear_field.png"))
    return written


BAND_RANKS = 6
"""Ranks from a free yarn end drawn one by one in the band (`plot_contact_field`); the
crossings further in are drawn together."""


def plot_contact_field(results: Results) -> Figure:
    """After step 0: R / R_p at every crossing over the specimen, and R / R_p against the rank
    from a free yarn end (1 a yarn's last crossing before it), median and range."""
    steps = results.steps
    preload = float(results.attrs["preload"])
    ratio = np.asarray(steps["contact_force"], float)[0] / preload
    xy = np.asarray(steps["crossing_positions"], float)[0]
    rank = np.asarray(results.reference["free_end_rank"])
    fig = new_figure(12, 5)
    field, band = fig.subplots(1, 2, gridspec_kw=dict(width_ratios=(1.3, 1)))
    shown = field.scatter(1e3 * xy[:, 0], 1e3 * xy[:, 1], c=ratio, s=12, cmap="viridis",
                          vmin=0.0, vmax=max(1.0, float(ratio.max())))
    field.set(xlabel="x [mm]", ylabel="y [mm]", aspect="equal")
    fig.colorbar(shown, ax=field, label="contact force / preload [-]")
    groups = [(str(k), rank == k) for k in range(1, BAND_RANKS + 1)]
    groups.append((f"{BAND_RANKS + 1}+", rank > BAND_RANKS))
    groups = [(name, chosen) for name, chosen in groups if np.any(chosen)]
    x = np.arange(len(groups))
    median = np.array([np.median(ratio[chosen]) for _, chosen in groups])
    low = np.array([ratio[chosen].min() for _, chosen in groups])
    high = np.array([ratio[chosen].max() for _, chosen in groups])
    band.errorbar(x, median, yerr=[median - low, high - median], marker="o", ms=4, capsize=3,
                  label="median, range")
    band.axhline(1.0, color="k", linestyle="--", linewidth=1, label="preload R_p")
    band.set(xticks=x, xticklabels=[name for name, _ in groups], ylim=(0.0, None),
             xlabel="crossings from a free yarn end [-]", ylabel="contact force / preload [-]")
    style_axes(band)
    legend(band)
    fig.suptitle(f"contact force after step 0 (woven-in preload R_p = {preload:g} N; "
                 "docs/model.md section 10)")
    return fig
