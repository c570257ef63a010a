"""Crossings that slide along the yarns (docs/model.md 11.13): a structure whose ties are fixed
pairs of nodes made into one whose crossings let the yarns' material through.

Each crossing's two nodes stay at the crossing and carry, besides their positions, the slide
of their own chain's material there: delta = u - U, u the material coordinate (the as-woven
arc length, from the chain's first node, of the yarn point at the crossing now) and U its
value as woven. Those two slides take the place of the crossing's two slip dofs (planar:
node a's x and node b's y, the nodes then held on the planes they cross; spatial: node b's x
and y, node b then sharing node a's), so the dofs, the held ones and the Hessian's sparsity
are fixed for the whole path. The nodes between two crossings of a chain (a bay) interpolate
their material: a segment's rest length is L = base + f (delta_R - delta_L), f its share of
the bay's material and base its rest length where the bay's ends have not slid, a chain's
ends being material points (delta = 0). A slot holds the slide rather than u itself because
u reaches a chain's length: differences of such coordinates would lose two or three digits
of a segment's rest length, and with them the forces' rounding floor.
"""

from __future__ import annotations

import numpy as np

from typing import NamedTuple

from dynfab.errors import SolverError
from dynfab.model import geometry
from dynfab.model.fabric.sliding import physical, rest_lengths
from dynfab.model.structure import Structure, chain_count, dim

GROUND_REFUSED = "crossings that slide join two chains; a tie to ground (the paper's weft) cannot"


def material_coordinates(structure: Structure) -> np.ndarray:
    """The as-woven material coordinate of every node (n,) [m]: the rest lengths summed from
    its chain's first node."""
    start, l0 = structure.chain_start, structure.rest_length
    out = np.zeros(start[-1])
    for y in range(start.size - 1):
        a, b = start[y], start[y + 1]
        out[a + 1:b] = np.cumsum(l0[a - y:b - y - 1])
    return out


def material_slots(structure: Structure) -> tuple[np.ndarray, np.ndarray]:
    """(the dofs of each tie's (u_a, u_b) (T, 2), the source of every physical coordinate
    (n dim,)): planar, node a's x and node b's y hold them, both held on their planes; spatial,
    node b's x and y hold them, node b's x and y being node a's."""
    d, a, b = dim(structure), structure.tie_a, structure.tie_b
    if np.any(b < 0):
        raise ValueError(GROUND_REFUSED)
    source = np.arange(d * structure.rest_position.shape[0], dtype=np.int64)
    if d == 2:
        slots = np.stack([d * a, d * b], axis=1)
        source[slots.ravel()] = -1
    else:
        slots = np.stack([d * b, d * b + 1], axis=1)
        source[d * b], source[d * b + 1] = d * a, d * a + 1
    return slots.astype(np.int64), source


def bays(structure: Structure, ties: np.ndarray, flat: np.ndarray, lengths: np.ndarray,
         retired: np.ndarray | None = None):
    """(segment_material (n - Y, 2), segment_material_end (n - Y, 2), segment_fraction
    (n - Y,), segment_base (n - Y,)) of the bays between consecutive crossings of each chain,
    the crossings the ties `ties` (`Structure`): each segment's fraction its rest length
    `lengths` over its bay's, its base its rest length less f times the slides of its bay's
    ends now (`flat` holding the crossings' slides in their slots, a chain's ends 0). The
    segments `retired` (a retired tail's, `_retire_tail`) count in no bay."""
    start = structure.chain_start
    count = lengths.size
    material = np.full((count, 2), -1, np.int64)
    slots = structure.tie_material[ties]
    nodes = np.concatenate([structure.tie_a[ties], structure.tie_b[ties]])
    dofs = np.concatenate([slots[:, 0], slots[:, 1]])
    for y in range(start.size - 1):
        a, b = start[y], start[y + 1]
        mine = (nodes >= a) & (nodes < b)
        order = np.argsort(nodes[mine])
        crossed, crossed_dof = nodes[mine][order], dofs[mine][order]
        for i in range(a, b - 1):
            k = i - y
            left = np.searchsorted(crossed, i, side="right") - 1
            right = np.searchsorted(crossed, i + 1, side="left")
            if left >= 0:
                material[k, 0] = crossed_dof[left]
            if right < crossed.size:
                material[k, 1] = crossed_dof[right]
    end = np.zeros((count, 2))
    fraction = np.empty(count)
    for y in range(start.size - 1):
        segments = np.arange(start[y] - y, start[y + 1] - y - 1)
        key = material[segments] if retired is None else np.column_stack(
            [material[segments], retired[segments]])
        _, bay = np.unique(key, axis=0, return_inverse=True)
        fraction[segments] = lengths[segments] / np.bincount(bay.ravel(),
                                                             weights=lengths[segments])[bay.ravel()]
    slide = np.where(material >= 0, flat[np.maximum(material, 0)], end)
    return material, end, fraction, lengths - fraction * (slide[:, 1] - slide[:, 0])


