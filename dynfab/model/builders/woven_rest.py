"""The woven-in contact: rest shapes that hold the preload (docs/model.md section 10,
"The woven-in contact", (10.12)-(10.15)).

A yarn leaves the loom with its crimp set: its stress-free shape is not the woven one, and
in the woven fabric it presses its crossing yarns with the contact force R_p woven in. The
builders give each chain the rest lengths and rest turnings that make the as-woven shape an
equilibrium of its stretch and bending springs against the crossing forces +-R_p at its
crossing nodes, with no tension along the fabric (inverse statics).

On an endless plain-weave yarn the crossing forces alternate, +-F at spacing p, and balance
over two spacings. A chain's internal force is then vertical (no horizontal resultant: no
tension at zero load), G = +-F/2 between crossings, and its moment a triangle wave in the
run along the chain, +-F p/4 at the crossings and 0 midway between them ((10.13)). Every
chain takes that endless yarn's pattern, its ends included: a yarn's set does not know
where the specimen was cut. Where an end is held (a clamp, a patch's pinned end, a periodic
image) the hold carries the pattern's end force; a free end carries none, so the piece past
its last crossing relaxes to its rest shape and the crossings next to it lose part of their
contact (docs/model.md section 10, "at a free end").

Plain numpy, once per scene.
"""

from __future__ import annotations

import math

import numpy as np

from dynfab.errors import UserError
from dynfab.model.terms import contact as contact_law

LARGEST_END_TURN = 0.5 * math.pi
"""The largest angle [rad] from the fabric's plane that a free yarn end may turn to: past it
the yarn folds back over itself, outside the model (docs/model.md, "What the model is not")."""


def internal_forces(run: np.ndarray, rise: np.ndarray, load: np.ndarray,
                    spacing: float) -> tuple[np.ndarray, np.ndarray]:
    """(tension T (m-1,) [N], moment M (m,) [N m]) that hold a chain of m nodes in its woven
    shape against the z-forces `load` (m,) [N] of its crossings (docs/model.md (10.13)).

    run, rise (m-1,) [m]: each segment's extent along the chain (> 0) and along z. With
    G_s = F_1 / 2 - sum_{i <= s} F_i the vertical force in segment s (F_1 the first
    crossing's force), T_s = G_s rise_s / l_s and M_{s+1} = M_s - G_s run_s, M = 0 half a
    `spacing` [m] before the first crossing: M = -F_1 p / 4 there. Without crossings, zeros.
    """
    crossings = np.flatnonzero(load)
    if crossings.size == 0:
        return np.zeros(run.size), np.zeros(run.size + 1)
    first = crossings[0]
    vertical = 0.5 * load[first] - np.cumsum(load)[:-1]
    tension = vertical * rise / np.hypot(run, rise)
    moment = np.concatenate([[0.0], np.cumsum(-vertical * run)])
    moment += -0.25 * load[first] * spacing - moment[first]
    return tension, moment


def rest_lengths(length: np.ndarray, tension: np.ndarray, EA: float) -> np.ndarray:
    """l0 = l / (1 + T / EA) [m]: the rest length whose stretch spring EA / l0 carries T at the
    woven length l (docs/model.md (10.14))."""
    return length / (1.0 + tension / EA)


def rest_turnings(turning: np.ndarray, moment: np.ndarray, bend_stiffness: np.ndarray
                  ) -> np.ndarray:
    """phi0 = phi - M / (EI / lbar) [rad] at the inner nodes, the woven turning phi at the end
    nodes (no spring): the rest turning whose bending spring carries M at the woven turning
    (docs/model.md (10.15))."""
    rest = turning.copy()
    rest[1:-1] -= moment[1:-1] / bend_stiffness[1:-1]
    return rest


def crossing_loads(nodes: int, tie_a: np.ndarray, tie_b: np.ndarray, side: np.ndarray,
                   preload: float) -> np.ndarray:
    """The z-force each node carries from the woven-in contact (nodes,) [N]: +sigma R_p on a
    crossing's node a, -sigma R_p on its node b (docs/model.md section 10, contact)."""
    load = np.zeros(nodes)
    np.add.at(load, tie_a, side * preload)
    np.add.at(load, tie_b, -side * preload)
    return load


