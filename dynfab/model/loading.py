"""The load the model prescribes: where a load step starts, and the transient's load in time.

Part of the model (docs/model.md sections 1, 5), not of a solver: every solver
takes its load from here (`dynfab.solvers.contract` states the contracts), so the
static and the dynamic solvers start each load step from the same positions
and neither imports the other.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

RELAXATION_STEPS = {"yarn": 0, "fabric": 0, "specimen": 1}
"""Steps a run of each kind writes before its load path: a specimen's step 0, its preload
relaxed at d = 0 (the models' `relaxation_steps`)."""


class Drive(NamedTuple):
    """What a transient's kernel drives (`kernels/structure_transient.py`, docs/model.md
    section 5): `path` (rows, K) [N or m], each row's values at t = k T / K, k = 1..K (the
    ramp starts at 0); `driven` None (the structure's load nodes, one row per load family,
    `family_drive`) or (first row (n,), direction (n, dim)) per node (-1: not driven), a held
    node's component c following row first + c."""

    path: np.ndarray
    driven: tuple[np.ndarray, np.ndarray] | None = None


def family_drive(model) -> Drive:
    """The transient's drive of a model whose load path is one value per load family and step
    (the yarn's and the fabric's): the path itself, one row per family."""
    values = np.asarray(model.load_values, float)
    return Drive(values.reshape(values.shape[0], -1).T)


def prescribe_load(model, state, load_value: float) -> np.ndarray:
    """The starting positions (yarns, N+1, 2) [m] of a load step to `load_value` [N or m].

    Under force control, the previous state's positions (P enters the energy, not the
    positions). Under displacement control, x_N = x0_N + u, and the increment of x_N
    spread linearly in x0 along the yarn (a better start than moving the end alone).
    `state` is not modified.
    """
    positions = state.positions.copy()
    if model.control == "displacement":
        rest = model.stacked("rest_position")
        length = rest[:, -1:, 0]
        increment = load_value - (positions[:, -1, 0] - rest[:, -1, 0])
        positions[:, :, 0] += increment[:, None] * rest[:, :, 0] / length
        positions[:, -1, 0] = rest[:, -1, 0] + load_value
    return positions


def load_at_time(model, time: float):
    """The transient's load [N or m] at `time` [s] (docs/model.md section 5): piecewise linear
    through (0, 0) and (k T / n, value_k), k = 1..n, T = dynamic.duration, held after T; a
    float for a one-yarn path (n,), one value per family for a fabric's (n, 2).

    The transient kernel evaluates the same ramp on the device (`kernels/structure_transient.py`
    load_at); this is its host side, for the frames.
    """
    values = np.asarray(model.load_values, float)
    duration = model.scene.dynamic.duration
    times = np.linspace(0.0, duration, values.shape[0] + 1)
    if values.ndim == 1:
        return float(np.interp(time, times, np.append(0.0, values)))
    return np.array([np.interp(time, times, np.append(0.0, column)) for column in values.T])