def sliding_structure(structure: Structure) -> Structure:
    """`structure` with crossings that slide (module docstring); ValueError for ties to ground."""
    slots, source = material_slots(structure)
    with_slots = structure._replace(tie_material=slots)
    material, end, fraction, base = bays(with_slots, np.arange(slots.shape[0]),
                                         woven_dofs(with_slots).reshape(-1),
                                         structure.rest_length)
    lbar = np.concatenate([geometry.voronoi_lengths(structure.rest_length[
        structure.chain_start[y] - y:structure.chain_start[y + 1] - y - 1])
        for y in range(chain_count(structure))])
    return structure._replace(
        physical_source=source, tie_material=slots, segment_material=material,
        segment_material_end=end, segment_fraction=fraction, segment_base=base,
        stretch_modulus=structure.stretch_stiffness * structure.rest_length,
        bend_modulus=structure.bend_stiffness * lbar,
        lateral_bend_modulus=np.asarray(structure.lateral_bend_stiffness) * lbar
        if dim(structure) == 3 else np.zeros(0))


def crossings_as_they_move(scene):
    """The structure as its crossings move (`crossing.motion` of a validated scene): fixed
    pairs of nodes as built, or sliding along the yarns (`sliding_structure`)."""
    motion = scene.crossing.motion if scene.crossing is not None else "fixed"
    return {"fixed": lambda structure: structure, "sliding": sliding_structure}[motion]


def woven_dofs(structure: Structure) -> np.ndarray:
    """The dofs of a sliding structure as woven (n, dim): the rest positions, each tie's slots
    holding its slides, 0."""
    dofs = np.array(structure.rest_position, float)
    dofs.reshape(-1)[structure.tie_material.ravel()] = 0.0
    return dofs


def woven_material(structure: Structure) -> np.ndarray:
    """U, each tie's two material coordinates as woven (T, 2) [m] (`material_coordinates` at
    its nodes): a record's material coordinates are U plus the slides."""
    woven = material_coordinates(structure)
    return np.stack([woven[structure.tie_a], woven[structure.tie_b]], axis=1)


class Departure(NamedTuple):
    """A yarn end leaving a crossing: the tie, the chain and which end (0 its first node)."""

    tie: int
    chain: int
    end: int


def leaving(structure: Structure, dofs) -> list[Departure]:
    """The crossings a free yarn end has reached (docs/model.md 11.13): each tie whose end bay,
    the piece of a chain between the crossing and the chain's free end, holds less material
    than one as-woven segment of that chain (its mean rest length), or than half its own
    as-woven material where the chain was cut shorter (a specimen's edges). A held or loaded
    end reaching its last crossing so is `SolverError` (its load or hold would be left on a
    yarn that has left the fabric)."""
    L = rest_lengths(dofs, structure)
    start, l0 = structure.chain_start, structure.rest_length
    found = []
    for y in range(start.size - 1):
        a, b = start[y], start[y + 1]
        active = np.flatnonzero(structure.stretch_modulus[a - y:b - y - 1] > 0.0)
        if active.size == 0:
            continue
        k0, k1 = a - y + active[0], a - y + active[-1]  # a retired tail is not the chain's
        segment = l0[a - y:b - y - 1].sum() / (b - a - 1)
        for end, k in ((0, k0), (1, k1)):
            dof = _reached(structure, L, k, end, segment)
            if dof is None:
                continue
            node = k + y if end == 0 else k + y + 1
            held = _held(structure, y, node)
            if held:
                raise SolverError(
                    f"the {held} end of chain {y + 1} reached its last crossing: its "
                    f"{'load' if held == 'loaded' else 'hold'} would act on a yarn that has "
                    "left the fabric (docs/model.md 11.13); stop the load path before")
            found.append((dof, y, end))
    return [Departure(int(np.flatnonzero((structure.tie_material == dof).any(axis=1))[0]), y, end)
            for dof, y, end in found]


