"""The precision study's vocabulary: the methods it compares, and what is read from its
points (the usable ones, the plotted error, the Pareto fronts, the cheapest).

The study (`dynfab.reports.precision`), its figures (`precision_plots`) and its table
(`precision_tables`) all import these names from here.
"""

from __future__ import annotations

from dataclasses import dataclass

from dynfab.scene import Dynamic

@dataclass(frozen=True)
class Method:
    """One curve of the study: a dynamic solver configuration, swept over tolerances."""

    key: str
    label: str
    options: Dynamic
    critical_factor: float | None = None
    """Viscous c = this x the critical damping of the lowest mode (None: options' c)."""
    style: tuple[str, str, str] = ("C0", "o", "-")
    """(colour, marker, line style) in the figures."""


METHODS = {m.key: m for m in (
    Method("kinetic", "explicit, kinetic", Dynamic(damping="kinetic"), style=("#1f77b4", "o", "-")),
    Method("kinetic_safety_0.5", "explicit, kinetic, safety 0.5",
           Dynamic(damping="kinetic", safety=0.5), style=("#6baed6", "o", "--")),
    Method("kinetic_safety_0.99", "explicit, kinetic, safety 0.99",
           Dynamic(damping="kinetic", safety=0.99), style=("#08306b", "o", "-.")),
    Method("kinetic_physical", "explicit, kinetic, physical masses",
           Dynamic(damping="kinetic", masses="physical"), style=("#17becf", "o", ":")),
    Method("viscous", "explicit, viscous (adaptive c)", Dynamic(damping="viscous"),
           style=("#ff7f0e", "s", "-")),
    Method("viscous_physical", "explicit, viscous (adaptive c), physical masses",
           Dynamic(damping="viscous", masses="physical"), style=("#fdae6b", "s", ":")),
    Method("viscous_c0.5", "explicit, viscous, c = 0.5 c_crit", Dynamic(damping="viscous"),
           critical_factor=0.5, style=("#8c564b", "v", "--")),
    Method("viscous_c1", "explicit, viscous, c = c_crit", Dynamic(damping="viscous"),
           critical_factor=1.0, style=("#d62728", "v", "-")),
    Method("viscous_c2", "explicit, viscous, c = 2 c_crit", Dynamic(damping="viscous"),
           critical_factor=2.0, style=("#e377c2", "v", "-.")),
    Method("fire", "explicit, FIRE 2.0", Dynamic(damping="fire"), style=("#2ca02c", "^", "-")),
    Method("fire_physical", "explicit, FIRE 2.0, physical masses",
           Dynamic(damping="fire", masses="physical"), style=("#98df8a", "^", ":")),
    Method("semi_implicit", "semi_implicit", Dynamic(method="semi_implicit"),
           style=("#9467bd", "D", "-")),
    Method("semi_implicit_physical", "semi_implicit, physical masses",
           Dynamic(method="semi_implicit", masses="physical"), style=("#c5b0d5", "D", ":")),
    Method("kinetic_float32", "explicit, kinetic, float32",
           Dynamic(damping="kinetic", precision="float32"), style=("#1f77b4", "o", (0, (1, 3)))),
    Method("viscous_float32", "explicit, viscous (adaptive c), float32",
           Dynamic(damping="viscous", precision="float32"), style=("#ff7f0e", "s", (0, (1, 3)))),
    Method("fire_float32", "explicit, FIRE 2.0, float32",
           Dynamic(damping="fire", precision="float32"), style=("#2ca02c", "^", (0, (1, 3)))),
    Method("semi_implicit_float32", "semi_implicit, float32",
           Dynamic(method="semi_implicit", precision="float32"),
           style=("#9467bd", "D", (0, (1, 3)))),
)}
"""Every method of the full report, in legend order."""


def method_label(key: str) -> str:
    """A point's method as labelled (legends break it over lines): static, L-BFGS-B or METHODS."""
    return {"static_reference": "static Newton to the floor\n(the reference)",
            "static_newton": "static Newton at the\nscene's tolerance",
            "lbfgs": "scipy L-BFGS-B"}.get(key) or METHODS[key].label


# --------------------------------------------------------------------------
# Points, Pareto fronts and the cheapest methods.


def shown_error(point: dict, floor: float) -> float:
    """The relative error as plotted: no lower than the position rounding floor."""
    return max(point["relative_error"], floor)


def usable_points(points: list[dict]) -> list[dict]:
    return [p for p in points if p["status"] != "failed"]


def dominates(a: dict, b: dict, cost: str, floor: float) -> bool:
    """a is at most as costly and as wrong as b, and strictly better in one of the two."""
    ca, cb = a[cost], b[cost]
    ea, eb = shown_error(a, floor), shown_error(b, floor)
    return ca <= cb and ea <= eb and (ca < cb or ea < eb)


def pareto_front(points: list[dict], cost: str, floor: float = 0.0) -> list[dict]:
    """The dynamic points no other dynamic point dominates in `cost` and (floored)
    relative error, sorted by cost. (The static Newton solves, reference points, are left
    out: they are faster than nearly every dynamic solve of the same accuracy.)"""
    dynamic = [p for p in usable_points(points) if p["solver"] == "dynamic"]
    front = [p for p in dynamic if not any(dominates(q, p, cost, floor) for q in dynamic)]
    return sorted(front, key=lambda p: (p[cost], shown_error(p, floor)))


def pareto_fronts(points: list[dict], floor: float) -> dict[str, set[int]]:
    """The ids on the dynamic front of each cost, errors floored at `floor`."""
    return {cost: {p["id"] for p in pareto_front(points, cost, floor)}
            for cost in ("wall_time_s", "force_evaluations")}


def cheapest(points: list[dict], target: float, cost: str) -> dict | None:
    """The dynamic point of least `cost` (then least wall time) reaching `target`."""
    reaching = [p for p in usable_points(points) if p["solver"] == "dynamic"
                and p["relative_error"] <= target]
    if not reaching:
        return None
    return min(reaching, key=lambda p: (p[cost], p["wall_time_s"]))
