"""The view of a result file: ``<result>.xdmf`` beside ``<result>.h5``, for ParaView and meshio.

An XDMF 3 file is XML that describes meshes whose numbers stay in the HDF5
file. This one opens in ParaView (``paraview out/paper_fig3.xdmf``: its "XDMF
Reader", which is VTK's ``vtkXdmfReader``) and in plain meshio
(``meshio.xdmf.TimeSeriesReader``), and shows every yarn of the file, the
fabric's warps and wefts together, over the load steps (tests/test_xdmf.py
reads it with both and compares with the HDF5 file).

Layout, chosen so that both readers open it (why: docs/model.md, "The view";
measured: docs/results.md, "The view"):

* a Uniform grid ``as-woven`` (meshio's mesh): the segments of every yarn as
  a ``Polyline`` of 2 nodes per element (``view/segments``; meshio's "line"
  cells), ``XYZ`` geometry (``view/points``), point data ``plane``, cell
  data ``yarn``;
* one Temporal collection ``yarns`` with one Uniform grid per *finished* load
  step (rows ``[0, steps_done)``), ``Time`` = the step's load value (the first
  column of ``steps/load``: a force [N], an end displacement or a specimen's
  clamp displacement d [m]), as ParaView's time shows it, where the finished
  steps' loads strictly increase; where they do not (a cycle going back and
  forth: ParaView orders grids by time), the step number 1, 2, ... (the
  summary table's ``step``). The load value is also each grid's ``Information
  load``. A transient run (``frames/``) gets one grid per frame with ``Time``
  = the frame's time [s].
* each step's grid: the same topology, its ``XYZ`` geometry, and point data
  ``position`` (the same 3D points [m]: meshio reads a step's point data, not
  its geometry), ``plane`` (the yarn's plane coordinate [m]: y of a warp or of
  a yarn of the one-yarn model, x of a weft), ``contact_force`` R [N] and
  ``slip`` [m] at the crossing nodes, 0 at the other nodes, and cell data
  ``yarn``;
* every DataItem is a whole HDF5 dataset of the result file's ``view/`` group
  (`dynfab.results.views`: virtual datasets into its rows, no number copied): meshio
  reads no HyperSlab and no ``X_Y_Z`` geometry, and VTK reports errors on
  HyperSlab geometry. A file written without ``steps/xdmf/*`` (point data per node)
  gets geometry, ``position`` and ``plane`` only.

When it is written: by a run after every finished step (`XdmfSync`, atomically:
a temporary file, then ``os.replace``), after an interrupt and at the end;
``dynfab xdmf RESULT.h5`` (re)writes it for any result file, and first adds
``view/`` to a file written before it existed (one atomic rewrite of the file,
under its writer lock). It lists only finished steps: a ``kill -9`` can leave
it behind the HDF5 file by the steps of its last fraction of a second
(`XdmfSync`), never ahead; ``--resume`` and ``dynfab xdmf`` bring it up to
date.
"""

from __future__ import annotations

import contextlib
import os
import time
from dataclasses import dataclass
from pathlib import Path
from xml.sax.saxutils import escape

import h5py
import numpy as np

from dynfab.errors import UserError
from dynfab.results.file import ResultFile, _remove_stale_tmp, _tmp_path
from dynfab.results.views import add_views, complete, families, row_name, row_views


def xdmf_path(result: str | os.PathLike) -> Path:
    """The XDMF file of a result file: same name, suffix ``.xdmf``."""
    return Path(result).with_suffix(".xdmf")


@dataclass(frozen=True)
class _Layout:
    """What the XDMF of a file needs: its sizes, finished entries and their time values."""

    h5_name: str
    group: str
    count: int
    points: int
    """P: the nodes of all yarns."""
    segments: int
    """S: the line segments of all yarns."""
    names: list[str]
    """The views of a row (`dynfab.results.views.row_views`)."""
    times: np.ndarray
    loads: np.ndarray | None


def _read_layout(path: Path) -> _Layout | None:
    """Sizes, finished counts and time values of a result file (no step data is read); None
    if it lacks views of its finished entries (written before `dynfab.results.views`)."""
    try:
        with h5py.File(path, "r") as h5:
            if "dynfab_version" not in h5.attrs:
                raise UserError(f"'{path}' is not a dynfab result file")
            group = "frames" if _count(h5, "frames") else "steps"
            count = _count(h5, group)
            names = row_views(h5, group, families(h5))
            if not complete(h5):
                return None
            loads = h5["steps/load"][:count, 0] if group == "steps" and count else None
            times = (h5["frames/time"][:count] if group == "frames" else step_times(loads))
            points, segments = h5["view/points"].shape[0], h5["view/segments"].shape[0]
    except (KeyError, ValueError) as error:
        raise UserError(f"'{path}' is not a dynfab result file (no {error})") from None
    except OSError as error:
        raise UserError(f"cannot read result file '{path}': {str(error).splitlines()[0]}") from None
    return _Layout(path.name, group, count, points, segments, names, times, loads)


