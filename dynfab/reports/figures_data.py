"""The figures report's vocabulary: its four result files and the quantities read from them.

The report (`dynfab.reports.figures`: solves, comparison, trend checks) and its drawings
(`dynfab.reports.figures_plots`) both read the result files through these names, so each
quantity (force per width, the friction gap, the K order...) is computed in one place.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from dynfab.results.friction_states import friction_states
from dynfab.results.file import Results, read_results
from dynfab.scene import Scene, expand_sweep, parse_scene_text

FIGURES = {"fig3": "paper_fig3.toml", "fig5": "paper_fig5.toml"}
"""The report's scenes: name -> scene file in runs/ (`common.RUNS`)."""

SOLVERS = ("static", "dynamic")

STRAIN_STAGE = 0.05
"""The paper's end of the first stage of Fig. 5: 5 mm on the 0.1 m yarn, 5 % strain."""


# --------------------------------------------------------------------------
# The result files.


def result_name(figure: str, solver: str) -> str:
    """The result file of one scene and solver, e.g. ``fig3_dynamic.h5``."""
    return f"{figure}_{solver}.h5"


def read_figure_data(folder) -> dict[tuple[str, str], Results]:
    """The four result files of the report folder, by (figure, solver)."""
    folder = Path(folder)
    return {(name, solver): read_results(folder / result_name(name, solver))
            for name in FIGURES for solver in SOLVERS}


# --------------------------------------------------------------------------
# Quantities read from a result file.


def scene_of(results: Results) -> Scene:
    """The scene a result file was written from (its ``scene`` attribute)."""
    return parse_scene_text(results.attrs["scene"], source="the result file's scene attribute")


def width(results: Results) -> float:
    """Fabric width per warp yarn [m] (force per unit width = P / width)."""
    return float(results.attrs["width_per_yarn"])


def length(results: Results) -> float:
    return float(results.attrs["projected_length"])


def strain_percent(results: Results) -> np.ndarray:
    """(steps, yarns) end displacement / L [%]."""
    return 100 * results.steps["end_displacement"] / length(results)


def force_per_width(results: Results) -> np.ndarray:
    """(steps, yarns) P / width [N/m]."""
    return results.steps["end_force"] / width(results)


def mean_contact_force(results: Results) -> np.ndarray:
    """(steps, yarns) contact force averaged over the crossings [N]."""
    return results.steps["contact_force"].mean(axis=-1)


def kawabata_K(results: Results) -> np.ndarray:
    """Warp K [m/N] of each yarn (sweep entry)."""
    return np.array([s.warp.kawabata_K for s in expand_sweep(scene_of(results))])


def friction_on(results: Results) -> np.ndarray:
    """(yarns,) True where the yarn has a non-zero Gralen law."""
    return np.array([s.friction is not None and (s.friction.alpha > 0 or s.friction.beta > 0)
                     for s in expand_sweep(scene_of(results))])


def solver_pair(data, figure):
    return data[(figure, "static")], data[(figure, "dynamic")]


def at_strain(results: Results, values: np.ndarray, strain: float) -> float:
    """`values` (steps,) of yarn 0's path, linearly interpolated at `strain` [-]."""
    return float(np.interp(100 * strain, strain_percent(results)[:, 0], values))


def k_order(results: Results) -> np.ndarray:
    return np.argsort(kawabata_K(results))


def friction_split(results: Results) -> tuple[int, int]:
    on = friction_on(results)
    return int(np.flatnonzero(on)[0]), int(np.flatnonzero(~on)[0])


def friction_gap(results: Results) -> np.ndarray:
    on, off = friction_split(results)
    q = force_per_width(results)
    return q[:, on] - q[:, off]


def state_codes(results: Results, yarn: int) -> np.ndarray:
    """(steps, crossings) friction state codes of one yarn (`dynfab.results.friction_states`)."""
    return friction_states(results, yarn)
