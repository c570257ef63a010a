"""Layout of the two in-plane shear specimens of a plain weave (docs/model.md section 11).

Where the yarns, their nodes and their crossings lie, which nodes are held, and the tests'
nominal kinematics, for the bias-extension and picture-frame tests (Cao et al., Composites A
39 (2008) 1037-1053). Plain numpy: it runs once per scene.

The weave (docs/model.md section 11): with t_wa, t_we the unit in-plane directions of the
warps and the wefts, crossing (k, j) lies at centre + k p_wa t_we + j p_we t_wa (p_wa the
warp spacing, p_we the weft spacing); warp k runs along t_wa, weft j along t_we. At crossing
(k, j) the warp lies above where k + j is even. Along a yarn of crossing pitch p (a warp's
pitch is the weft spacing) and amplitude A, z = +-A cos(pi s / p), s the in-plane arc
position from the yarn's crossing with index 0 of the other family.

Every chain runs along +t of its family, and t has a positive component along the pull
(bias: +y; frame: the diagonal (1, 1)/sqrt(2)), so the in-plane chord from node n-1 to node
n+1 of a chain has that positive component too (the sign convention of the shear angle).
"""

from __future__ import annotations

import math
import numbers
from typing import NamedTuple

import numpy as np

from dynfab.errors import UserError

BIAS = "bias_extension"
FRAME = "picture_frame"
_SQRT_HALF = math.sqrt(0.5)
_RELATIVE_TOLERANCE = 1e-9
"""On-the-boundary tolerance, relative to the specimen's size (the brief's 1e-9)."""


class Layout(NamedTuple):
    """The as-woven (stress-free) layout of a shear specimen; indices are int64."""

    test: str                       # BIAS or FRAME
    positions: np.ndarray           # (n, 3) [m], chain after chain
    chain_start: np.ndarray         # (Y+1,): chain y holds nodes chain_start[y]..chain_start[y+1]-1
    chain_family: np.ndarray        # (Y,): 0 warp, 1 weft
    chain_index: np.ndarray         # (Y,): lattice index k (warps) or j (wefts), signed
    crossing_nodes: np.ndarray      # (C, 2): (warp node, weft node)
    crossing_lattice: np.ndarray    # (C, 2): (k, j)
    crossing_side: np.ndarray       # (C,): +1 where the warp lies above the weft
    held: np.ndarray                # (n,) bool: held in x, y, z
    zone: np.ndarray                # (C,): bias 0 A, 1 B, 2 C (clamped yarns); frame 0
    interior: np.ndarray            # (C,) bool: a crossing on each side along both yarns
    lateral: np.ndarray             # (L, 4): (A_prev, A_next, A, B) lateral-contact stencils
    lateral_sign: np.ndarray        # (L,): sign of cross2(A_next - A_prev, B - A) at rest
    width: float                    # [m] bias W; frame L
    height: float                   # [m] bias H; frame L


class _Weave(NamedTuple):
    """The crossing lattice of a plain weave laid in a specimen's plane."""

    centre: np.ndarray              # (2,) [m]
    direction: tuple                # (t_wa, t_we), unit (2,) vectors
    spacing: tuple                  # (warp spacing, weft spacing) [m]
    amplitude: tuple                # (warp, weft) crimp half-heights [m]
    segments: int                   # segments between consecutive crossings

    def pitch(self, family: int) -> float:
        """Arc length [m] between a yarn's consecutive crossings: the other family's spacing."""
        return self.spacing[1 - family]

    def point(self, k, j) -> np.ndarray:
        """In-plane positions (..., 2) [m] of crossings (k, j); one formula for both yarns."""
        k = np.asarray(k, dtype=float)[..., None]
        j = np.asarray(j, dtype=float)[..., None]
        t_wa, t_we = self.direction
        return self.centre + k * self.spacing[0] * t_we + j * self.spacing[1] * t_wa

    def origin(self, family: int, index: int) -> np.ndarray:
        """Point (2,) [m] of yarn `index` at its arc position s = 0."""
        return self.point(index, 0) if family == 0 else self.point(0, index)

    def elevation(self, family: int, index: int, arc: np.ndarray) -> np.ndarray:
        """z [m] along a yarn: +-A cos(pi s / p), exactly +-A at every crossing.

        Warp k: +A_wa (-1)^k cos(pi s / p_wa); weft j: -A_we (-1)^j cos(pi s / p_we), so at
        crossing (k, j) the warp is at +A_wa (-1)^(k+j) and the weft at -A_we (-1)^(k+j).
        """
        p = self.pitch(family)
        whole = np.rint(arc / p)
        parity = 1.0 - 2.0 * (np.abs(whole) % 2)         # (-1)^m, exact
        sign = (1.0 if family == 0 else -1.0) * (1.0 - 2.0 * (abs(index) % 2))
        return sign * self.amplitude[family] * parity * np.cos(math.pi * (arc - whole * p) / p)


