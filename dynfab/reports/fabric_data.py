"""The fabric report's vocabulary: the cell, its load paths, and the quantities read from a solve.

The report (`dynfab.reports.fabric`: solves, checks, summary) and its drawings
(`dynfab.reports.fabric_plots`) share these names; the drawings read only the data dict
that `solve_paths` returns (also written as ``fabric.json``), so the figures and the JSON
hold the same numbers.

The cell (docs/model.md section 10, boundary "periodic"): the plain-weave repeat of 2 warps x 2
wefts of the paper's yarns (docs/model.md section 7: EA = 13.72 N, EI = 1.47e-7 N m^2,
A = 0.5 mm, C = 0.2 mm, K = 0.2 m/N, crossings L / 16 = 6.25 mm apart), the weft family the
same as the warp (a balanced fabric: the paper's weft has EI_we = EI_wa and C_we = C_wa, and
section 7 takes A_we = A_wa; its EA, absent from the paper, is taken as the warp's), the
default core stiffness, no friction (on the
periodic cell every crossing lies on a mirror plane, so slips stay zero: docs/model.md section 10).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from dynfab.model.geometry import tensioned_beam_stiffness, weft_stiffness
from dynfab.scene import Scene, scene_from_tables

SPACING = 0.1 / 16
"""Crossing spacing [m]: the paper's L / crossings (docs/model.md section 7), both directions."""
YARNS = 2
"""Warps and wefts in the cell (the plain-weave repeat)."""
PAPER_YARN = dict(amplitude=0.5e-3, EA=13.72, EI=1.47e-7, kawabata_C=0.2e-3, kawabata_K=0.2)
"""The paper's yarn (docs/model.md section 7), K = 0.2 m/N where one is needed."""
PAPER_WEFT_LENGTH, PAPER_WEFT_COUNT = 0.1, 16
"""The paper's weft: L_we [m] and the warps N_wa it crosses (runs/paper_fig5.toml)."""

PATHS = {"2:1": (1.0, 0.5), "1:1": (1.0, 1.0), "1:2": (0.5, 1.0), "1:0.05": (1.0, 0.05)}
"""Proportional biaxial paths, name -> (warp, weft) load ratio; the larger of the two loads
rises to the plan's largest load. "1:0.05": the weft held at a small tension (near uniaxial)."""


@dataclass(frozen=True)
class Plan:
    name: str
    segments_per_crossing: int
    """Segments between neighbouring crossings (the paper's N / crossings = 224 / 16 = 14)."""
    steps: int
    """Load steps per path, loads s^2 P_max at s = i / steps (dense where the crimp goes)."""
    largest_load_N: float
    """Largest end force per yarn [N] (1 N: about 8.5 % strain, 160 N/m)."""


FULL = Plan("full", segments_per_crossing=14, steps=40, largest_load_N=1.0)
QUICK = Plan("quick", segments_per_crossing=8, steps=8, largest_load_N=1.0)


def width_per_yarn() -> float:
    """Fabric width per yarn [m], as woven: the spacing of the other family's crossings."""
    return SPACING


def load_fractions(plan: Plan) -> np.ndarray:
    """s^2 at s = i / steps, i = 1..steps (steps,) [-]."""
    return (np.arange(1, plan.steps + 1) / plan.steps) ** 2


def cell_scene(plan: Plan, ratio: tuple[float, float]) -> Scene:
    """The balanced periodic cell under force control along `ratio` (module docstring)."""
    scale = plan.largest_load_N / max(ratio)
    fractions = load_fractions(plan)
    return paper_patch_scene(YARNS, YARNS, plan.segments_per_crossing, SPACING,
                             boundary="periodic",
                             load={"control": "force",
                                   "values": list(scale * ratio[0] * fractions),
                                   "weft_values": list(scale * ratio[1] * fractions)})


def paper_patch_scene(warps: int, wefts: int, segments_per_half_wave: int = 8,
                      pitch: float = SPACING, *, boundary: str = "clamped",
                      planes: str = "fixed", load: dict, **tables) -> Scene:
    """A balanced fabric scene of the paper's yarn (docs/model.md section 7) for both families:
    crossings `pitch` apart both ways (L = pitch n_we, L_we = pitch n_wa), a half-wave of
    crimp of `segments_per_half_wave` segments between neighbouring crossings; `load` the
    [load] table, `tables` any other tables ([friction], [contact], [gravity], [pullout], ...)."""
    yarn = {key: PAPER_YARN[key] for key in ("EA", "EI", "kawabata_C", "kawabata_K")}
    geometry = {"model": "fabric", "length": pitch * wefts, "crossings": wefts,
                "segments": segments_per_half_wave * wefts,
                "amplitude": PAPER_YARN["amplitude"], "boundary": boundary}
    if boundary != "periodic":
        geometry["planes"] = planes
    return scene_from_tables({
        "geometry": geometry, "warp": yarn,
        "weft": {**yarn, "amplitude": PAPER_YARN["amplitude"], "length": pitch * warps,
                 "count": warps, "segments": segments_per_half_wave * warps},
        "load": load, **tables})


def yarn_nodes(positions: np.ndarray, chain_start: np.ndarray, yarn: int) -> np.ndarray:
    """(in-plane coordinate, z) of one yarn's nodes (nodes, 2) [m]."""
    return positions[chain_start[yarn]:chain_start[yarn + 1]]


# --------------------------------------------------------------------------
# Readers of the data dict (one path's entry), shared by the checks and the drawings.


def load_per_width(path: dict, family: str) -> np.ndarray:
    """(steps + 1,) end force per yarn over the width per yarn [N/m], as woven first (0)."""
    return np.asarray(path[f"{family}_load_N_per_m"])


def strain_percent(path: dict, family: str) -> np.ndarray:
    """(steps + 1,) nominal strain [%]: cell stretch over cell length (docs/model.md section 10)."""
    return np.asarray(path[f"{family}_strain_percent"])


def crimp_percent(path: dict, family: str) -> np.ndarray:
    """(steps + 1,) mean crimp of the family [%]."""
    return np.asarray(path[f"{family}_crimp_percent"])


def larger_load(path: dict) -> np.ndarray:
    """(steps + 1,) the larger of the two loads per unit width [N/m] (the path's abscissa)."""
    return np.maximum(load_per_width(path, "warp"), load_per_width(path, "weft"))


EQ4_TENSIONS_N = (0.0, 0.01, 0.1, 0.3, 0.6, 1.0)
"""Weft tensions [N] of the table of paper eq. 4 against the tensioned beam."""


def eq4_against_beam(tensions=EQ4_TENSIONS_N) -> list[dict]:
    """Paper eq. 4 (the one-sine-mode weft stiffness the one-yarn model uses) against the
    tensioned beam with alternating point loads (docs/model.md section 10) on the paper's
    weft (EI, L_we = 0.1 m, N_wa = 16; EA of the warp, the paper giving none), both at the
    stretched length (EI, L_we and Lp times 1 + T/EA) so that only the shape differs."""
    EA, EI = PAPER_YARN["EA"], PAPER_YARN["EI"]
    rows = []
    for T in tensions:
        stretch = 1.0 + T / EA
        eq4 = weft_stiffness(EI * stretch, PAPER_WEFT_LENGTH * stretch, PAPER_WEFT_COUNT, T)
        beam = tensioned_beam_stiffness(T, EA, EI, PAPER_WEFT_LENGTH, PAPER_WEFT_COUNT)
        rows.append({"tension_N": T, "eq4_N_per_m": eq4, "beam_N_per_m": beam,
                     "excess_percent": 100 * (eq4 / beam - 1)})
    return rows