def woven_closure(preload: float, law: np.ndarray) -> float:
    """g_p [m]: the closure at which the series contact law `law` (k, C_a, a_a, C_b, a_b)
    carries R_p (docs/model.md (10.12)); 0 without a preload (the as-woven state at g = 0)."""
    return contact_law.closure_from_force(float(preload), law) if preload > 0.0 else 0.0


def release_turn(preload: float, spacing: float, EI: float) -> float:
    """Phi = R_p p^2 / (16 EI) [rad]: the turn of the woven-in moment's curvature M / EI over
    half a spacing, from a crossing (M = R_p p / 4) to the inflection midway (M = 0)
    (docs/model.md (10.16)). A free yarn end released there turns by about 2 Phi."""
    return preload * spacing * spacing / (16.0 * EI)


def check_free_end(preload: float, spacing: float, EI: float, amplitude: float,
                   family: str) -> None:
    """Refuse a preload whose release would turn a free yarn end of `family` past
    LARGEST_END_TURN: 2 Phi (`release_turn`) from its crimp's steepest angle atan(pi A / p)
    (docs/model.md (10.16)), naming the largest preload that stays within it and the contact
    of a yarn straight at rest, 48 EI A / p^3."""
    crimp = math.atan(math.pi * amplitude / spacing)
    turn = 2.0 * release_turn(preload, spacing, EI)
    if turn + crimp < LARGEST_END_TURN:
        return
    largest = (LARGEST_END_TURN - crimp) * 8.0 * EI / spacing ** 2
    straight = 48.0 * EI * amplitude / spacing ** 3
    raise UserError(
        f"crossing.preload = {preload:g} N: the rest shape that holds it in a {family} yarn "
        f"(EI = {EI:g} N m^2, crossings {spacing * 1e3:.3g} mm apart) turns a free yarn end by "
        f"about R_p p^2 / (8 EI) = {math.degrees(turn):.0f} degrees from its crimp of "
        f"{math.degrees(crimp):.0f}, past the {math.degrees(LARGEST_END_TURN):.0f} degrees "
        f"where a yarn folds back (docs/model.md section 10, the woven-in contact): give a "
        f"preload below {largest:.3g} N or a stiffer yarn ({straight:.3g} N is the contact of "
        f"a yarn straight at rest, 48 EI A / p^3)")


def free_ends(fixed: np.ndarray, chain_start: np.ndarray, d: int) -> np.ndarray:
    """(chains, 2) bool: whether each chain's first and last node is free along z (its z dof,
    the last of the node's `d`, not in `fixed`): an end that carries none of the woven-in
    pattern's end force (module docstring)."""
    first, last = chain_start[:-1], chain_start[1:] - 1
    return np.column_stack([~fixed[d * first + d - 1], ~fixed[d * last + d - 1]])


def crossings_from_free_end(structure) -> np.ndarray:
    """For each tie (T,), int64: its rank from the nearest free yarn end along its two chains,
    1 for a yarn's last crossing before a free end (an end node whose z is not held), a
    large number where neither chain has a free end: where the woven-in contact relaxes
    (docs/model.md section 10, at a free end)."""
    start = structure.chain_start
    free = free_ends(structure.fixed, start, structure.rest_position.shape[1])
    rank = np.full(structure.tie_a.size, np.iinfo(np.int64).max // 2, np.int64)
    nodes = np.concatenate([structure.tie_a, structure.tie_b])
    ties = np.concatenate([np.arange(structure.tie_a.size)] * 2)
    for y in range(start.size - 1):
        on_chain = np.flatnonzero((nodes >= start[y]) & (nodes < start[y + 1]))
        order = on_chain[np.argsort(nodes[on_chain], kind="stable")]
        count = np.arange(1, order.size + 1)
        if free[y, 0]:
            np.minimum.at(rank, ties[order], count)
        if free[y, 1]:
            np.minimum.at(rank, ties[order], count[::-1])
    return rank
