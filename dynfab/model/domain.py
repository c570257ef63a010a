"""The model's domain: a yarn that has folded back is outside it (docs/model.md, "What
the model is not"), and so is a fabric's crossing whose node has slid more than half a
segment from it (docs/model.md section 10, "Crossings at fixed nodes": `slip_ratios`,
`check_crossings_held`).

Every yarn is a plane chain that runs along its axis: warps along x, wefts along y
(docs/model.md sections 1, 10). Its energy cannot tell a segment that points backwards
from one that points forwards: the stretch springs see lengths and the bending springs
turning angles, and a yarn mirrored end for end has the same of both. So under enough
compression a load step can converge, with a small residual and a positive definite
Hessian, to a yarn that has turned a segment by more than 90 degrees or passed through
itself (as the paper yarn under -0.1 N of force control does, its end beyond its first
node, and a periodic cell under -0.5 N per yarn both ways: tests/test_domain.py;
docs/results.md, "Folded yarns"). That is an equilibrium of the discrete energy and not
of a yarn, so a run stops there (`SolverError`, exit status 3), naming the yarn and
segment, instead of writing it as a result.
"""

from __future__ import annotations

from typing import Callable, Sequence

import numba
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


def check_not_folded(families: Sequence[np.ndarray],
                     labels: Sequence[str] | Callable[[], Sequence[str]]) -> None:
    """Raise SolverError if a yarn of a step has folded back (`first_fold`).

    `families` holds each family's yarns (yarns, nodes, 2) [m] (a one-yarn model's yarns, or
    a fabric's warps and wefts); `labels` names the yarns in that order (or makes them:
    called only when a yarn has folded, so that a run does not build every yarn's label at
    every step)."""
    offset = 0
    for family in (np.asarray(chains, float) for chains in families):
        fold = first_fold(family)
        if fold is not None:
            yarn, segment, extent = fold
            names = labels() if callable(labels) else labels
            raise SolverError(
                f"{names[offset + yarn]} folded back at segment {segment + 1} (its extent "
                f"along the yarn is {extent:.3g} m): the load has turned the yarn beyond the "
                f"model's domain (docs/model.md, what the model is not)")
        offset += family.shape[0]


SLIP_LIMIT = 0.5
"""The largest slip ratio (`slip_ratios`) a fabric's step may reach: beyond half a segment
another node of the yarn is nearer the crossing than the node that carries its contact
(docs/model.md section 10, "Crossings at fixed nodes")."""


def slip_ratios(chains: np.ndarray, crossing_nodes: np.ndarray, planes: np.ndarray) -> np.ndarray:
    """(yarns, crossings) slip ratio [-] of each crossing node (docs/model.md section 10,
    "Crossings at fixed nodes"): its in-plane offset from the crossing yarn's plane,
    |x_n - X|, over the in-plane extent of its segment towards that plane (x_n - x_{n-1}
    when the node has passed the plane, x_{n+1} - x_n otherwise). As woven every crossing
    node lies on its plane (0); above 1/2 the node's neighbour is nearer the crossing.

    `chains` (yarns, nodes, 2) [m] holds (in-plane coordinate, z); `crossing_nodes`
    (crossings,) the node of each crossing; `planes` [m] the crossing yarns' planes where
    the step leaves them, (crossings,) or (yarns, crossings). A folded segment (extent not
    positive, `first_fold`) gives inf or NaN, never a small ratio."""
    x = np.asarray(chains, float)[:, :, 0]
    nodes = np.asarray(crossing_nodes, np.int64)
    ratios = np.empty((x.shape[0], nodes.size))
    _slip_ratios(x, nodes, np.broadcast_to(np.asarray(planes, float), ratios.shape), ratios)
    return ratios


@numba.njit(cache=True)
def _slip_ratios(x, nodes, planes, ratios):
    """`slip_ratios` into `ratios` (a loop: a paper step's observables call it on 16 crossings,
    where numpy's calls cost more than the arithmetic)."""
    for k in range(x.shape[0]):
        for j in range(nodes.size):
            n = nodes[j]
            offset = x[k, n] - planes[k, j]
            extent = x[k, n] - x[k, n - 1] if offset > 0 else x[k, n + 1] - x[k, n]
            ratios[k, j] = abs(offset) / extent if extent > 0 else np.inf


def fabric_slip_ratios(record: dict, crossing_nodes: np.ndarray,
                       weft_crossing_nodes: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """A fabric step's slip ratios (`slip_ratios`): the warps' crossing nodes against the
    wefts' planes x = X_j, (n_wa, n_we), and the wefts' against the warps' planes y = Y_k,
    (n_we, n_wa); the record's `positions`, `weft_positions`, `warp_planes`, `weft_planes`."""
    return (slip_ratios(record["positions"], crossing_nodes, record["weft_planes"]),
            slip_ratios(record["weft_positions"], weft_crossing_nodes, record["warp_planes"]))


def check_crossings_held(record: dict, crossing_nodes: np.ndarray,
                         weft_crossing_nodes: np.ndarray, suggest_affine: bool = False) -> None:
    """Raise SolverError if a fabric step has carried a crossing node more than half a
    segment from the crossing (`fabric_slip_ratios` above SLIP_LIMIT), naming the crossing
    as the scene counts it, (warp k, weft j), and the yarn whose node slid.
    `suggest_affine`: a clamped patch on fixed planes, not a pull-out, where a uniform
    stretch alone slides every crossing node (docs/model.md section 10) and "affine"
    planes would not: the message says so."""
    ratio, family, yarn, crossing = 0.0, "warp", 0, 0
    for name, ratios in zip(("warp", "weft"),
                            fabric_slip_ratios(record, crossing_nodes, weft_crossing_nodes)):
        ratios = np.where(np.isnan(ratios), np.inf, ratios)  # never a silent NaN
        if ratios.size and ratios.max() > ratio:
            ratio, family = float(ratios.max()), name
            yarn, crossing = np.unravel_index(np.argmax(ratios), ratios.shape)
    if ratio <= SLIP_LIMIT:
        return
    k, j = (yarn, crossing) if family == "warp" else (crossing, yarn)
    other, plane = ("weft", f"x = X_{j + 1}") if family == "warp" else ("warp", f"y = Y_{k + 1}")
    hint = ("; with geometry.planes = \"fixed\" a stretched yarn slides by its strain "
            "times the plane's distance from its first node: \"affine\" planes move with the "
            "patch" if suggest_affine else "")
    raise SolverError(
        f"crossing (warp {k + 1}, weft {j + 1}): {family} {yarn + 1}'s node there has slid "
        f"{ratio:.3g} of its segment from the {other}'s plane {plane} (at most "
        f"{SLIP_LIMIT:g}): another node of the {family} is now nearer the crossing, which the "
        f"model keeps on a fixed pair of nodes, so its contact and friction no longer act where "
        f"the yarns cross (docs/model.md section 10, crossings at fixed nodes){hint}")
