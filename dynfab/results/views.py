"""The view datasets of a result file: what ``<result>.xdmf`` (`dynfab.results.xdmf`) shows, as
whole HDF5 datasets under ``view/``, made of the file's own rows without copying them.

Why whole datasets: meshio's XDMF reader (``meshio.xdmf.TimeSeriesReader``)
reads an HDF5 DataItem only as a whole dataset, and VTK's XDMF reader
(ParaView's "XDMF Reader") reports errors on geometry that is a HyperSlab;
both read a whole dataset, virtual ones included (HDF5 virtual datasets,
HDF5 >= 1.10). So every array the view shows is a dataset of its own:

* ``view/points`` (P, 3) [m]: the as-woven nodes in 3D; ``view/plane`` (P,) [m]:
  each node's as-woven plane coordinate; ``view/segments`` (S, 2): the line
  segments, node pairs; ``view/yarn`` (S,): each segment's yarn, the index
  into the root attribute ``yarn_labels`` (warps, then wefts). Nodes are
  numbered family by family (warps, then a fabric's wefts), yarn by yarn.
* ``view/<group>/<name>/<n>`` for every row n = 1, 2, ... of ``steps/`` (or
  ``frames/``) up to its capacity: ``points`` (P, 3) [m]; ``contact_force``
  [N], ``slip`` [m] (P,) where the file has their node arrays
  (``<group>/xdmf/*``); ``plane`` (P,) [m] where the planes move.

Every one but ``view/plane``, ``view/segments`` and ``view/yarn`` (a few node
arrays, once) is a virtual dataset into rows of ``reference/`` and
``<group>/``: no number is stored twice. A node of the one-yarn model and a
warp lies at (x, y, z) = (positions x, plane, positions z), a weft at
(plane, positions y, positions z) (docs/model.md sections 1, 10).

Plane coordinates: yarn k lies in the plane ``y = (k - 1/2) w`` with ``w`` the
fabric width per yarn (root attribute ``width_per_yarn``); the yarns of a
``[sweep]`` are not neighbours in a fabric, and a rod has no width: they are
spaced by L / `LENGTHS_PER_SPACING` (L the projected length). A fabric's weft j
lies in ``x = (j - 1/2) L / n_we`` (``length_per_weft``); where its planes move
("affine", periodic cell), each row's ``<group>/xdmf/plane`` and
``weft_plane`` hold every node's plane coordinate, and the row's points and
``plane`` use them.

`add_views` writes all of them. A run's `dynfab.results.file.ResultFile` (given
``views=add_views``) calls it whenever it writes the file's structure (create,
first entry, growth, close), so they are as crash-safe as the structure:
published whole, atomically, for every row the datasets hold, so a row's views
exist before the row is written; ``dynfab xdmf`` adds them to a file written
without them (`dynfab.results.xdmf.write_xdmf`).
"""

from __future__ import annotations

import tomllib
from dataclasses import dataclass

import h5py
import numpy as np

from dynfab.results.file import units_of

LENGTHS_PER_SPACING = 10
"""A sweep's or a rod's yarns are spaced by L / 10 (L the projected length): y = (k-1/2) L/10."""

POINT_DATA = ("contact_force", "slip")
"""Nodal point data: column ``<group>/xdmf/<prefix><name>`` (entries, yarns, nodes)."""

SPATIAL_POINT_DATA = ("shear_angle",)
"""A spatial model's nodal point data: ``<group>/xdmf/<name>`` (entries, nodes)."""

GROUPS = ("steps", "frames")
"""The series whose rows get views."""


@dataclass(frozen=True)
class ViewFamily:
    """One yarn family of a result file: where its datasets are and where its yarns lie."""

    prefix: str
    """Dataset name prefix: "" (one-yarn model, warps) or "weft_"."""
    plane_axis: int
    """The 3D axis normal to the yarns' planes: 1 (y) for warps, 0 (x) for wefts."""
    planes: np.ndarray
    """The as-woven plane coordinate of each yarn [m]."""
    nodes: int
    """Nodes per yarn (N+1)."""
    offset: int
    """Index of the family's first node in the view."""

    @property
    def yarns(self) -> int:
        return len(self.planes)

    @property
    def size(self) -> int:
        """The family's nodes, all yarns."""
        return self.yarns * self.nodes

    def column(self, group: str, name: str) -> str:
        """The family's dataset ``name`` of a series (``positions``, ``xdmf/slip``, ...)."""
        head, _, tail = name.rpartition("/")
        return f"{group}/{head + '/' if head else ''}{self.prefix}{tail}"


