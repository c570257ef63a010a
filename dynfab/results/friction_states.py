"""The friction state of each crossing at each load step, read from a result file
(`dynfab.results.file` layout): open, sticking or sliding, with the colours every figure draws
them in (`dynfab.plots.figures`'s friction.png, the `dynfab reports` figures)."""

from __future__ import annotations

import numpy as np

from dynfab.results.file import Results

FRICTION_STATES = (("open", "#d9d9d9"), ("sticking", "#1f77b4"), ("sliding", "#d62728"))
"""Categories of `friction_states`, in code order, with their colours."""


def crossing_count(results: Results) -> int:
    """Crossings per yarn (0 for a plain rod)."""
    nodes = results.reference.get("crossing_nodes")
    if nodes is not None:
        return int(np.size(nodes))
    contact = results.steps.get("contact_force")
    return 0 if contact is None else int(contact.shape[-1])


def friction_states(results: Results, yarn: int = 0) -> np.ndarray:
    """(steps, crossings) state codes of yarn `yarn` (from 0): 0 open, 1 sticking, 2 sliding.

    A crossing is open when its contact force is zero (or, without contact
    forces in the file, its friction limit is zero).
    """
    count = crossing_count(results)
    source = results.steps.get("contact_force", results.steps.get("friction_limit"))
    force = np.asarray(source, dtype=float).reshape(results.step_count, -1, count)[:, yarn]
    states = np.where(force > 0, 1, 0)
    sliding = results.steps.get("sliding")
    if sliding is not None:
        slide = np.asarray(sliding).reshape(results.step_count, -1, count)[:, yarn].astype(bool)
        states = np.where(slide & (force > 0), 2, states)
    return states
