"""The open/closed active set of the crossings and the continuation in R_0 (docs/model.md
section 4): the pieces the one-yarn static solver (`dynfab.static`) and the fabric's
(`dynfab.fabric.static`) share. Each solver holds every crossing's contact branch fixed
(`dynfab.terms.contact`: OPEN, CLOSED) during a Newton solve, updates the set where the
state contradicts it (`update_set`), and where that fails from the previous step's state,
lowers R_0 from CONTINUATION_START to the scene's value (`onset_stages`).
"""

from __future__ import annotations

import numpy as np

from dynfab.terms import contact

MAX_FLIPS = 12
"""Open/closed switches of one crossing after which the iteration is declared cycling (the
literal jump law, R_0 = 0)."""
MAX_SET_UPDATES = 40
"""Open/closed set updates per continuation stage with an onset force (docs/model.md section 4)."""
DIRECT_SET_UPDATES = 4
"""Set updates tried at the scene's R_0 before the continuation (most steps need 0 or 1)."""
DIRECT_ITERATIONS = 50
"""Newton iterations per set in that first attempt."""
CONTINUATION_FACTORS = (2.0, 1.25, 1.05)
"""R_0 falls by this factor per stage, the next one if the continuation fails (a factor of
10 was tried and dropped: docs/model.md, "Decisions", friction onset)."""
CONTINUATION_START = 1e-3
"""R_0 [N] the continuation starts from (docs/model.md section 4: Newton converges there in about 20
iterations from the previous step's state on the paper's yarn)."""


def update_set(g, branch, seen) -> np.ndarray:
    """Switch the crossings whose branch the closures g [m] contradict; returns their indices.

    A closed crossing needs R >= 0 (g >= 0), an open one g <= 0 (docs/model.md section 4); where
    both hold (g = 0) the two branches agree. All of them switch at once, unless that
    gives a set already tried (`seen`, the sets as bytes): then only the one that
    contradicts its branch most, then the next ones, one at a time. Returns an empty
    array when consistent, None when every choice was tried.
    """
    wrong = ((branch == contact.CLOSED) & (g < 0.0)) | ((branch == contact.OPEN) & (g > 0.0))
    indices = np.flatnonzero(wrong)
    if indices.size == 0:
        return indices
    candidates = [np.array([j]) for j in indices[np.argsort(-np.abs(g[indices]))]] + [indices]
    for switch in candidates:
        trial = branch.copy()
        trial[switch] = contact.OPEN + contact.CLOSED - trial[switch]
        if trial.tobytes() not in seen:
            branch[:] = trial
            seen.add(trial.tobytes())
            return switch
    return None


def onset_stages(target: float, factor: float):
    """The R_0 [N] of the continuation's stages: CONTINUATION_START (or `target` if larger),
    divided by `factor` per stage, ending at `target` > 0 (docs/model.md section 4)."""
    onset = max(CONTINUATION_START, target)
    while onset != target:
        yield onset
        onset = max(target, onset / factor)
    yield target
