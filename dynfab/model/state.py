"""What changes during a one-yarn model's run: its `State` (docs/model.md sections 1-4), and the
as-woven start of a run.

A Model (`dynfab.model.yarn`) does not change during a run; a State does: the yarns' positions,
their friction anchors, the energy friction has dissipated, the load last applied.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np



@dataclass
class State:
    """What changes during a run, for every yarn."""

    positions: np.ndarray
    """Node positions (yarns, N+1, 2) [m]."""
    anchors: np.ndarray
    """Friction anchors xi (yarns, C) [m] (docs/model.md section 4)."""
    dissipated: np.ndarray
    """Cumulative friction dissipation (yarns,) [J]."""
    load: np.ndarray
    """The load last applied (yarns,) [N or m]; 0 at the as-woven start."""

    def copy(self) -> "State":
        return State(self.positions.copy(), self.anchors.copy(), self.dissipated.copy(),
                     self.load.copy())


def initial_state(model) -> State:
    """The as-woven geometry, anchors at the as-woven crossing positions, nothing dissipated."""
    positions = model.stacked("rest_position").copy()
    nodes = model.yarns[0].crossing_node
    return State(positions=positions, anchors=positions[:, nodes, 0].copy(),
                 dissipated=np.zeros(model.yarn_count), load=np.zeros(model.yarn_count))
