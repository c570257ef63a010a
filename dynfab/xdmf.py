"""The ParaView view of a result file: ``<result>.xdmf`` beside ``<result>.h5``.

An XDMF 3 file is XML that describes meshes whose numbers stay in the HDF5
file: every array here is a ``HyperSlab`` of a dataset of the result file
(one row of ``steps/positions``, ...), never a copy. ParaView opens it
(``paraview out/paper_fig3.xdmf``) and shows the yarns as polylines over the
load steps; checked with VTK's XDMF reader, ParaView's "XDMF Reader"
(tests/test_xdmf.py, where the ``vtk`` package is installed).

Layout of the XDMF file:

* a Uniform grid ``as-woven``: the reference state (``reference/positions``),
  whose Topology (one Polyline of N+1 nodes per yarn) and plane coordinates
  every step includes (``xi:include``), so the XML holds them once;
* a Temporal collection per yarn family (the one-yarn model: ``warp yarns``)
  with one Uniform grid per *finished* load step (rows ``[0, steps_done)``),
  ``Time`` = the step number 1, 2, ... (the summary table's ``step``): not the
  load value, because a load path may go back and forth (a cycle) and ParaView
  orders grids by time; the load value is each grid's ``Information load``.
  A transient run (``frames/``) gets one grid per frame with ``Time`` = the
  frame's time [s].
* Geometry ``X_Y_Z``: a yarn of the one-yarn model moves in (x, z); yarn k
  lies in the plane ``y = (k - 1/2) w`` with ``w`` the fabric width per yarn
  (`dynfab.model.width_per_yarn`, root attribute ``width_per_yarn``). The
  yarns of a ``[sweep]`` are not neighbours in a fabric, and a rod has no
  width: they are spaced by L / `LENGTHS_PER_SPACING` (L the projected length).
  (The fabric model, docs/model.md section 10, adds a second family: wefts in the
  planes ``x = X_j`` moving in (y, z), a second `Family` with ``plane_axis``
  0. Where its planes move, with "affine" planes or on a periodic cell, each step
  stores every node's plane coordinate, ``steps/xdmf/plane`` (the warps' y = Y_k)
  and ``steps/xdmf/weft_plane`` (the wefts' x = X_j) [m], and a step's grid
  draws its yarns there, a HyperSlab of them, instead of in the as-woven planes.)
* point data (Center="Node") ``contact_force`` R [N] and ``slip`` x - anchor
  [m] at the crossing nodes, 0 at the other nodes: the datasets
  ``steps/xdmf/contact_force`` and ``steps/xdmf/slip`` that `nodal_point_data`
  adds to every step as it is written (so they are as crash-safe as the step
  and survive ``--resume``); a file written without them gets the geometry only.

When it is written: by a run after every finished step (`XdmfSync`, atomically:
a temporary file, then ``os.replace``), after an interrupt and at the end;
``dynfab xdmf RESULT.h5`` (re)writes it for any result file. It lists only
finished steps: a ``kill -9`` can leave it behind the HDF5 file by the steps of
its last fraction of a second (`XdmfSync`), never ahead; ``--resume`` and
``dynfab xdmf`` bring it up to date.
"""

from __future__ import annotations

import contextlib
import os
import time
import tomllib
from dataclasses import dataclass
from pathlib import Path
from xml.sax.saxutils import escape, quoteattr

import h5py
import numpy as np

from dynfab.errors import UserError
from dynfab.results import _remove_stale_tmp, _tmp_path

LENGTHS_PER_SPACING = 10
"""A sweep's or a rod's yarns are spaced by L / 10 (L the projected length): y = (k-1/2) L/10."""

POINT_DATA = {"contact_force": "N", "slip": "m"}
"""Nodal point data: name -> units; dataset ``<group>/xdmf/<name>``, shape (entries, yarns, N+1)."""


def xdmf_path(result: str | os.PathLike) -> Path:
    """The XDMF file of a result file: same name, suffix ``.xdmf``."""
    return Path(result).with_suffix(".xdmf")


