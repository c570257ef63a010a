"""The load the model prescribes: where a load step starts, and the transient's load in time.

Part of the model (docs/model.md sections 1, 5), not of a solver: every solver
takes its load from here (`dynfab.solvers.contract` states the contracts), so the
static and the dynamic solvers start each load step from the same positions
and neither imports the other.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from dynfab.model.structure import Structure, sliding

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
    """A one-yarn model's starting positions (yarns, N+1, 2) [m] of a load step to `load_value`
    [N or m]: under force control the previous state's (P enters the energy, not the
    positions), under displacement control every yarn's end moved to u (`prescribe_ends`).
    `state` is not modified."""
    positions = state.positions.copy()
    if model.control == "displacement":
        prescribe_ends(model.structure, positions, np.full(model.yarn_count, float(load_value)))
    return model.per_yarn(positions)


def prescribe_ends(structure: Structure, pos: np.ndarray, displacements: np.ndarray) -> None:
    """Displacement control of the chains' ends, in place on the dofs `pos` (n, 2) [m]: each
    chain's last node at x0_N + u (`displacements` (Y,) [m]), the increment of x_N spread
    linearly in x0 along the chain (a better start than moving the end alone). Where the
    crossings slide the spread runs from the chain's last crossing, whose slot holds a
    material coordinate, and the nodes before it stay: the yarn's material moves through the
    crossings (a yarn that has left them moves whole)."""
    f = structure
    crossed = np.zeros(pos.shape[0], bool)
    crossed[np.concatenate([f.tie_a, f.tie_b])] = sliding(f)
    for y in range(f.chain_start.size - 1):
        a, b = f.chain_start[y], f.chain_start[y + 1]
        rest = f.rest_position[a:b, 0]
        increment = displacements[y] - (pos[b - 1, 0] - rest[-1])
        first = a + (np.flatnonzero(crossed[a:b])[-1] if crossed[a:b].any() else 0)
        base = rest[first - a:] - rest[first - a]
        pos[first:b, 0] += increment * base / (rest[-1] - rest[first - a])
        pos[b - 1, 0] = rest[-1] + displacements[y]


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
