"""Stability report figure: ``map.png``, measured against predicted stable time steps.

Drawn from the cases `dynfab.reports.stability.run_stability` measures (matplotlib Figure +
Agg, as dynfab.plots.figures).
"""

from __future__ import annotations

import math

from matplotlib.figure import Figure
from matplotlib.lines import Line2D

from dynfab.plots.style import FONT_SIZE, new_figure
from dynfab.reports.stability_cases import Plan
from dynfab.scene import Dynamic

FAMILY_STYLE = {"baseline": ("k", "*"), "kawabata": ("C0", "o"), "stretch": ("C1", "s"),
                "mesh": ("C2", "^"), "weft": ("C4", "D"), "load": ("C3", "v"),
                "friction": ("#8c2d04", "P"), "reference": ("C9", "X")}


def plot_map(cases: list[dict], plan: Plan) -> Figure:
    """Left: measured against predicted stable dt per case, log-log, with y = x (cases far
    from the cluster named). Right: measured / predicted per case, with the solver's
    default safety factor: a case left of 1 is one where Gershgorin is not on the safe
    side."""
    points = [(c, c["stability"]) for c in cases
              if c.get("stability") and c["stability"].get("measured_dt_s") is not None]
    fig = new_figure(11.5, 0.5 + max(4.8, 0.2 * len(points)))
    ax, ratios = fig.subplots(1, 2, width_ratios=(1.15, 1))
    families, placed = [], []
    for case, stability in points:
        color, marker = FAMILY_STYLE.get(case["family"], ("0.4", "o"))
        style = dict(ls="", marker=marker, ms=7, mew=1.6, color=color, zorder=3,
                     mfc="white" if stability.get("measured_with") == "kinetic damping" else color)
        x, y = stability["predicted_dt_s"], stability["measured_dt_s"]
        ax.plot(x, y, **style)
        if _relaxation_fails(stability):  # energy-stable at that dt, yet no relaxation there
            ax.plot(x, y, ls="", marker="x", ms=12, mew=1.6, color="k", zorder=4)
        if case["family"] not in families:
            families.append(case["family"])
        if stability["measured_over_predicted"] > 1.25 or case["family"] in ("stretch", "mesh"):
            near = sum(abs(math.log10(x / px)) < 0.1 and abs(math.log10(y / py)) < 0.1
                       for px, py in placed)
            left = case["family"] == "stretch"
            ax.annotate(case["case"], (x, y), xytext=(-7 if left else 7, -3 - 9 * near),
                        textcoords="offset points", ha="right" if left else "left",
                        fontsize=FONT_SIZE - 3)
            placed.append((x, y))
    values = [v for _, s in points for v in (s["predicted_dt_s"], s["measured_dt_s"])]
    if values:
        low, high = min(values) / 2, max(values) * 2
        ax.plot([low, high], [low, high], "k-", lw=1)
        ax.set_xlim(low, high)
        ax.set_ylim(low, high)
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_aspect("equal")
    ax.set(xlabel="predicted stable dt (s): Gershgorin, stiffest tangent",
           ylabel="measured stable dt (s): bisection, physical masses")
    handles = [Line2D([], [], ls="", marker=FAMILY_STYLE[f][1], color=FAMILY_STYLE[f][0], label=f)
               for f in families if f in FAMILY_STYLE]
    handles.append(Line2D([], [], color="k", lw=1, label="y = x"))
    if any(_relaxation_fails(s) for _, s in points):
        handles.append(Line2D([], [], ls="", marker="x", ms=9, mew=1.6, color="k",
                              label="relaxation at the measured dt fails"))
    if any(s.get("measured_with") == "kinetic damping" for _, s in points):
        handles.append(Line2D([], [], ls="", marker="o", color="0.3", mfc="white",
                              label="measured with kinetic damping"))
    ax.legend(handles=handles, fontsize=FONT_SIZE - 2, loc="lower right")
    ax.set_title("measured against predicted: above the line, the prediction is safe",
                 fontsize=FONT_SIZE)
    for k, (case, stability) in enumerate(points):
        color, marker = FAMILY_STYLE.get(case["family"], ("0.4", "o"))
        hollow = stability.get("measured_with") == "kinetic damping"
        ratios.plot(stability["measured_over_predicted"], -k, ls="", marker=marker, ms=6, mew=1.4,
                    color=color, mfc="white" if hollow else color, zorder=3)
        if _relaxation_fails(stability):
            ratios.plot(stability["measured_over_predicted"], -k, ls="", marker="x", ms=10,
                        mew=1.6, color="k", zorder=4)
            ratios.annotate("relaxation fails at this dt", (stability["measured_over_predicted"], -k),
                            xytext=(8, -3), textcoords="offset points", fontsize=FONT_SIZE - 3)
    ratios.axvline(1.0, color="k", lw=1, label="measured = predicted")
    ratios.axvline(Dynamic().safety, color="k", lw=1, ls="--",
                   label=f"default safety {Dynamic().safety:g} (dt used with physical masses)")
    ratios.set_yticks([-k for k in range(len(points))], [c["case"] for c, _ in points],
                      fontsize=FONT_SIZE - 2)
    ratios.set_xscale("log")
    ratios.set_xlabel("measured / predicted stable dt (-)")
    ratios.set_ylim(-len(points) + 0.5, 0.5)
    ratios.legend(fontsize=FONT_SIZE - 2, loc="upper right")
    ratios.set_title("measured / predicted per case", fontsize=FONT_SIZE)
    for axis in (ax, ratios):
        axis.tick_params(labelsize=FONT_SIZE)
        axis.xaxis.label.set_size(FONT_SIZE)
        axis.yaxis.label.set_size(FONT_SIZE)
        axis.grid(True, which="both", alpha=0.3)
    ratios.tick_params(axis="y", labelsize=FONT_SIZE - 2)
    fig.suptitle(f"Stable time step of symplectic Euler with the physical masses ({plan.name} "
                 f"plan: {plan.crossings} crossings, N = {plan.segments} unless named)",
                 fontsize=FONT_SIZE + 1)
    return fig


def _relaxation_fails(stability: dict) -> bool:
    """A case whose load step, relaxed at the measured stable dt, did not converge: stable in
    energy is not enough to relax (friction's stick/slip), and the figure must say so."""
    return stability.get("relaxation_at_measured_dt", {}).get("verdict") == "failed"