def nodal_point_data(positions: np.ndarray, anchors: np.ndarray, contact_force: np.ndarray,
                     crossing_nodes: np.ndarray) -> dict[str, np.ndarray]:
    """One step's (or frame's) point data on every node: R [N] and slip x - anchor [m] at the
    crossing nodes, 0 elsewhere; keys ``xdmf/contact_force``, ``xdmf/slip``, (yarns, N+1)."""
    yarns, nodes = positions.shape[:2]
    force, slip = np.zeros((yarns, nodes)), np.zeros((yarns, nodes))
    if len(crossing_nodes):
        force[:, crossing_nodes] = contact_force
        slip[:, crossing_nodes] = positions[:, crossing_nodes, 0] - anchors
    return {"xdmf/contact_force": force, "xdmf/slip": slip}


@dataclass(frozen=True)
class Family:
    """One yarn family: its positions (entries, yarns, N+1, 2) and where its yarns lie."""

    name: str
    positions: str
    """Dataset of the positions, the two in-plane coordinates last."""
    reference: str
    """Dataset of the as-woven positions (yarns, N+1, 2)."""
    plane_axis: int
    """The 3D axis normal to the yarns' planes: 1 (y) for warps, 0 (x) for wefts."""
    planes: np.ndarray
    """The plane coordinate of each yarn [m]."""
    point_data: dict[str, str]
    """Attribute name -> dataset of nodal point data (entries, yarns, N+1)."""
    moving_planes: str | None = None
    """Dataset of every node's plane coordinate per entry (entries, yarns, N+1) [m] where the
    planes move (a fabric's "affine" planes or periodic cell), else None: the as-woven
    `planes`."""


@dataclass(frozen=True)
class _Layout:
    """What the XDMF of a file needs: the families, entries and their time values."""

    h5_name: str
    group: str
    count: int
    shapes: dict[str, tuple]
    families: list[Family]
    times: np.ndarray
    loads: np.ndarray | None


_ATTRS = ("dynfab_version", "width_per_yarn", "projected_length", "scene", "length_per_weft")
"""The root attributes the view reads (all of them take longer)."""


def _plane_spacing(attrs: dict) -> float:
    """Width per yarn of a fabric; L / `LENGTHS_PER_SPACING` for a sweep or a rod."""
    width = attrs.get("width_per_yarn")
    scene = attrs.get("scene", "")
    try:
        sweep = "sweep" in tomllib.loads(scene.decode() if isinstance(scene, bytes) else scene)
    except tomllib.TOMLDecodeError:
        sweep = False
    if width is None or sweep:
        return float(attrs["projected_length"]) / LENGTHS_PER_SPACING
    return float(width)


def _read_layout(path: Path) -> _Layout:
    """Shapes, finished counts and attributes of a result file (no step data is read)."""
    try:
        with h5py.File(path, "r") as h5:
            attrs = {key: h5.attrs[key] for key in _ATTRS if key in h5.attrs}
            if "dynfab_version" not in attrs:
                raise UserError(f"'{path}' is not a dynfab result file")
            group = "frames" if _count(h5, "frames") else "steps"
            count = _count(h5, group)
            wanted = ["reference/positions", f"{group}/positions"]  # a fabric: per family
            wanted += [f"{group}/xdmf/{name}" for name in POINT_DATA]
            wanted += ["reference/weft_positions", f"{group}/weft_positions"]  # docs/model.md
            # section 10
            wanted += [f"{group}/xdmf/weft_{name}" for name in POINT_DATA]
            wanted += [f"{group}/xdmf/plane", f"{group}/xdmf/weft_plane"]  # moving planes
            shapes = {name: h5[name].shape for name in wanted if name in h5}
            times = (h5["frames/time"][:count] if group == "frames"
                     else np.arange(1, count + 1, dtype=float))
            loads = h5["steps/load"][:count, 0] if group == "steps" and count else None
        yarns = shapes["reference/positions"][0]
        spacing = _plane_spacing(attrs)
    except (KeyError, ValueError) as error:
        raise UserError(f"'{path}' is not a dynfab result file (no {error})") from None
    except OSError as error:
        raise UserError(f"cannot read result file '{path}': {str(error).splitlines()[0]}") from None
    point_data = {name: f"{group}/xdmf/{name}" for name in POINT_DATA
                  if f"{group}/xdmf/{name}" in shapes}
    moving = {prefix: f"{group}/xdmf/{prefix}plane" if f"{group}/xdmf/{prefix}plane" in shapes
              else None for prefix in ("", "weft_")}
    warps = Family("warp yarns", f"{group}/positions", "reference/positions", 1,
                   (np.arange(yarns) + 0.5) * spacing, point_data, moving[""])
    families = [warps]
    if "reference/weft_positions" in shapes:  # a fabric: wefts in the planes x = X_j
        wefts = shapes["reference/weft_positions"][0]
        families.append(Family(
            "weft yarns", f"{group}/weft_positions", "reference/weft_positions", 0,
            (np.arange(wefts) + 0.5) * float(attrs["length_per_weft"]),
            {name: f"{group}/xdmf/weft_{name}" for name in POINT_DATA
             if f"{group}/xdmf/weft_{name}" in shapes}, moving["weft_"]))
    return _Layout(path.name, group, count, shapes, families, times, loads)


