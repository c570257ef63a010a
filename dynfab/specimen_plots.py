"""Figures of an in-plane shear specimen's result file (docs/model.md section 11).

- ``shear_force.png``: the force on the moved clamp (frame corner) along d against d, and
  Cao et al.'s normalised shear force (eq. 10; the bias extension's Harrison normalisation,
  `dynfab.shear_force`) against the test's nominal shear angle (eq. 13 for the bias
  extension's zone A, eq. 2 for the picture frame); the bias extension's panels also show each zone's mean
  computed shear angle against d beside eq. 13, the frame's its interior mean;
- ``shear_field.png``: the shear angle of every crossing over the specimen, drawn at the
  crossings' in-plane positions, at about a third, two thirds and the end of the path (the
  zones A, B, C of the bias extension are visible as the diamond, the triangles beside it and
  the triangles on the clamps);
- ``contact_field.png``: the contact force of every crossing after step 0 over the woven-in
  preload R_p, drawn over the specimen, and its median and range against the crossing's rank
  from a free yarn end (docs/model.md section 10, the woven-in contact: where it relaxes).
"""

from __future__ import annotations

import numpy as np
from matplotlib.figure import Figure

from dynfab.plot_style import legend, new_figure, style_axes
from dynfab.results import Results
from dynfab.shear_force import bias_normalised_shear_force
from dynfab.specimen_layout import nominal_shear_angle

DEGREE = 180.0 / np.pi
ZONES = ("zone A", "zone B", "zone C")
WIDE_RANGE = 30.0
"""Largest over smallest force drawn on a linear axis (`_log_if_wide`)."""


def _nominal(results: Results, d: np.ndarray) -> np.ndarray:
    """The test's nominal shear angle at each d [rad]."""
    a = results.attrs
    if a["specimen_test"] == "bias_extension":
        dims = dict(width=float(a["specimen_width"]), height=float(a["specimen_height"]))
    else:
        dims = dict(side=float(a["specimen_side"]))
    return np.array([nominal_shear_angle(a["specimen_test"], float(x), **dims) for x in d])


def plot_shear_force(results: Results) -> Figure:
    """Force against d, normalised shear force against the nominal angle; computed angles
    against eq. 13 / 2."""
    steps = results.steps
    d = np.asarray(steps["load"], float)[:, 0]
    force = np.asarray(steps["clamp_force"], float)
    gamma = np.asarray(steps["shear_angle"], float)
    nominal = _nominal(results, d)
    fig = new_figure(14, 4)
    by_d, by_angle, angles = fig.subplots(1, 3)
    by_d.plot(1e3 * d, force, marker="o", ms=3)
    by_d.set(xlabel="clamp displacement d [mm]", ylabel="clamp force along d [N]")
    normalised = _normalised_over_the_path(results, d, force)
    by_angle.plot(DEGREE * nominal, normalised, marker="o", ms=3)
    by_angle.set(xlabel="nominal shear angle [deg]", ylabel="normalised shear force [N/m]")
    angles.plot(1e3 * d, DEGREE * nominal, color="k", linestyle="--", label="kinematics")
    if results.attrs["specimen_test"] == "bias_extension":
        zone = np.asarray(results.reference["zone"])
        for z, name in enumerate(ZONES):
            if np.any(zone == z):
                angles.plot(1e3 * d, DEGREE * gamma[:, zone == z].mean(axis=1), marker="o",
                            ms=3, label=f"{name}, mean")
    else:
        interior = np.asarray(results.reference["interior"], bool)
        angles.plot(1e3 * d, DEGREE * gamma[:, interior].mean(axis=1), marker="o", ms=3,
                    label="interior crossings, mean")
    angles.set(xlabel="clamp displacement d [mm]", ylabel="shear angle [deg]")
    for ax in (by_d, by_angle, angles):
        style_axes(ax)
    loaded = d > 0.0  # step 0's force is zero to rounding
    _log_if_wide(by_d, force[loaded])
    _log_if_wide(by_angle, normalised[loaded])
    legend(angles)
    fig.suptitle(f"{results.attrs['specimen_test'].replace('_', ' ')}: force and shear angle "
                 "(docs/model.md section 11)")
    return fig


def _normalised_over_the_path(results: Results, d: np.ndarray, force: np.ndarray) -> np.ndarray:
    """The normalised shear force [N/m] of every step: the frame's as recorded (eq. 10, a
    step's own), the bias extension's from the whole path (Harrison's recursion reads the
    curve from d -> 0+, which a step records only once two loaded steps exist: step 0's
    recorded value is 0, `dynfab.shear_force`)."""
    if results.attrs["specimen_test"] != "bias_extension":
        return np.asarray(results.steps["normalised_shear_force"], float)
    return bias_normalised_shear_force(d, force, float(results.attrs["specimen_width"]),
                                       float(results.attrs["specimen_height"]))


def _log_if_wide(ax, values: np.ndarray) -> None:
    """A logarithmic force axis from half the smallest of `values` (the loaded steps') where
    they are positive and span more than WIDE_RANGE (a picture frame past the lock: its force
    rises a hundredfold in the last steps and a linear axis hides the curve before it)."""
    values = values[np.isfinite(values)]
    if values.size and np.all(values > 0.0) and values.max() > WIDE_RANGE * values.min():
        ax.set_yscale("log")
        ax.set_ylim(bottom=0.5 * values.min())


def plot_shear_field(results: Results) -> Figure:
    """The shear angle of every crossing at its in-plane position, three steps."""
    steps = results.steps
    xy = np.asarray(steps["crossing_positions"], float)
    gamma = DEGREE * np.asarray(steps["shear_angle"], float)
    d = np.asarray(steps["load"], float)[:, 0]
    last = gamma.shape[0] - 1
    chosen = sorted({max(1, round(last / 3)), max(1, round(2 * last / 3)), last}) if last else [0]
    fig = new_figure(4.5 * len(chosen) + 1, 5)
    axes = np.atleast_1d(fig.subplots(1, len(chosen)))
    top = max(float(np.abs(gamma[chosen]).max()), 1e-12)
    for ax, k in zip(axes, chosen):
        shown = ax.scatter(1e3 * xy[k, :, 0], 1e3 * xy[k, :, 1], c=gamma[k], s=12, cmap="viridis",
                           vmin=min(0.0, float(gamma[chosen].min())), vmax=top)
        ax.set(xlabel="x [mm]", ylabel="y [mm]", title=f"d = {1e3 * d[k]:.4g} mm",
               aspect="equal")
    fig.colorbar(shown, ax=list(axes), label="shear angle [deg]")
    fig.suptitle("shear angle at the crossings (from step 0, the preload relaxed)")
    return fig


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