def _reached(structure: Structure, L: np.ndarray, k: int, end: int,
             segment: float) -> int | None:
    """The dof of the last crossing before a chain's `end` (0 first, 1 last; k the end's
    segment) where the end bay's material (its segments' rest lengths now, L) is below
    `leaving`'s bound, else None."""
    bays, ends = structure.segment_material, structure.segment_material_end
    if bays[k, end] >= 0:  # the end segment's bay ends at a crossing: not a chain's end
        return None
    crossing = bays[k, 1 - end]
    if crossing < 0:  # no crossing on the chain
        return None
    in_bay = np.flatnonzero(np.all(bays == bays[k], axis=1)
                            & np.all(ends == ends[k], axis=1))
    bound = min(segment, 0.5 * structure.rest_length[in_bay].sum())
    return int(crossing) if L[in_bay].sum() < bound else None


def _held(structure: Structure, y: int, node: int) -> str:
    """"loaded" where a chain's end node carries the chain's load, "held" where it is held,
    else ""."""
    if node == structure.load_node[y] and structure.load_factor[y] != 0.0:
        return "loaded"
    return "held" if structure.fixed[dim(structure) * node] else ""


def without_crossings(structure: Structure, departures: list[Departure],
                      dofs) -> tuple[Structure, np.ndarray]:
    """(the structure without the ties a yarn end left, its dofs) at `dofs` (docs/model.md
    11.13): each such tie's nodes ordinary nodes again, their slots holding their coordinates
    where they are now; on its other chain the bays on each side of it one bay whose segments
    keep the rest lengths they have now; on the leaving chain the tail past it, less than a
    segment of material, retired (`_retire_tail`), the crossing's node the chain's free end
    from then on, its material coordinate the end's."""
    removed = np.array(sorted({d.tie for d in departures}), np.int64)
    flat = np.asarray(dofs, float).reshape(-1)
    keep = np.ones(structure.tie_a.size, bool)
    keep[removed] = False
    lengths = rest_lengths(dofs, structure)
    retired = structure.stretch_modulus == 0.0  # a retired tail keeps its constants
    material, end, fraction, base = bays(structure, np.flatnonzero(keep), flat, lengths,
                                         retired)
    same = np.all(material == structure.segment_material, axis=1) | retired  # and bays kept
    for new, old in ((material, structure.segment_material),
                     (end, structure.segment_material_end),
                     (fraction, structure.segment_fraction), (base, structure.segment_base)):
        new[same] = old[same]
    slots = structure.tie_material[removed].ravel()
    source = structure.physical_source.copy()
    out = np.array(dofs, float)
    out.reshape(-1)[slots] = physical(dofs, structure).reshape(-1)[slots]
    source[slots] = slots
    ties = {name: getattr(structure, name)[keep] for name in structure._fields
            if name.startswith("tie_") and np.ndim(getattr(structure, name))
            and len(getattr(structure, name)) == keep.size}
    out_structure = structure._replace(
        **ties, physical_source=source, segment_material=material, segment_material_end=end,
        segment_fraction=fraction, segment_base=base, has_friction=bool(np.any(ties["tie_friction_law"][:, 3] > 0.0)))
    for departure in departures:
        node = structure.tie_a[departure.tie] if _on_chain(structure, structure.tie_a[
            departure.tie], departure.chain) else structure.tie_b[departure.tie]
        slide = flat[structure.tie_material[departure.tie,
                                            0 if node == structure.tie_a[departure.tie] else 1]]
        y = departure.chain
        out_structure = _retire_tail(out_structure, y, int(node), departure.end, slide, lengths,
                                     flat)
        if not any(_on_chain(out_structure, n, y) for n in (*out_structure.tie_a,
                                                            *out_structure.tie_b)):
            out_structure = _left_the_fabric(out_structure, y, lengths, flat)
    return out_structure, out