def step_times(loads: np.ndarray | None) -> np.ndarray:
    """The ``Time`` of each finished step (module docstring): its load where the loads
    strictly increase, else its number 1, 2, ..."""
    if loads is None or loads.size == 0:
        return np.zeros(0)
    loads = np.asarray(loads, float)
    if np.all(np.diff(loads) > 0.0) and np.all(np.isfinite(loads)):
        return loads
    return np.arange(1, loads.size + 1, dtype=float)


def _count(h5: h5py.File, group: str) -> int:
    """Finished rows of a group (files without a count: the datasets' length)."""
    if f"{group}_done" in h5:
        return int(h5[f"{group}_done"][0])
    if f"{group}/positions" in h5:
        return int(h5[f"{group}/positions"].shape[0])
    return 0


def _item(layout: _Layout, dataset: str, *shape: int, integer: bool = False) -> str:
    """A DataItem naming a whole dataset of the result file (found beside the XDMF file)."""
    kind, precision = ("Int", 4) if integer else ("Float", 8)  # dynfab.results.views' dtypes
    return (f'<DataItem Format="HDF" NumberType="{kind}" Precision="{precision}" '
            f'Dimensions="{" ".join(map(str, shape))}">{escape(layout.h5_name)}:/{dataset}'
            '</DataItem>')


def _attribute(name: str, item: str, kind: str = "Scalar", center: str = "Node") -> str:
    return f'<Attribute Name="{name}" AttributeType="{kind}" Center="{center}">{item}</Attribute>'


def _mesh(layout: _Layout, points: str) -> str:
    """The topology, the geometry ``points`` (a dataset) and the cell data ``yarn``."""
    S, P = layout.segments, layout.points
    return (f'<Topology TopologyType="Polyline" NumberOfElements="{S}" NodesPerElement="2">'
            f'{_item(layout, "view/segments", S, 2, integer=True)}</Topology>'
            f'<Geometry GeometryType="XYZ">{_item(layout, points, P, 3)}</Geometry>'
            + _attribute("yarn", _item(layout, "view/yarn", S, integer=True), center="Cell"))


def render(layout: _Layout) -> str:
    """The XDMF text of a result file's layout."""
    P = layout.points
    lines = ['<?xml version="1.0" encoding="utf-8"?>', '<Xdmf Version="3.0">', "<Domain>",
             '<Grid Name="as-woven" GridType="Uniform">' + _mesh(layout, "view/points")
             + _attribute("plane", _item(layout, "view/plane", P)) + "</Grid>",
             '<Grid Name="yarns" GridType="Collection" CollectionType="Temporal">']
    lines += [_step_grid(layout, entry) for entry in range(layout.count)]
    lines += ["</Grid>", "</Domain>", "</Xdmf>", ""]
    return "\n".join(lines)


def _step_grid(layout: _Layout, entry: int) -> str:
    """One finished entry: its time, the topology, its geometry and point data."""
    P, group = layout.points, layout.group
    parts = [f'<Grid Name="{layout.group} {entry + 1}" GridType="Uniform">',
             f'<Time Value="{float(layout.times[entry])!r}"/>']
    if layout.loads is not None:
        parts.append(f'<Information Name="load" Value="{float(layout.loads[entry])!r}"/>')
    points = row_name(group, "points", entry)
    parts += [_mesh(layout, points), _attribute("position", _item(layout, points, P, 3), "Vector"),
              _attribute("plane", _item(layout, row_name(group, "plane", entry)
                                        if "plane" in layout.names else "view/plane", P))]
    parts += [_attribute(name, _item(layout, row_name(group, name, entry), P))
              for name in layout.names if name not in ("points", "plane")]
    parts.append("</Grid>")
    return "".join(parts)


def write_xdmf(result: str | os.PathLike) -> Path:
    """Write ``<result>.xdmf`` for the finished steps (or frames) of a result file; its path.

    Atomic: a temporary file beside it, then ``os.replace``. A file without
    ``view/`` (written before it existed) first gets it (`add_views`, one atomic
    rewrite under the writer lock). UserError (one line) for a missing or
    foreign file, or one another process writes without views.
    """
    path = Path(result)
    if not path.is_file():
        raise UserError(f"result file '{path}' does not exist")
    layout = _read_layout(path)
    if layout is None:
        _add_views(path)
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


def has_views(result: str | os.PathLike) -> bool:
    """True if a result file holds all its views (`dynfab.results.views.complete`)."""
    with h5py.File(result, "r") as h5:
        return complete(h5)


def _add_views(path: Path) -> None:
    """Add ``view/`` to a result file: its structure rewritten (atomically) with them, the
    rows and the finished counts as they are."""
    sink = ResultFile.resume(path, views=add_views)
    try:
        sink.flush()
    finally:
        sink.close(trim=False)


class XdmfSync:
    """Keeps a run's XDMF file in step with its result file.

    `update` after every finished entry rewrites it unless the last rewrite
    took more than `SHARE` of the time since it ended (short steps, or so many
    that the O(steps) text would dominate). So the view lags the result file by
    at most the steps finished in the last 1/`SHARE` = 20 rewrite times (their
    cost: docs/results.md, "The view"), and only after a ``kill -9``; `finish`
    always rewrites it.
    """

    SHARE = 0.05
    """Largest share of a run's time spent rewriting its view (its cost: docs/results.md,
    "The view")."""

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