# --------------------------------------------------------------------------
# Input checks.


def _is_real(value) -> bool:
    return isinstance(value, numbers.Real) and not isinstance(value, bool) and math.isfinite(value)


def _require_positive(key: str, value: float) -> None:
    if not (_is_real(value) and value > 0):
        raise UserError(f"{key} = {value!r}: must be a positive length [m]")


def _check_weave(warp_spacing, weft_spacing, warp_amplitude, weft_amplitude,
                 segments_per_spacing) -> None:
    _require_positive("warp.spacing", warp_spacing)
    _require_positive("weft.spacing", weft_spacing)
    for key, value in (("warp.amplitude", warp_amplitude), ("weft.amplitude", weft_amplitude)):
        if not (_is_real(value) and value >= 0):
            raise UserError(f"{key} = {value!r}: must be a length >= 0 [m]")
    if isinstance(segments_per_spacing, bool) or not isinstance(
            segments_per_spacing, numbers.Integral) or segments_per_spacing < 1:
        raise UserError(f"specimen.segments_per_spacing = {segments_per_spacing!r}: "
                        "must be a whole number >= 1")


# --------------------------------------------------------------------------
# Building the chains.


def _clip(origin: np.ndarray, direction: np.ndarray, box: tuple) -> tuple:
    """Arc interval (s_lo, s_hi) [m] of the line origin + s direction inside [0, W] x [0, H]."""
    s_lo, s_hi = -math.inf, math.inf
    for axis, size in enumerate(box):
        if direction[axis] == 0.0:
            continue
        a = (0.0 - origin[axis]) / direction[axis]
        b = (size - origin[axis]) / direction[axis]
        s_lo, s_hi = max(s_lo, min(a, b)), min(s_hi, max(a, b))
    return s_lo, s_hi


def _piece(start: float, stop: float, segment: float) -> np.ndarray:
    """Node arcs of an end piece from `start` towards `stop` (excluded): ceil(piece/segment)
    equal segments, or none where the piece is shorter than half a segment."""
    piece = abs(stop - start)
    if piece < 0.5 * segment:
        return np.empty(0)
    count = math.ceil(piece / segment)
    return start + (stop - start) * np.arange(count) / count


def _yarn_arcs(s_lo: float, s_hi: float, crossings: np.ndarray, p: float,
               segments: int) -> tuple:
    """Node arcs (m,) [m] of one yarn and the node of each of its crossings (sorted indices
    `crossings`): end pieces to the boundary and `segments` per pitch between crossings."""
    segment = p / segments
    arcs = [_piece(s_lo, crossings[0] * p, segment)]
    nodes = arcs[0].size + segments * (crossings - crossings[0])
    for a, b in zip(crossings[:-1], crossings[1:]):
        count = segments * int(b - a)
        arcs.append(a * p + (b - a) * p * np.arange(count) / count)
    arcs.append([crossings[-1] * p])
    arcs.append(_piece(s_hi, crossings[-1] * p, segment)[::-1])
    return np.concatenate(arcs), nodes


def _snap(xy: np.ndarray, box: tuple) -> np.ndarray:
    """Put coordinates within the on-the-boundary tolerance exactly on the boundary."""
    tol = _RELATIVE_TOLERANCE * max(box)
    for axis, size in enumerate(box):
        for edge in (0.0, size):
            xy[np.abs(xy[:, axis] - edge) <= tol, axis] = edge
    return xy


