"""The view datasets of a result file: what ``<result>.xdmf`` (`dynfab.xdmf`) shows, as whole
HDF5 datasets under ``view/``, made of the file's own rows without copying them.

Why whole datasets: meshio's XDMF reader (``meshio.xdmf.TimeSeriesReader``)
reads an HDF5 DataItem only as a whole dataset, and VTK's XDMF reader
(ParaView's "XDMF Reader") warns on every step whose geometry is a HyperSlab;
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

`add_views` writes all of them; `dynfab.results.ResultFile` calls it whenever
it writes the file's structure (create, first entry, growth, close), so they
are as crash-safe as the structure: published whole, atomically, for every row
the datasets hold, before any row is written.
"""

from __future__ import annotations

import tomllib
from dataclasses import dataclass

import h5py
import numpy as np

from dynfab.results import units_of

LENGTHS_PER_SPACING = 10
"""A sweep's or a rod's yarns are spaced by L / 10 (L the projected length): y = (k-1/2) L/10."""

POINT_DATA = ("contact_force", "slip")
"""Nodal point data: column ``<group>/xdmf/<prefix><name>`` (entries, yarns, nodes)."""

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
    yarns, nodes = h5["reference/positions"].shape[:2]
    found = [ViewFamily("", 1, (np.arange(yarns) + 0.5) * plane_spacing(h5.attrs), nodes, 0)]
    if "reference/weft_positions" in h5:
        wefts, weft_nodes = h5["reference/weft_positions"].shape[:2]
        found.append(ViewFamily("weft_", 0, (np.arange(wefts) + 0.5) * float(h5.attrs["length_per_weft"]),
                            weft_nodes, yarns * nodes))
    return found


def row_views(h5: h5py.File, group: str, found: list[ViewFamily]) -> list[str]:
    """The names of a row's views: ``points``, then the point data every family stores, then
    ``plane`` where the planes move."""
    names = ["points"]
    names += [name for name in POINT_DATA
              if all(f.column(group, f"xdmf/{name}") in h5 for f in found)]
    if all(f.column(group, "xdmf/plane") in h5 for f in found):
        names.append("plane")
    return names


def row_name(group: str, name: str, row: int) -> str:
    """The view ``name`` of row ``row`` (0-based) of a series: ``view/<group>/<name>/<row + 1>``
    (one group per name, not per row: an HDF5 group of the file's format costs about 0.8 kB)."""
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
    total = sum(f.size for f in found)
    _physical(h5, "view/plane", np.concatenate([np.repeat(f.planes, f.nodes) for f in found]))
    pairs = [f.offset + np.arange(f.size).reshape(f.yarns, f.nodes) for f in found]
    _physical(h5, "view/segments", np.concatenate(
        [np.stack([p[:, :-1], p[:, 1:]], -1).reshape(-1, 2) for p in pairs]).astype(np.int32))
    starts = np.cumsum([0] + [f.yarns for f in found[:-1]])  # warps 0, wefts n_wa
    _physical(h5, "view/yarn", np.concatenate(
        [start + np.repeat(np.arange(f.yarns), f.nodes - 1) for f, start in zip(found, starts)]
    ).astype(np.int32))
    source = _Sources(h5)
    _points(source, "view/points", found, total,
            [(f, f"reference/{f.prefix}positions", (), None) for f in found])
    for group in GROUPS:
        names = row_views(h5, group, found)
        for row in range(rows(h5, group)):
            _row(source, group, row, found, total, names)


def _row(source: "_Sources", group: str, row: int, found: list[ViewFamily], total: int,
         names: list[str]) -> None:
    """The views of one row (0-based) of a series (`row_name`)."""
    moving = "plane" in names
    _points(source, row_name(group, "points", row), found, total,
            [(f, f.column(group, "positions"), (row,),
              f.column(group, "xdmf/plane") if moving else None) for f in found])
    for name in names[1:]:
        layout = h5py.VirtualLayout(shape=(total,), dtype=np.float64)
        for f in found:
            layout[f.offset:f.offset + f.size] = source[f.column(group, f"xdmf/{name}")][row]
        source.create(row_name(group, name, row), layout)


def _points(source: "_Sources", name: str, found: list[ViewFamily], total: int,
            parts: list) -> None:
    """A (P, 3) virtual dataset of 3D points: per family (family, positions dataset, leading
    index, plane dataset of the same leading index or None: ``view/plane``)."""
    layout = h5py.VirtualLayout(shape=(total, 3), dtype=np.float64)
    for family, positions, lead, plane in parts:
        nodes = slice(family.offset, family.offset + family.size)
        first, second = (0, 2) if family.plane_axis == 1 else (1, 2)
        layout[nodes, first] = source[positions][lead + (slice(None), slice(None), 0)]
        layout[nodes, second] = source[positions][lead + (slice(None), slice(None), 1)]
        if plane is None:
            layout[nodes, family.plane_axis] = source["view/plane"][nodes]
        else:
            layout[nodes, family.plane_axis] = source[plane][lead]
    source.create(name, layout)


class _Sources:
    """The datasets of a file as sources of its virtual datasets (each looked up once), and
    the virtual datasets made of them."""

    def __init__(self, h5: h5py.File) -> None:
        self.h5, self.found = h5, {}

    def __getitem__(self, name: str) -> h5py.VirtualSource:
        """Dataset ``name`` of this file as a source: file name ".", this file wherever it is
        moved or copied."""
        if name not in self.found:
            dataset = self.h5[name]
            self.found[name] = h5py.VirtualSource(".", name, shape=dataset.shape,
                                                  dtype=dataset.dtype)
        return self.found[name]

    def create(self, name: str, layout: h5py.VirtualLayout) -> None:
        """The virtual dataset ``name``, with its units (NaN where no source maps)."""
        dataset = self.h5.create_virtual_dataset(name, layout, fillvalue=np.nan)
        dataset.attrs["units"] = units_of(name)


def _physical(h5: h5py.File, name: str, values: np.ndarray) -> None:
    h5.create_dataset(name, data=values).attrs["units"] = units_of(name)