def _count(h5: h5py.File, group: str) -> int:
    """Finished rows of a group (files without a count: the datasets' length)."""
    if f"{group}_done" in h5:
        return int(h5[f"{group}_done"][0])
    if f"{group}/positions" in h5:
        return int(h5[f"{group}/positions"].shape[0])
    return 0


def _hdf(layout: _Layout, dataset: str) -> str:
    """A DataItem naming a whole dataset of the result file (the XDMF file's folder)."""
    shape = layout.shapes[dataset]
    return (f'<DataItem Format="HDF" NumberType="Float" Precision="8" '
            f'Dimensions="{" ".join(map(str, shape))}">{escape(layout.h5_name)}:/{dataset}'
            '</DataItem>')


def _slab(layout: _Layout, dataset: str, start: tuple, count: tuple) -> str:
    """A HyperSlab DataItem: ``count`` values of ``dataset`` from ``start``, stride 1."""
    rows = " ".join(map(str, start)) + "  " + " ".join("1" * len(start)) + "  " + \
        " ".join(map(str, count))
    return (f'<DataItem ItemType="HyperSlab" Dimensions="{" ".join(map(str, count))}" '
            f'Type="HyperSlab"><DataItem Dimensions="3 {len(start)}" Format="XML">{rows}'
            f'</DataItem>{_hdf(layout, dataset)}</DataItem>')


def _coordinates(layout: _Layout, family: Family, positions: str, entry: int | None,
                 planes: str) -> str:
    """The X_Y_Z Geometry of a family: the two in-plane coordinates from ``positions`` (row
    ``entry``, or the whole reference), the plane coordinate from ``planes``."""
    shape = layout.shapes[positions]
    lead = () if entry is None else (entry,)
    yarns, nodes = shape[-3], shape[-2]
    count = (1,) * len(lead) + (yarns, nodes, 1)
    inplane = [_slab(layout, positions, lead + (0, 0, c), count) for c in (0, 1)]
    axes = [inplane[0], planes, inplane[1]] if family.plane_axis == 1 else \
        [planes, inplane[0], inplane[1]]
    return f'<Geometry GeometryType="X_Y_Z">{"".join(axes)}</Geometry>'


def _planes_item(family: Family, nodes: int) -> str:
    """The plane coordinate of every node (yarn by yarn), inline: the one array not in the file."""
    values = np.repeat(family.planes, nodes)
    text = " ".join(repr(float(v)) for v in values)
    return f'<DataItem Format="XML" NumberType="Float" Precision="8" Dimensions="{values.size}">' \
           f'{text}</DataItem>'


def _topology(yarns: int, nodes: int) -> str:
    """One Polyline of N+1 nodes per yarn, nodes numbered yarn by yarn."""
    numbers = " ".join(map(str, range(yarns * nodes)))
    return (f'<Topology TopologyType="Polyline" NumberOfElements="{yarns}" '
            f'NodesPerElement="{nodes}"><DataItem Format="XML" NumberType="Int" '
            f'Dimensions="{yarns} {nodes}">{numbers}</DataItem></Topology>')


def _include(xpath: str) -> str:
    return f'<xi:include xpointer={quoteattr(f"xpointer({xpath})")}/>'


