"""The model's domain: a yarn that has folded back is outside it (docs/model.md, "What
the model is not").

Every yarn is a plane chain that runs along its axis: warps along x, wefts along y
(docs/model.md sections 1, 10). Its energy cannot tell a segment that points backwards
from one that points forwards: the stretch springs see lengths and the bending springs
turning angles, and a yarn mirrored end for end has the same of both. So under enough
compression a load step can converge, with a small residual and a positive definite
Hessian, to a yarn that has turned a segment by more than 90 degrees or passed through
itself (measured: the paper yarn under -0.1 N of force control ends 184 % shorter than
its length, its end beyond its first node; a periodic cell under -0.5 N per yarn both
ways, -171 %). That is an equilibrium of the discrete energy and not of a yarn, so a run
stops there (`SolverError`, exit status 3), naming the yarn and segment, instead of
writing it as a result.
"""

from __future__ import annotations

from typing import Callable, Sequence

import numpy as np

from dynfab.errors import SolverError


def first_fold(chains: np.ndarray) -> tuple[int, int, float] | None:
    """(yarn, segment, along-axis extent [m]) of the first segment, in yarn then segment
    order, whose along-axis extent (in-plane coordinate of its end minus its start) is not
    positive, or None. `chains` is (yarns, nodes, 2) [m]: (in-plane coordinate, z)."""
    extent = np.diff(np.asarray(chains, float)[:, :, 0], axis=1)
    folded = ~(extent > 0.0)  # a NaN counts as folded: never a silent NaN
    if not folded.any():
        return None
    yarn, segment = np.argwhere(folded)[0]
    return int(yarn), int(segment), float(extent[yarn, segment])


def check_not_folded(record: dict, labels: Sequence[str] | Callable[[], Sequence[str]]) -> None:
    """Raise SolverError if a yarn of the step's record has folded back (`first_fold`).

    `record["positions"]` holds the yarns of the one-yarn model or a fabric's warps, and
    a fabric's record also `weft_positions`; `labels` names them in that order (or makes
    them: called only when a yarn has folded, so that a run does not build every yarn's
    label at every step)."""
    chains = [np.asarray(record["positions"], float)]
    if "weft_positions" in record:
        chains.append(np.asarray(record["weft_positions"], float))
    offset = 0
    for family in chains:
        fold = first_fold(family)
        if fold is not None:
            yarn, segment, extent = fold
            names = labels() if callable(labels) else labels
            raise SolverError(
                f"{names[offset + yarn]} folded back at segment {segment + 1} (its extent "
                f"along the yarn is {extent:.3g} m): the load has turned the yarn beyond the "
                f"model's domain (docs/model.md, what the model is not)")
        offset += family.shape[0]