def _left_the_fabric(structure: Structure, y: int, lengths: np.ndarray,
                     flat: np.ndarray) -> Structure:
    """Chain y, which no crossing holds any more, out of the mechanics: nothing holds it but a
    held or loaded end, on which it would turn freely, so it moves with that end (its last
    one where both are); where neither end is held it stays where it left, held, its lateral
    contacts without stiffness (the yarn has fallen out of the fabric)."""
    a, b = int(structure.chain_start[y]), int(structure.chain_start[y + 1])
    if _held(structure, y, b - 1):
        return _retire_tail(structure, y, b - 1, 0, 0.0, lengths, flat)
    if _held(structure, y, a):
        return _retire_tail(structure, y, a, 1, 0.0, lengths, flat)
    structure = _retire_tail(structure, y, b - 1, 0, 0.0, lengths, flat)
    d = dim(structure)
    fixed, tie = structure.fixed.copy(), structure.dof_tie.copy()
    fixed[d * a:d * b], tie[d * a:d * b] = True, -1
    law = structure.lateral_law.copy()
    on_chain = np.any((structure.lateral_stencil >= a) & (structure.lateral_stencil < b), axis=1)
    law[on_chain, 2] = law[on_chain, 4] = 0.0  # k and Gutowski's A
    return structure._replace(fixed=fixed, dof_tie=tie, lateral_law=law)


def _on_chain(structure: Structure, node: int, y: int) -> bool:
    return bool(structure.chain_start[y] <= node < structure.chain_start[y + 1])


def _retire_tail(structure: Structure, y: int, node: int, end: int, slide: float,
                 lengths: np.ndarray, flat: np.ndarray) -> Structure:
    """Chain y's tail from its `end` (0 its first node, 1 its last) to `node` retired: its
    segments without stiffness (their rest lengths `lengths` kept, constant), its nodes
    without bending and moving as `node` (tied dofs), `node` the chain's free end, a material
    point with the slide `slide` [m], the end of the bay that reaches it."""
    a, b = int(structure.chain_start[y]), int(structure.chain_start[y + 1])
    d = dim(structure)
    segments = np.arange(a - y, b - y - 1)
    tail = segments[segments < node - y] if end == 0 else segments[segments >= node - y]
    material = structure.segment_material.copy()
    bay_end = structure.segment_material_end.copy()
    fraction = structure.segment_fraction.copy()
    base = structure.segment_base.copy()
    material[tail], bay_end[tail], fraction[tail], base[tail] = -1, 0.0, 1.0, lengths[tail]
    rest = np.setdiff1d(segments, tail)
    bay = rest[structure.segment_material[rest, end] < 0]  # the bay that reaches `node`
    bay_end[bay, end] = slide
    fraction[bay] = lengths[bay] / lengths[bay].sum()
    ends = np.where(material[bay] >= 0, flat[np.maximum(material[bay], 0)], bay_end[bay])
    base[bay] = lengths[bay] - fraction[bay] * (ends[:, 1] - ends[:, 0])
    stretch = structure.stretch_modulus.copy()
    stretch[tail] = 0.0
    still = slice(a, node + 1) if end == 0 else slice(node, b)  # no bending from here on
    bend = structure.bend_modulus.copy()
    bend[still] = 0.0
    lateral = structure.lateral_bend_modulus.copy()
    lateral[still] = 0.0
    tie = structure.dof_tie.copy()
    nodes = np.arange(a, node) if end == 0 else np.arange(node + 1, b)
    for k in range(d):
        tie[d * nodes + k] = d * node + k
    return structure._replace(segment_material=material, segment_material_end=bay_end,
                              segment_fraction=fraction, segment_base=base,
                              stretch_modulus=stretch, bend_modulus=bend,
                              lateral_bend_modulus=lateral, dof_tie=tie)