def render(layout: _Layout) -> str:
    """The XDMF text of a result file's layout."""
    lines = ['<?xml version="1.0" encoding="utf-8"?>',
             '<Xdmf xmlns:xi="http://www.w3.org/2001/XInclude" Version="3.0">', "<Domain>"]
    for family in layout.families:
        yarns, nodes = layout.shapes[family.reference][0:2]
        reference = f"as-woven {family.name}"
        lines += [f'<Grid Name="{reference}" GridType="Uniform">', _topology(yarns, nodes),
                  _coordinates(layout, family, family.reference, None,
                               _planes_item(family, nodes)), "</Grid>"]
        grid = f'//Grid[@Name="{reference}"]'
        lines.append(f'<Grid Name="{family.name}" GridType="Collection" '
                     'CollectionType="Temporal">')
        for entry in range(layout.count):
            lines.append(_step_grid(layout, family, entry, grid, yarns, nodes))
        lines.append("</Grid>")
    lines += ["</Domain>", "</Xdmf>", ""]
    return "\n".join(lines)


def _step_grid(layout: _Layout, family: Family, entry: int, reference: str, yarns: int,
               nodes: int) -> str:
    """One finished entry: its time, the shared topology, its geometry and point data."""
    if family.moving_planes is None:
        planes = _include(f"{reference}/Geometry/DataItem[{family.plane_axis + 1}]")  # X_Y_Z
    else:  # the planes where they are at this entry
        planes = _slab(layout, family.moving_planes, (entry, 0, 0), (1, yarns, nodes))
    parts = [f'<Grid Name="{layout.group} {entry + 1}" GridType="Uniform">',
             f'<Time Value="{float(layout.times[entry])!r}"/>']
    if layout.loads is not None:
        parts.append(f'<Information Name="load" Value="{float(layout.loads[entry])!r}"/>')
    parts += [_include(f"{reference}/Topology"),
              _coordinates(layout, family, family.positions, entry, planes)]
    for name, dataset in family.point_data.items():
        parts.append(f'<Attribute Name="{name}" AttributeType="Scalar" Center="Node">'
                     f'{_slab(layout, dataset, (entry, 0, 0), (1, yarns, nodes))}</Attribute>')
    parts.append("</Grid>")
    return "".join(parts)


def write_xdmf(result: str | os.PathLike) -> Path:
    """Write ``<result>.xdmf`` for the finished steps (or frames) of a result file; its path.

    Atomic: a temporary file beside it, then ``os.replace``. UserError (one
    line) for a missing or foreign file.
    """
    path = Path(result)
    if not path.is_file():
        raise UserError(f"result file '{path}' does not exist")
    layout = _read_layout(path)
    target = xdmf_path(path)
    _remove_stale_tmp(target)  # left by a writer killed mid-write
    tmp = _tmp_path(target)
    try:
        tmp.write_text(render(layout), encoding="utf-8")
        os.replace(tmp, target)
    except OSError as error:
        with contextlib.suppress(OSError):
            tmp.unlink()
        raise UserError(f"cannot write '{target}': {error.strerror or error}") from None
    return target


class XdmfSync:
    """Keeps a run's XDMF file in step with its result file.

    `update` after every finished entry rewrites it unless the last rewrite
    took more than `SHARE` of the time since it ended (short steps, or so many
    that the O(steps) text would dominate). So the view lags the result file by
    at most the steps finished in the last 1/`SHARE` = 20 rewrite times (8 ms
    per rewrite at 100 steps, 19 ms at 1000: benchmarks/xdmf.py), and only
    after a ``kill -9``; `finish` always rewrites it.
    """

    SHARE = 0.05
    """Largest share of a run's time spent rewriting its view (benchmarks/xdmf.py)."""

    def __init__(self, result: str | os.PathLike) -> None:
        self.result = Path(result)
        self.last_end = 0.0
        self.last_took = 0.0

    def update(self) -> None:
        if self.last_took <= self.SHARE * (time.perf_counter() - self.last_end):
            self.finish()

    def finish(self) -> None:
        started = time.perf_counter()
        write_xdmf(self.result)
        self.last_end = time.perf_counter()
        self.last_took = self.last_end - started