def plane_spacing(attrs) -> float:
    """Width per yarn of a fabric; L / `LENGTHS_PER_SPACING` for a sweep or a rod [m]."""
    width = attrs.get("width_per_yarn")
    scene = attrs.get("scene", "")
    try:
        sweep = "sweep" in tomllib.loads(scene.decode() if isinstance(scene, bytes) else scene)
    except tomllib.TOMLDecodeError:
        sweep = False
    if width is None or sweep:
        return float(attrs["projected_length"]) / LENGTHS_PER_SPACING
    return float(width)


def families(h5: h5py.File) -> list[ViewFamily]:
    """The families of a result file: the warps (or the one-yarn model's yarns), then a
    fabric's wefts (docs/model.md section 10). KeyError if it lacks ``reference/positions``."""
    if is_spatial(h5):
        return []  # one (nodes, 3) array of every chain: `_add_spatial_views`
    yarns, nodes = h5["reference/positions"].shape[:2]
    found = [ViewFamily("", 1, (np.arange(yarns) + 0.5) * plane_spacing(h5.attrs), nodes, 0)]
    if "reference/weft_positions" in h5:
        wefts, weft_nodes = h5["reference/weft_positions"].shape[:2]
        planes = (np.arange(wefts) + 0.5) * float(h5.attrs["length_per_weft"])
        found.append(ViewFamily("weft_", 0, planes, weft_nodes, yarns * nodes))
    return found


def row_views(h5: h5py.File, group: str, found: list[ViewFamily]) -> list[str]:
    """The names of a row's views: ``points``, then the point data every family stores, then
    ``plane`` where the planes move."""
    names = ["points"]
    if not found:  # spatial: the nodes' own point data
        return names + [name for name in SPATIAL_POINT_DATA if f"{group}/xdmf/{name}" in h5]
    names += [name for name in POINT_DATA
              if all(f.column(group, f"xdmf/{name}") in h5 for f in found)]
    if all(f.column(group, "xdmf/plane") in h5 for f in found):
        names.append("plane")
    return names


def row_name(group: str, name: str, row: int) -> str:
    """The view ``name`` of row ``row`` (0-based) of a series: ``view/<group>/<name>/<row + 1>``
    (one HDF5 group per name, not one per row: each group adds to the file)."""
    return f"view/{group}/{name}/{row + 1}"


def rows(h5: h5py.File, group: str) -> int:
    """The rows a series' datasets hold (its capacity; 0 if it has none)."""
    return h5[f"{group}/positions"].shape[0] if f"{group}/positions" in h5 else 0


def complete(h5: h5py.File) -> bool:
    """True if a result file holds every view `add_views` would write (the last row's
    stand for the others: they are written together)."""
    if "reference/positions" not in h5:
        return True
    wanted = ["view/points", "view/plane", "view/segments", "view/yarn"]
    found = families(h5)
    for group in GROUPS:
        last = rows(h5, group)
        wanted += [row_name(group, name, last - 1) for name in row_views(h5, group, found)
                   if last]
    return all(name in h5 for name in wanted)


def add_views(h5: h5py.File) -> None:
    """Write ``view/`` into a result file open for writing whose other datasets are written
    (sizes final): the as-woven arrays and every row's views (module docstring). A file
    without ``reference/positions`` gets none."""
    if "reference/positions" not in h5:
        return
    found = families(h5)
    if not found:
        _add_spatial_views(h5)
        return
    total = sum(f.size for f in found)
    _physical(h5, "view/plane", np.concatenate([np.repeat(f.planes, f.nodes) for f in found]))
    pairs = [f.offset + np.arange(f.size).reshape(f.yarns, f.nodes) for f in found]
    _physical(h5, "view/segments", np.concatenate(
        [np.stack([p[:, :-1], p[:, 1:]], -1).reshape(-1, 2) for p in pairs]).astype(np.int32))
    starts = np.cumsum([0] + [f.yarns for f in found[:-1]])  # warps 0, wefts n_wa
    _physical(h5, "view/yarn", np.concatenate(
        [start + np.repeat(np.arange(f.yarns), f.nodes - 1) for f, start in zip(found, starts)]
    ).astype(np.int32))
    virtual = _Virtual(h5)
    virtual.create("view/points", (total, 3), _point_maps(found, "reference/{}positions", (),
                                                        None))
    for group in GROUPS:
        names = row_views(h5, group, found)
        for row in range(rows(h5, group)):
            _row(virtual, group, row, found, total, names)


def _row(virtual: "_Virtual", group: str, row: int, found: list[ViewFamily], total: int,
         names: list[str]) -> None:
    """The views of one row (0-based) of a series (`row_name`)."""
    moving = f"{group}/xdmf/{{}}plane" if "plane" in names else None
    virtual.create(row_name(group, "points", row), (total, 3),
                   _point_maps(found, f"{group}/{{}}positions", (row,), moving))
    for name in names[1:]:
        virtual.create(row_name(group, name, row), (total,), [
            ((f.offset,), (f.size,), f.column(group, f"xdmf/{name}"), (row, 0, 0),
             (1, f.yarns, f.nodes)) for f in found])