class _Chains(NamedTuple):
    positions: np.ndarray
    chain_start: np.ndarray
    chain_family: np.ndarray
    chain_index: np.ndarray
    crossing_node: dict             # (family, k, j) -> node
    ends: list                      # per chain: (first, last node, first/last is a crossing)
    exits: list                     # per chain: (2, 2) [m], where its centreline leaves the box


def _build_chains(weave: _Weave, box: tuple, yarns: list, crossings: set) -> _Chains:
    """Nodes of every yarn (family, index) in `yarns`, in order, from boundary to boundary,
    with a node at each crossing (k, j) of `crossings`."""
    blocks, start, node_of, ends, exits = [], [0], {}, [], []
    for family, index in yarns:
        others = sorted(c[1 - family] for c in crossings if c[family] == index)
        others = np.asarray(others, dtype=np.int64)
        origin, t = weave.origin(family, index), weave.direction[family]
        s_lo, s_hi = _clip(origin, t, box)
        arcs, nodes = _yarn_arcs(s_lo, s_hi, others, weave.pitch(family), weave.segments)
        xy = _snap(origin + arcs[:, None] * t, box)
        own = np.full(others.size, index)
        k, j = (own, others) if family == 0 else (others, own)
        xy[nodes] = weave.point(k, j)                   # both yarns' nodes: one formula
        z = weave.elevation(family, index, arcs)
        base = start[-1]
        for other, node in zip(others, nodes):
            key = (index, other) if family == 0 else (other, index)
            node_of[(family,) + tuple(int(v) for v in key)] = base + int(node)
        ends.append((base, base + arcs.size - 1, nodes[0] == 0, nodes[-1] == arcs.size - 1))
        exits.append(_snap(origin + np.array([[s_lo], [s_hi]]) * t, box))
        blocks.append(np.column_stack([xy, z]))
        start.append(base + arcs.size)
    return _Chains(np.concatenate(blocks), np.asarray(start, dtype=np.int64),
                   np.asarray([f for f, _ in yarns], dtype=np.int64),
                   np.asarray([i for _, i in yarns], dtype=np.int64), node_of, ends, exits)


def _crossing_tables(chains: _Chains, crossings: list) -> tuple:
    """(crossing_nodes, crossing_lattice, crossing_side, interior) in (k, j) order."""
    lattice = np.asarray(crossings, dtype=np.int64).reshape(-1, 2)
    nodes = np.asarray([(chains.crossing_node[(0, k, j)], chains.crossing_node[(1, k, j)])
                        for k, j in crossings], dtype=np.int64).reshape(-1, 2)
    side = np.where(lattice.sum(axis=1) % 2 == 0, 1.0, -1.0)
    k, j = lattice.T
    interior = np.ones(len(crossings), dtype=bool)
    for along, other in ((k, j), (j, k)):            # along the warp k, then the weft j
        for yarn in np.unique(along):
            on = along == yarn
            interior[on] &= (other[on] > other[on].min()) & (other[on] < other[on].max())
    return nodes, lattice, side, interior


def chord_neighbours(chain_start: np.ndarray, nodes: np.ndarray, reach: int = 1) -> tuple:
    """Nodes (n - reach, n + reach) along each node's chain, the chain's end node where it
    ends first (the node itself at its end)."""
    chain = np.searchsorted(chain_start, nodes, side="right") - 1
    before = np.maximum(nodes - reach, chain_start[chain])
    after = np.minimum(nodes + reach, chain_start[chain + 1] - 1)
    return before, after


