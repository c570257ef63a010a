"""The one record layout and a result file's view of it (docs/model.md, "The record layout").

Every model holds its nodal arrays in the structure's layout, (n, dim) in chain order, and its
per-crossing arrays in the scene's crossing order, (C, ...) (a tie's through
`StructureNow.per_tie`). A result file lays them out per test, as views of those flat arrays
that users' files, `dynfab plot`, the XDMF view, the fits and the studies read:

- one yarn: positions (yarns, N+1, 2); the crossings (yarns, C); of an anchor its first
  column, the slip, alone;
- a fabric: positions (n_wa, N+1, 2) and weft_positions (n_we, M+1, 2); the crossings
  (n_wa, n_we);
- a specimen: positions (n, 3) and the crossings (C,) as they are.

`RecordLayout` is that view and its inverse (what a resumed run reads back).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

FRAME_NODAL = ("positions", "velocities", "force")
"""The nodal arrays of a transient's frame (`dynfab.solvers.contract.FRAME_KEYS`)."""


@dataclass(frozen=True)
class RecordLayout:
    """How a result file lays out a model's flat arrays (module docstring)."""

    blocks: tuple[tuple[str, int, int], ...]
    """(dataset prefix, chains, nodes per chain) of each family's block of nodes, in chain
    order; () where the file holds the nodes flat."""
    crossings: tuple[int, ...]
    """The shape of the crossings' axes in the file: (yarns, C), (n_wa, n_we) or (C,)."""
    dim: int
    """Coordinates per node [-]: 2 in the plane, 3 in space."""
    anchor_columns: int
    """Of each anchor's columns, how many the file holds; 1: the first alone, without its
    axis (a one-yarn model's slips along its yarn)."""

    @property
    def prefixes(self) -> list[str]:
        """The dataset prefix of each node block ("" alone where the nodes are flat)."""
        return [prefix for prefix, _, _ in self.blocks] or [""]

    def blocks_of(self, flat) -> list[np.ndarray]:
        """A nodal array (n, ...) as each family's block (chains, nodes, ...): views."""
        flat = np.asarray(flat)
        if not self.blocks:
            return [flat]
        out, start = [], 0
        for _, chains, nodes in self.blocks:
            stop = start + chains * nodes
            out.append(flat[start:stop].reshape(chains, nodes, *flat.shape[1:]))
            start = stop
        return out

    def nodes(self, name: str, flat) -> dict:
        """A nodal array (n, ...) as the file's datasets {prefix + name: block}."""
        return {prefix + name: block
                for prefix, block in zip(self.prefixes, self.blocks_of(flat))}

    def flat_nodes(self, name: str, record) -> np.ndarray:
        """The file's datasets of the nodal array `name` back as one (n, dim) array (a copy)."""
        return np.concatenate([np.asarray(record[prefix + name], float).reshape(-1, self.dim)
                               for prefix in self.prefixes])

    def per_crossing(self, values) -> np.ndarray:
        """Per-crossing `values` (C, ...) in the file's layout (crossings..., ...): a view."""
        values = np.asarray(values)
        return values.reshape(*self.crossings, *values.shape[1:])

    def anchors(self, anchors) -> np.ndarray:
        """The anchors (C, k) as the file holds them (`anchor_columns` of each): a copy."""
        anchors = np.asarray(anchors)
        if self.anchor_columns == 1:
            return np.ascontiguousarray(anchors[:, 0].reshape(self.crossings))
        return self.per_crossing(anchors[:, :self.anchor_columns].copy())

    def flat_anchors(self, stored, width: int) -> np.ndarray:
        """The file's anchors back as (C, `width`): the columns it holds, 0 in the others."""
        stored = np.asarray(stored, float).reshape(-1, self.anchor_columns)
        out = np.zeros((stored.shape[0], width))
        out[:, :self.anchor_columns] = stored
        return out

    def frame_nodes(self, arrays: dict) -> dict:
        """A transient's flat nodal arrays (`FRAME_NODAL`, (n, dim)) as the frame's datasets
        (`nodes`): the inverse of `frame_arrays`' nodes."""
        out = {}
        for name in FRAME_NODAL:
            out.update(self.nodes(name, np.asarray(arrays[name], float)))
        return out

    def frame_arrays(self, frame: dict, anchor_width: int) -> dict:
        """A transient frame's positions, velocities, force (n, dim) and anchors
        (C, `anchor_width`) as the flat arrays, and its time: what a resumed transient
        restores (`dynfab.solvers.contract.RunModel.frame_arrays`)."""
        out = {name: self.flat_nodes(name, frame) for name in FRAME_NODAL}
        return {**out, "anchors": self.flat_anchors(frame["anchors"], anchor_width),
                "time": float(frame["time"])}