def is_spatial(h5: h5py.File) -> bool:
    """A spatial model's file (docs/model.md section 11): ``reference/positions`` is every
    node's (x, y, z), (nodes, 3), chain after chain (``reference/chain_start``)."""
    return "reference/chain_start" in h5


def _add_spatial_views(h5: h5py.File) -> None:
    """A spatial file's views: its points are its positions (virtual, whole rows), the
    segments each chain's consecutive nodes, each segment's yarn its chain (warps, then
    wefts, as ``yarn_labels``: the view tells both families apart by it), ``view/plane`` 0
    (its yarns lie in no plane), and each row's point data its ``xdmf/shear_angle``."""
    start = h5["reference/chain_start"][:]
    total = int(start[-1])
    chain = np.repeat(np.arange(start.size - 1), np.diff(start))
    _physical(h5, "view/plane", np.zeros(total))
    first = np.arange(total - 1)
    keep = chain[first] == chain[first + 1]
    _physical(h5, "view/segments", np.stack([first[keep], first[keep] + 1], 1).astype(np.int32))
    _physical(h5, "view/yarn", chain[first[keep]].astype(np.int32))
    virtual = _Virtual(h5)
    virtual.create("view/points", (total, 3),
                   [((0, 0), (total, 3), "reference/positions", (0, 0), (total, 3))])
    for group in GROUPS:
        names = row_views(h5, group, [])
        for row in range(rows(h5, group)):
            virtual.create(row_name(group, "points", row), (total, 3),
                           [((0, 0), (total, 3), f"{group}/positions", (row, 0, 0),
                             (1, total, 3))])
            for name in names[1:]:
                virtual.create(row_name(group, name, row), (total,),
                               [((0,), (total,), f"{group}/xdmf/{name}", (row, 0), (1, total))])


def _point_maps(found: list[ViewFamily], positions: str, lead: tuple, plane: str | None) -> list:
    """The maps (`_Virtual.create`) of a (P, 3) dataset of 3D points: each family's two
    in-plane coordinates from ``positions`` (its prefix in the braces) after the leading
    index ``lead``, its plane coordinate from ``plane`` likewise, None: ``view/plane``."""
    maps = []
    for f in found:
        first = 0 if f.plane_axis == 1 else 1  # a warp's x, a weft's y
        for column, component in ((first, 0), (2, 1)):
            maps.append(((f.offset, column), (f.size, 1), positions.format(f.prefix),
                         lead + (0, 0, component), (1,) * len(lead) + (f.yarns, f.nodes, 1)))
        maps.append(((f.offset, f.plane_axis), (f.size, 1), "view/plane", (f.offset,), (f.size,))
                    if plane is None else
                    ((f.offset, f.plane_axis), (f.size, 1), plane.format(f.prefix), lead + (0, 0),
                     (1,) * len(lead) + (f.yarns, f.nodes)))
    return maps


class _Virtual:
    """Makes the virtual datasets of a file from its own datasets (h5py's low-level API: the
    high-level one costs several times more per dataset, and a file has a few per row)."""

    def __init__(self, h5: h5py.File) -> None:
        self.h5, self.spaces = h5, {}
        self.links = h5py.h5p.create(h5py.h5p.LINK_CREATE)
        self.links.set_create_intermediate_group(True)

    def space(self, name: str):
        """A fresh copy of dataset ``name``'s dataspace (each looked up once)."""
        if name not in self.spaces:
            self.spaces[name] = self.h5[name].id.get_space()
        return self.spaces[name].copy()

    def create(self, name: str, shape: tuple, maps: list) -> None:
        """The float64 virtual dataset ``name`` of ``shape``, with its units; ``maps``: (start,
        count) in it, the source dataset of this file, (start, count) in that. The source file
        is ".", this file wherever it is moved or copied; NaN where no source maps."""
        plist = h5py.h5p.create(h5py.h5p.DATASET_CREATE)
        plist.set_fill_value(np.array(np.nan))
        whole = h5py.h5s.create_simple(shape)
        for start, count, source, source_start, source_count in maps:
            target = h5py.h5s.create_simple(shape)
            target.select_hyperslab(start, count)
            selected = self.space(source)
            selected.select_hyperslab(source_start, source_count)
            plist.set_virtual(target, b".", source.encode(), selected)
        dataset = h5py.h5d.create(self.h5.id, name.encode(), h5py.h5t.IEEE_F64LE, whole,
                                  dcpl=plist, lcpl=self.links)
        h5py.Dataset(dataset).attrs["units"] = units_of(name)


def _physical(h5: h5py.File, name: str, values: np.ndarray) -> None:
    h5.create_dataset(name, data=values).attrs["units"] = units_of(name)