def _cross2(u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """u_x v_y - u_y v_x over the last axis."""
    return u[..., 0] * v[..., 1] - u[..., 1] * v[..., 0]


def _lateral_stencils(chains: _Chains, crossings: list) -> tuple:
    """Stencils (A_prev, A_next, A, B) and signs of the lateral contact (docs/model.md
    section 11): for neighbouring yarns i, i+1 of a family both crossing the same yarn of the
    other family, A on yarn i and B on yarn i+1 at those two crossings."""
    kept, rows = set(crossings), []
    for family in (0, 1):
        for k, j in crossings:
            nxt = (k + 1, j) if family == 0 else (k, j + 1)
            if nxt in kept:
                rows.append((chains.crossing_node[(family, k, j)],
                             chains.crossing_node[(family,) + nxt]))
    pairs = np.asarray(rows, dtype=np.int64).reshape(-1, 2)
    before, after = chord_neighbours(chains.chain_start, pairs[:, 0])
    stencil = np.column_stack([before, after, pairs]).astype(np.int64)
    xy = chains.positions[:, :2]
    sign = np.sign(_cross2(xy[after] - xy[before], xy[pairs[:, 1]] - xy[pairs[:, 0]]))
    return stencil, sign


def _layout(test: str, weave: _Weave, box: tuple, crossings: set, held_end) -> Layout:
    """Assemble a Layout from the kept crossings; held_end(family, exit, position, dropped)
    says whether a yarn's end is held: `exit` (2,) [m] where its centreline leaves the box,
    `position` (3,) [m] its end node, `dropped` whether that node is a crossing's (the end
    piece shorter than half a segment)."""
    order = sorted(crossings)
    yarns = sorted({(0, k) for k, _ in order}) + sorted({(1, j) for _, j in order})
    chains = _build_chains(weave, box, yarns, crossings)
    held = np.zeros(chains.positions.shape[0], dtype=bool)
    clamped_yarn = {}
    for chain, (first, last, first_dropped, last_dropped) in enumerate(chains.ends):
        family = yarns[chain][0]
        grips = [held_end(family, exit, chains.positions[n], dropped)
                 for exit, n, dropped in zip(chains.exits[chain], (first, last),
                                             (first_dropped, last_dropped))]
        held[[first, last]] |= grips
        clamped_yarn[yarns[chain]] = any(grips)
    nodes, lattice, side, interior = _crossing_tables(chains, order)
    held = _grip_end_pieces(held, chains.chain_start, nodes)
    zone = np.zeros(len(order), dtype=np.int64)
    if test == BIAS:
        zone = np.asarray([clamped_yarn[(0, k)] + clamped_yarn[(1, j)] for k, j in order],
                          dtype=np.int64)
    stencil, sign = _lateral_stencils(chains, order)
    return Layout(test, chains.positions, chains.chain_start, chains.chain_family,
                  chains.chain_index, nodes, lattice, side, held, zone, interior, stencil,
                  sign, float(box[0]), float(box[1]))


def _grip_end_pieces(held: np.ndarray, chain_start: np.ndarray, nodes: np.ndarray) -> np.ndarray:
    """`held` with every held end's whole end piece held too: the nodes from a held end node
    to its chain's nearest crossing node, that excluded. A clamp (a frame's bar) grips the
    fabric's edge strip up to the first crossing, so the yarn there moves with the clamp
    (docs/model.md section 11: a single held end node would leave the end piece a free hinge
    between the clamp and the first crossing)."""
    out = held.copy()
    crossing = np.zeros(held.size, dtype=bool)
    crossing[nodes.ravel()] = True
    for first, stop in zip(chain_start[:-1], chain_start[1:]):
        on_chain = np.flatnonzero(crossing[first:stop]) + first
        if held[first]:
            out[first:on_chain[0]] = True
        if held[stop - 1]:
            out[on_chain[-1] + 1:stop] = True
    return out


def _drop_short_yarns(crossings: set) -> set:
    """Drop every yarn with fewer than two crossings, and its crossings, until none is left."""
    while True:
        count = {}
        for k, j in crossings:
            count[(0, k)] = count.get((0, k), 0) + 1
            count[(1, j)] = count.get((1, j), 0) + 1
        kept = {(k, j) for k, j in crossings if count[(0, k)] >= 2 and count[(1, j)] >= 2}
        if kept == crossings:
            return kept
        crossings = kept


# --------------------------------------------------------------------------
# The specimens.


def bias_extension(width: float, height: float, warp_spacing: float, weft_spacing: float,
                   warp_amplitude: float, weft_amplitude: float,
                   segments_per_spacing: int, yarn_widths: tuple) -> Layout:
    """Bias-extension specimen: the rectangle 0 <= x <= W, 0 <= y <= H, warps at +45 and
    wefts at -45 degrees to the long side y, clamps at y = 0 (fixed) and y = H (moved).

    Yarns run from boundary to boundary; one with fewer than two crossings inside is dropped
    with its crossings. A clamp grips every yarn whose band reaches it: a yarn end on a
    short side is held (and so is a crossing end node within half a segment of it), and so
    is an end on a long side whose band, `yarn_widths` (warp, weft) [m] wide, reaches the
    short side there: within (w/2) / sin(45 deg) of it along the long side (docs/model.md
    section 11.7). Zone of a crossing = number of its yarns with a held end (Cao et al.
    2008: A, B, C).
    """
    _require_positive("specimen.width", width)
    _require_positive("specimen.height", height)
    if height < 2 * width:
        raise UserError(f"specimen.height = {height!r}: a bias-extension specimen needs "
                        f"H >= 2 W = {2 * width!r} [m]")
    _check_weave(warp_spacing, weft_spacing, warp_amplitude, weft_amplitude,
                 segments_per_spacing)
    for family, w in zip(("warp", "weft"), yarn_widths):
        _require_positive(f"{family}.width", w)
    weave = _Weave(np.array([width / 2, height / 2]),
                   (np.array([_SQRT_HALF, _SQRT_HALF]), np.array([-_SQRT_HALF, _SQRT_HALF])),
                   (warp_spacing, weft_spacing), (warp_amplitude, weft_amplitude),
                   int(segments_per_spacing))
    box = (width, height)
    crossings = _drop_short_yarns(_crossings_inside(weave, box))
    row = _centre_row(weave, crossings, height)
    if row < 2:
        raise UserError(f"specimen.width = {width!r}: {row} crossing(s) across the specimen's "
                        "centre row; at least 2 are needed (widen it or use a finer weave)")

    band = [0.5 * w / abs(t[0]) for w, t in zip(yarn_widths, weave.direction)]
    tol = _RELATIVE_TOLERANCE * height

    def held_end(family, exit, position, dropped):
        reach = 0.5 * weave.pitch(family) / weave.segments if dropped else tol
        if min(abs(position[1]), abs(height - position[1])) <= reach:
            return True                                     # on a short side
        on_long_side = min(abs(exit[0]), abs(width - exit[0])) <= tol
        return on_long_side and min(exit[1], height - exit[1]) <= band[family]

    return _layout(BIAS, weave, box, crossings, held_end)


def _crossings_inside(weave: _Weave, box: tuple) -> set:
    """Lattice crossings (k, j) inside the box (its boundary included)."""
    reach = math.hypot(*box) / 2
    kk = np.arange(-math.ceil(reach / weave.spacing[0]), math.ceil(reach / weave.spacing[0]) + 1)
    jj = np.arange(-math.ceil(reach / weave.spacing[1]), math.ceil(reach / weave.spacing[1]) + 1)
    k, j = np.meshgrid(kk, jj, indexing="ij")
    xy = weave.point(k, j)
    tol = _RELATIVE_TOLERANCE * max(box)
    inside = np.ones(k.shape, dtype=bool)
    for axis, size in enumerate(box):
        inside &= (xy[..., axis] >= -tol) & (xy[..., axis] <= size + tol)
    return {(int(a), int(b)) for a, b in zip(k[inside], j[inside])}


def _centre_row(weave: _Weave, crossings: set, height: float) -> int:
    """Crossings on the centre row y = H/2 (rows of crossings lie min(spacing)/sqrt(2) apart
    with equal spacings: the band of half that width holds exactly the row)."""
    if not crossings:
        return 0
    y = weave.point(*np.asarray(sorted(crossings)).T)[:, 1]
    return int(np.sum(np.abs(y - height / 2) < 0.5 * _SQRT_HALF * min(weave.spacing)))


def picture_frame(side: float, warp_spacing: float, weft_spacing: float,
                  warp_amplitude: float, weft_amplitude: float,
                  segments_per_spacing: int) -> Layout:
    """Picture-frame specimen: the square 0 <= x, y <= L, warps along x and wefts along y,
    every yarn pinned to a bar at both ends. Only yarns farther than half a segment of the
    crossing yarns from the bars are kept (a closer one would put a crossing on a pin).
    """
    _require_positive("specimen.side", side)
    _check_weave(warp_spacing, weft_spacing, warp_amplitude, weft_amplitude,
                 segments_per_spacing)
    weave = _Weave(np.array([side / 2, side / 2]), (np.array([1.0, 0.0]), np.array([0.0, 1.0])),
                   (warp_spacing, weft_spacing), (warp_amplitude, weft_amplitude),
                   int(segments_per_spacing))
    warps = _inside_frame(side, warp_spacing, 0.5 * warp_spacing / weave.segments)
    wefts = _inside_frame(side, weft_spacing, 0.5 * weft_spacing / weave.segments)
    if len(warps) < 2 or len(wefts) < 2:
        raise UserError(f"specimen.side = {side!r}: the frame holds {len(warps)} warp(s) and "
                        f"{len(wefts)} weft(s) clear of its bars; at least 2 of each are needed")
    crossings = {(k, j) for k in warps for j in wefts}
    return _layout(FRAME, weave, (side, side), crossings, lambda *_: True)


def _inside_frame(side: float, spacing: float, half_segment: float) -> list:
    """Indices i of the yarns at side/2 + i spacing farther than half_segment from both bars
    (half a segment of the crossing yarns, whose pitch is `spacing`)."""
    reach = math.ceil(side / 2 / spacing)
    return [i for i in range(-reach, reach + 1)
            if half_segment < side / 2 + i * spacing < side - half_segment]


# --------------------------------------------------------------------------
# Nominal kinematics.


def bias_limit(width: float, height: float) -> float:
    """Kinematic limit d = (sqrt(2) - 1)(H - W) [m] of the bias test (zone A at 90 degrees)."""
    return (math.sqrt(2.0) - 1.0) * (height - width)


def frame_angle(side: float, d: float) -> float:
    """Frame angle theta [rad]: cos(theta) = (sqrt(2) L + d) / (2 L) (Cao et al. eq. 1)."""
    cosine = (math.sqrt(2.0) * side + d) / (2.0 * side)
    if not 0.0 < cosine <= 1.0:
        raise UserError(f"load.values: corner displacement d = {d!r} m is outside the picture "
                        f"frame's range ({-math.sqrt(2.0) * side!r}, "
                        f"{(2 - math.sqrt(2.0)) * side!r}] for side L = {side!r} m")
    return math.acos(cosine)


def yarns_meet_at(warp, weft) -> float:
    """The nominal shear angle [rad] at which neighbouring yarns first meet, acos(w / p) of
    the family (`warp`, `weft`: the scene's) whose width is the larger share of its spacing
    (docs/model.md 11.5)."""
    return float(np.arccos(max(t.width / t.spacing for t in (warp, weft))))


def nominal_shear_angle(layout_or_test, d: float, width: float = None, height: float = None,
                        side: float = None) -> float:
    """Nominal shear angle gamma [rad] at clamp / corner displacement d [m].

    Bias (Cao et al. eq. 13, zone A): gamma = pi/2 - 2 acos((L0 + d) / (sqrt(2) L0)),
    L0 = H - W. Frame (eqs. 1-2): gamma = pi/2 - 2 theta. A Layout supplies its own sizes.
    """
    if isinstance(layout_or_test, Layout):
        test = layout_or_test.test
        width = layout_or_test.width if width is None else width
        height = layout_or_test.height if height is None else height
        side = layout_or_test.width if side is None else side
    else:
        test = layout_or_test
    if test == FRAME:
        return math.pi / 2 - 2.0 * frame_angle(side, d)
    if test != BIAS:
        raise UserError(f"specimen.test = {test!r}: must be '{BIAS}' or '{FRAME}'")
    free = height - width
    ratio = (free + d) / (math.sqrt(2.0) * free)
    if not -1.0 <= ratio <= 1.0:
        raise UserError(f"load.values: clamp displacement d = {d!r} m is beyond the bias "
                        f"test's kinematic limit (sqrt(2) - 1)(H - W) = "
                        f"{bias_limit(width, height)!r} m")
    return math.pi / 2 - 2.0 * math.acos(ratio)


def frame_map(theta: float) -> np.ndarray:
    """In-plane map F(theta) = [u1 u2] (2, 2) of the hinged frame, u1 = (cos(pi/4 - theta),
    sin(pi/4 - theta)) the image of x, u2 = (cos(pi/4 + theta), sin(pi/4 + theta)) of y."""
    a, b = math.pi / 4 - theta, math.pi / 4 + theta
    return np.array([[math.cos(a), math.cos(b)], [math.sin(a), math.sin(b)]])


def _frame_map_rate(theta: float) -> np.ndarray:
    """dF/dtheta (2, 2)."""
    a, b = math.pi / 4 - theta, math.pi / 4 + theta
    return np.array([[math.sin(a), -math.sin(b)], [-math.cos(a), math.cos(b)]])


def _moved_clamp(layout: Layout) -> np.ndarray:
    """Held nodes (in held order) on the moved clamp y = H of a bias specimen."""
    return layout.positions[layout.held, 1] > layout.height / 2


def held_positions(layout: Layout, rest_positions: np.ndarray, d: float) -> np.ndarray:
    """Prescribed positions (k, 3) [m] of the held nodes (np.flatnonzero(layout.held) order)
    at clamp / corner displacement d [m], from their reference positions.

    Bias: the y = H clamp moves by (0, d, 0), the y = 0 clamp stays. Frame: rigid hinged bars,
    (x, y) -> F(theta) (x, y), z unchanged (docs/model.md section 11), as x + (F(theta) -
    F(theta_0)) x: exactly x at d = 0, where F(theta_0) is the identity only to rounding.
    """
    rest = np.array(rest_positions[layout.held], dtype=float)
    if layout.test == BIAS:
        rest[_moved_clamp(layout), 1] += d
        return rest
    turn = frame_map(frame_angle(layout.width, d)) - frame_map(frame_angle(layout.width, 0.0))
    rest[:, :2] += rest[:, :2] @ turn.T
    return rest


def held_velocity(layout: Layout, rest_positions: np.ndarray, d: float) -> np.ndarray:
    """d/dd of held_positions (k, 3) [m/m]: F = sum reaction . velocity is the clamp force."""
    rest = np.asarray(rest_positions, dtype=float)[layout.held]
    velocity = np.zeros_like(rest)
    if layout.test == BIAS:
        velocity[_moved_clamp(layout), 1] = 1.0
        return velocity
    theta = frame_angle(layout.width, d)
    rate = -1.0 / (2.0 * layout.width * math.sin(theta))     # dtheta/dd
    velocity[:, :2] = rest[:, :2] @ (rate * _frame_map_rate(theta)).T
    return velocity


def _chord_directions(layout: Layout, positions: np.ndarray, nodes: np.ndarray) -> np.ndarray:
    """Unit in-plane chords (m, 2) from node n-1 to node n+1 along each node's chain."""
    before, after = chord_neighbours(layout.chain_start, nodes)
    chord = positions[after, :2] - positions[before, :2]
    return chord / np.linalg.norm(chord, axis=1, keepdims=True)


def shear_angles(layout: Layout, rest_positions: np.ndarray, positions: np.ndarray) -> np.ndarray:
    """Shear angle (C,) [rad] at every crossing: asin(t_wa . t_we) - asin(t0_wa . t0_we),
    t the unit in-plane chords n-1 -> n+1 of the warp and the weft (docs/model.md section 11)."""
    def sine(x):
        x = np.asarray(x, dtype=float)
        warp = _chord_directions(layout, x, layout.crossing_nodes[:, 0])
        weft = _chord_directions(layout, x, layout.crossing_nodes[:, 1])
        return np.arcsin(np.clip(np.sum(warp * weft, axis=1), -1.0, 1.0))
    return sine(positions) - sine(rest_positions)
