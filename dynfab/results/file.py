"""Crash-safe HDF5 result files, appended in place: O(1) per finished step.

Guarantee: whatever the moment of a kill, even ``kill -9``, the file opens
with plain ``h5py.File(path, "r")`` and holds every finished load step (and
transient frame), and `ResultFile.resume` continues it exactly.

How (measured by ``benchmarks/io.py``; the reasons for this design):

* The HDF5 *structure* (groups, datasets, attributes, their sizes) is only
  ever written whole: to ``<name>.tmp-<pid>``, fsynced, then published
  atomically, with ``os.link`` for a new file (fails if another process
  created the name first) or ``os.replace`` otherwise. This happens at
  create, at the first entry of a series, when a series outgrows its
  capacity (the capacity doubles, so the copies cost O(1) per entry
  amortised), on `ResultFile.set_attrs` + `flush`, and at `close`, which
  trims the datasets to the finished count.
* Every per-entry dataset is allocated at once at its full capacity (the
  run's number of load steps or frames, known before it starts):
  contiguous, early allocation, filled with NaN (-1 for integers, False for
  bools). An entry is then raw bytes written with ``os.pwrite`` at the
  row's file offset, which HDF5 reports (``get_offset``): no HDF5 call, so
  no HDF5 metadata (chunk index, extent, object header) can change, and the
  file is the old format (superblock v0, library default ``libver``), which
  keeps no "file open for writing" flag a kill could leave set. Order: the
  rows, ``fdatasync``, then the 8-byte count ``steps_done`` (or
  ``frames_done``). A kill before the count is written leaves the previous
  count: the half-written row is beyond it; a kill after it loses nothing
  (the page cache outlives the process). The count reaches the disk with the
  next append's ``fdatasync`` (or `close`'s), so a power failure can lose
  the last step but never count a row not on disk. One sync per step, not
  two: the sync, not the writing, is most of an append's cost.
* Rejected: rewriting the whole file per step (the former design, O(steps)
  per step); chunked resizable datasets (each append changes the chunk
  index and the extent, metadata that a kill can leave half-written unless
  the file is copied); SWMR (superblock v3 keeps a writer flag that a killed
  writer leaves set, so a plain open fails until ``h5clear -s``); a side
  journal (a second file to merge and to lose).
* One writer per file: the writer holds an open-file-description lock
  (``F_OFD_SETLK``) on the file for its whole run. It is a fcntl lock, not
  the ``flock`` HDF5 itself takes on open, so readers (``h5py`` "r", plots
  of a running job) are never blocked; a second writer is refused.

The layout is a contract (scripts read it; never rename):

* root attributes: ``scene`` (TOML text), ``solver``, ``dynfab_version``,
  ``units = "SI"``, plus the caller's (``load_control``, ``projected_length``,
  ``width_per_yarn``, ``reference_state``, ``title``, ``yarn_labels``, ...);
* ``reference/<name>``: the as-woven state;
* ``steps/<name>``: one row per load step, stacked on axis 0;
* ``frames/<name>``: one row per output frame of a transient run;
* ``steps_done``, ``frames_done``: int64 arrays of one element, the number
  of finished rows of ``steps/`` and ``frames/``. Only rows
  ``[0, steps_done)`` are finished. A file whose run ended (finished, or
  stopped by a solver failure) has exactly ``steps_done`` rows; a file whose
  writer was killed may have more, holding the fill values above (files
  written before these counts existed have none: every row is finished);
* ``view/``: what the XDMF view shows, as whole datasets (`dynfab.results.views`),
  mostly virtual datasets into ``reference/`` and the rows of ``steps/`` and
  ``frames/``; written with the structure, for every row it holds, by the
  ``views`` function a writer is given (`dynfab.results.views.add_views`; files
  written without one have no ``view/``).

Every dataset carries a ``units`` attribute taken from `UNITS`, the one table
of dataset names; a name not in it is refused at append, so a new dataset
must be documented here before it can be written.
"""

from __future__ import annotations

import contextlib
import errno
import functools
import glob
import importlib.metadata
import os
import re
import struct
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Iterable, Mapping

import h5py
import numpy as np

from dynfab.errors import UserError

ENERGY_TERM = "<term>"
"""Placeholder in `UNITS` for any energy term name (``energy/stretch``, ...)."""

LOAD_CONTROL_UNITS = "<load_control>"
"""Placeholder in `UNITS`: the units follow the root attribute ``load_control``."""

LOAD_UNITS = {"force": "N", "displacement": "m"}

ENTRY = "<entry>"
"""Placeholder in `UNITS` for a row number 1, 2, ... of ``view/steps/`` and ``view/frames/``."""
"""Units of ``steps/load`` for each value of the root attribute ``load_control``."""

UNITS: dict[str, str] = {
    # As-woven reference state.
    "reference/positions": "m",  # (yarns, N+1, 2) node (x, z)
    "reference/crossing_nodes": "-",  # (crossings,) node index of each crossing
    "reference/weft_positions": "m",  # fabric: (n_we, M+1, 2) weft node (y, z)
    "reference/weft_crossing_nodes": "-",  # fabric: (n_wa,) weft node of each crossing
    "reference/chain_start": "-",  # specimen: (chains+1,) first node of each chain
    "reference/chain_family": "-",  # specimen: (chains,) 0 warp, 1 weft
    "reference/crossing_lattice": "-",  # specimen: (crossings, 2) lattice (k, j) from the centre
    "reference/crossing_positions": "m",  # specimen: (crossings, 2) in-plane, as woven
    "reference/zone": "-",  # specimen: (crossings,) bias extension's zone, 0 A, 1 B, 2 C
    "reference/interior": "-",  # specimen: (crossings,) bool, neither yarn's end crossing
    "reference/held": "-",  # specimen: (nodes,) bool, held by a clamp or bar
    "reference/free_end_rank": "-",  # specimen: (crossings,) rank from a free yarn end, 1 last
    # One entry per finished load step (axis 0 = steps).
    "steps/clamp_force": "N",  # specimen: (steps,) force on the moved clamp (corner) along d
    "steps/clamp_force_from_step_0": "N",  # specimen: (steps,) the same less step 0's
    "steps/shear_force": "N",  # specimen: (steps,) picture frame F / (2 cos theta); NaN bias
    "steps/normalised_shear_force": "N/m",  # specimen: (steps,) frame eq. 10; bias Harrison
    "steps/crossing_positions": "m",  # specimen: (steps, crossings, 3) warp node of each crossing
    "steps/shear_angle": "rad",  # specimen: (steps, crossings) gamma from step 0
    "steps/reference_angle": "rad",  # specimen: (steps, crossings) step 0's gamma from as woven
    "steps/crossing_slip_ratio": "-",  # specimen: (steps, crossings) in-plane offset / segment
    "steps/lateral_gap": "m",  # specimen: (steps, lateral contacts) w - d, > 0 pressing
    "steps/yarn_width": "m",  # specimen: (steps, lateral contacts) min(d, w), the narrowed width
    "steps/fibre_volume_fraction": "-",  # specimen: (steps, lateral contacts) V0 w / min(d, w)
    "steps/max_slope": "-",  # specimen: (steps,) largest |e_z| / |e_xy| of a segment
    "steps/xdmf/shear_angle": "rad",  # specimen: (steps, nodes) gamma at crossing nodes
    "steps/load": LOAD_CONTROL_UNITS,  # (steps, yarns) applied value, N or m
    "steps/end_force": "N",  # (steps, yarns) P at the end node
    "steps/end_displacement": "m",  # (steps, yarns) end node x displacement
    "steps/positions": "m",  # (steps, yarns, N+1, 2)
    "steps/contact_force": "N",  # (steps, yarns, crossings)
    "steps/friction_force": "N",  # (steps, yarns, crossings)
    "steps/friction_limit": "N",  # (steps, yarns, crossings)
    "steps/sliding": "-",  # (steps, yarns, crossings) bool
    "steps/anchors": "m",  # friction spring anchors
    f"steps/energy/{ENERGY_TERM}": "J",  # (steps, yarns) one per energy term
    "steps/dissipated": "J",  # (steps, yarns) friction work so far
    "steps/crimp": "-",  # (steps, yarns)
    "steps/residual": "N",  # (steps, yarns) force residual reached
    "steps/iterations": "-",  # Newton iterations
    "steps/rounding_floor": "-",  # (steps, yarns) bool: residual stopped falling above tolerance
    "steps/wall_time": "s",  # (steps,)
    "steps/compile_time": "s",  # (steps,) of wall_time, compiling kernels (a first run's)
    "steps/time_steps": "-",  # dynamic solver: time steps taken
    "steps/cg_iterations": "-",  # semi-implicit dynamic solver: CG iterations of the step
    "steps/force_evaluations": "-",  # dynamic solver
    "steps/dt": "s",  # dynamic solver time step
    "steps/stable": "-",  # (steps, yarns) bool: no negative pivot of the frozen-F_T Hessian
    "steps/buckled": "-",  # (steps, yarns) bool: the step left a saddle (an escape was taken)
    "steps/lowest_eigenvalue": "N/m",  # (steps, yarns) lambda_min of that Hessian, an upper bound
    "steps/lowest_eigenvalue_error": "N/m",  # (steps, yarns) lambda_min >= lowest_eigenvalue - this
    "steps/error_estimate": "m",  # (steps, yarns) residual x est ||H^-1||_inf, position error bound
    "steps/tolerance": "N",  # dynamic solver: the residual each load step had to reach
    "steps/weft_positions": "m",  # fabric: (steps, n_we, M+1, 2) weft node (y, z)
    "steps/strain": "-",  # fabric: (steps, 2) nominal strain (warp, weft)
    "steps/stress": "N/m",  # fabric: (steps, 2) load per unit width (warp, weft); yarn: (steps, yarns)
    "steps/slip_ratio": "-",  # fabric: (steps,) largest crossing node slip / segment; yarn: per yarn
    "steps/work": "J",  # fabric: (steps,) work of the end loads so far
    "steps/slip": "m",  # fabric, sliding crossings: (steps, n_wa, n_we, 2) slide along warp, weft
    "steps/material": "m",  # fabric, sliding crossings: (steps, n_wa, n_we, 2) u_a, u_b now
    "steps/crossing_present": "-",  # fabric, sliding crossings: (steps, n_wa, n_we) bool
    "steps/friction_solves": "-",  # fabric: (steps,) Newton solves of the friction update
    "steps/negative_eigenvalues": "-",  # fabric, dynamic solver: of the frozen-F_T Hessian
    "steps/xdmf/weft_contact_force": "N",  # fabric: (steps, n_we, M+1) as steps/xdmf/contact_force
    "steps/xdmf/weft_slip": "m",  # fabric: (steps, n_we, M+1) y - Y_k - anchor at crossing nodes
    "steps/warp_planes": "m",  # fabric: (steps, n_wa) plane y = Y_k of each warp
    "steps/weft_planes": "m",  # fabric: (steps, n_we) plane x = X_j of each weft
    "steps/xdmf/plane": "m",  # fabric, moving planes: (steps, n_wa, N+1) each warp node's Y_k
    "steps/xdmf/weft_plane": "m",  # fabric, moving planes: (steps, n_we, M+1) each weft node's X_j
    "steps/xdmf/contact_force": "N",  # (steps, yarns, N+1) R at crossing nodes, 0 elsewhere
                                      # (dynfab.results.xdmf)
    "steps/xdmf/slip": "m",  # (steps, yarns, N+1) x - anchor at crossing nodes, 0 elsewhere
    # Transient runs: one entry per output frame (axis 0 = frames).
    "frames/time": "s",  # (frames,)
    "frames/positions": "m",  # (frames, yarns, N+1, 2)
    "frames/velocities": "m/s",  # (frames, yarns, N+1, 2)
    "frames/force": "N",  # (frames, yarns, N+1, 2) nodal force the next time step uses (resume)
    "frames/contact_force": "N",  # (frames, yarns, crossings)
    "frames/anchors": "m",
    f"frames/energy/{ENERGY_TERM}": "J",  # (frames, yarns)
    "frames/xdmf/contact_force": "N",  # as steps/xdmf/contact_force
    "frames/xdmf/slip": "m",  # as steps/xdmf/slip
    "frames/weft_positions": "m",  # fabric: (frames, n_we, M+1, 2) weft node (y, z)
    "frames/weft_velocities": "m/s",  # fabric: (frames, n_we, M+1, 2)
    "frames/weft_force": "N",  # fabric: (frames, n_we, M+1, 2) as frames/force
    "frames/warp_planes": "m",  # fabric: (frames, n_wa) as steps/warp_planes
    "frames/weft_planes": "m",  # fabric: (frames, n_we) as steps/weft_planes
    "frames/xdmf/weft_contact_force": "N",  # fabric: as steps/xdmf/weft_contact_force
    "frames/xdmf/weft_slip": "m",  # fabric: as steps/xdmf/weft_slip
    "frames/xdmf/plane": "m",  # fabric, moving planes: as steps/xdmf/plane
    "frames/xdmf/weft_plane": "m",  # fabric, moving planes: as steps/xdmf/weft_plane
    "frames/load": LOAD_CONTROL_UNITS,  # specimen: (frames, 1) d of the ramp at the frame
    "frames/end_displacement": "m",  # specimen: (frames, 1) as frames/load
    "frames/clamp_force": "N",  # specimen: (frames,) as steps/clamp_force
    "frames/shear_angle": "rad",  # specimen: (frames, C) from the as-woven state
    "frames/crossing_slip_ratio": "-",  # specimen: (frames, C) as steps/crossing_slip_ratio
    "frames/slip_ratio": "-",  # specimen: (frames,) as steps/slip_ratio
    "frames/dissipated": "J",  # specimen: (frames,) friction's dissipation since t = 0
    "frames/xdmf/shear_angle": "rad",  # specimen: as steps/xdmf/shear_angle
    # Finished rows of steps/ and frames/ (the rest are unwritten: see the layout).
    "steps_done": "-",  # (1,) int64
    "frames_done": "-",  # (1,) int64
    # The XDMF view's datasets (dynfab.results.views; P nodes of all yarns, S segments): virtual
    # datasets into the rows above but view/plane, view/segments, view/yarn.
    "view/points": "m",  # (P, 3) as-woven nodes in 3D
    "view/plane": "m",  # (P,) as-woven plane coordinate of each node
    "view/segments": "-",  # (S, 2) the nodes of each line segment
    "view/yarn": "-",  # (S,) each segment's yarn: index into the attribute yarn_labels
    **{f"view/{group}/{name}/{ENTRY}": units for group in ("steps", "frames")
       for name, units in (("points", "m"), ("contact_force", "N"), ("slip", "m"),
                           ("plane", "m"), ("shear_angle", "rad"))},  # (P, 3) or (P,): row
    # <entry> in 3D, per node
}
"""Units of every dataset a result file may hold; the only list of names."""

MACHINE_TIMES = frozenset({"wall_time", "compile_time"})
"""The steps/ datasets that time the machine, not the model: they differ run to run (and a
first run's compile_time, its kernels compiled, from a later run's), so two runs of one scene
agree bit for bit in every steps/ dataset but these."""

_ENERGY_PREFIXES = ("steps/energy/", "frames/energy/")
_VIEW_ROW = re.compile(r"(view/(?:steps|frames)/[a-z_]+/)[1-9][0-9]*\Z")
_TERM_NAME = re.compile(r"[A-Za-z0-9_]+\Z")
_REQUIRED_ATTRS = ("scene", "solver")


def units_of(name: str, load_control: str | None = None) -> str:
    """Units of the dataset ``name`` (full path, e.g. ``steps/energy/bend``).

    ``load_control`` ("force" or "displacement") fixes the units of
    ``steps/load``. Raises ValueError for a name not in `UNITS`.
    """
    for prefix in _ENERGY_PREFIXES:
        if name.startswith(prefix):
            term = name[len(prefix):]
            if not _TERM_NAME.match(term):
                raise ValueError(f"bad energy term name {term!r} in dataset {name!r}")
            return UNITS[prefix + ENERGY_TERM]
    listed = _VIEW_ROW.sub(rf"\g<1>{ENTRY}", name)  # view/steps/points/3: row 3's
    if listed not in UNITS or ENERGY_TERM in name or ENTRY in name:
        raise ValueError(
            f"dataset {name!r} is not in dynfab.results.file.UNITS: add it there with its units"
        )
    units = UNITS[listed]
    if units == LOAD_CONTROL_UNITS:
        if load_control not in LOAD_UNITS:
            raise ValueError(
                f"dataset {name!r} needs root attribute load_control in "
                f"{sorted(LOAD_UNITS)}, got {load_control!r}"
            )
        return LOAD_UNITS[load_control]
    return units


@functools.cache
def dynfab_version() -> str:
    """The installed dynfab version, or "unknown" when run from a source tree.

    Looked up once per process: the installed metadata does not change under a running
    process, and reading it (`importlib.metadata`) costs more than a small run's step."""
    try:
        return importlib.metadata.version("dynfab")
    except importlib.metadata.PackageNotFoundError:
        return "unknown"


def _check_attr(name: str, value: Any) -> Any:
    """Return an attribute value HDF5 can store: str, bool, int, float or a list of them."""
    scalar = (str, bool, int, float, np.bool_, np.integer, np.floating)
    if isinstance(value, scalar):
        return value
    if isinstance(value, (list, tuple)) and all(isinstance(v, scalar) for v in value):
        if value and all(isinstance(v, str) for v in value):
            return np.array(value, dtype=h5py.string_dtype())
        if value and any(isinstance(v, str) for v in value):
            raise ValueError(f"attribute {name!r} mixes strings and numbers")
        return np.asarray(value)
    raise ValueError(
        f"attribute {name!r} must be a str, float, int, bool or a list of them, "
        f"got {type(value).__name__}"
    )


def _attr_from_h5(value: Any) -> Any:
    """Turn an attribute read by h5py back into plain Python (str, float, list, ...)."""
    if isinstance(value, bytes):
        return value.decode()
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, np.ndarray):
        return [v.decode() if isinstance(v, bytes) else v for v in value.tolist()]
    return value


def _as_entry(name: str, value: Any) -> np.ndarray:
    """One step's (or frame's) value as a private numeric or bool array."""
    array = np.array(value, copy=True)
    if array.dtype.kind not in "biuf":
        raise ValueError(f"dataset {name!r}: values must be numbers or bools, got {array.dtype}")
    return array


@dataclass(frozen=True)
class Results:
    """A result file read into memory (see the module docstring for the layout)."""

    attrs: dict[str, Any]
    """Root attributes (``scene``, ``solver``, ``projected_length``, ...)."""
    reference: dict[str, np.ndarray]
    """``reference/`` datasets by name (``positions``, ``crossing_nodes``)."""
    steps: dict[str, np.ndarray]
    """``steps/`` datasets by name relative to ``steps/`` (``energy/stretch`` style)."""
    frames: dict[str, np.ndarray] = field(default_factory=dict)
    """``frames/`` datasets (transient runs); empty otherwise."""
    units: dict[str, str] = field(default_factory=dict)
    """Units of every dataset by full path (``steps/end_force`` -> ``N``)."""

    @property
    def step_count(self) -> int:
        """Finished load steps in the file."""
        return _entry_count(self.steps, "steps")

    @property
    def frame_count(self) -> int:
        """Transient frames in the file."""
        return _entry_count(self.frames, "frames")


COUNT_DATASETS = {"steps": "steps_done", "frames": "frames_done"}
"""Root datasets holding the number of finished rows of each group (see the layout)."""


def _entry_count(group: Mapping[str, np.ndarray], what: str) -> int:
    """Common first dimension of a group's stacked datasets (0 when empty)."""
    counts = {len(array) for array in group.values()}
    if len(counts) > 1:
        raise ValueError(f"{what} datasets have different lengths {sorted(counts)}")
    return counts.pop() if counts else 0


def _finished_rows(h5: h5py.File, group: str) -> int | None:
    """The group's finished row count from its count dataset (None in files without one)."""
    name = COUNT_DATASETS.get(group)
    if name is None or name not in h5:
        return None
    return int(h5[name][0])


def _group_datasets(h5: h5py.File, group: str) -> dict[str, h5py.Dataset]:
    """The datasets under ``group`` by name relative to it (``energy/stretch`` style)."""
    found: dict[str, h5py.Dataset] = {}
    if group in h5:
        h5[group].visititems(
            lambda name, obj: found.__setitem__(name, obj) if isinstance(obj, h5py.Dataset) else None)
    return found


def _read_group(h5: h5py.File, group: str, only: set[str] | None = None
                ) -> tuple[dict[str, np.ndarray], dict[str, str]]:
    """The finished rows of the datasets under ``group`` and their units.

    A group whose count dataset says 0 reads as empty, like a group never written.
    """
    count = _finished_rows(h5, group)
    data: dict[str, np.ndarray] = {}
    units: dict[str, str] = {}
    if count == 0:
        return data, units
    for name, dataset in _group_datasets(h5, group).items():
        if only is not None and f"{group}/{name}" not in only:
            continue
        if count is not None and (dataset.ndim == 0 or dataset.shape[0] < count):
            raise ValueError(f"{group}/{name} has fewer rows than {COUNT_DATASETS[group]} = {count}")
        data[name] = dataset[()] if count is None else dataset[:count]
        units[f"{group}/{name}"] = _attr_from_h5(dataset.attrs.get("units", ""))
    return data, units


def _load(path: Path, only: Iterable[str] | None = None) -> Results:
    """Read a result file; UserError (one line) if missing or not a dynfab file."""
    if not path.exists():
        raise UserError(f"result file '{path}' does not exist")
    if not path.is_file():
        raise UserError(f"result file '{path}' is not a file")
    wanted = None if only is None else set(only)
    try:
        with h5py.File(path, "r") as h5:
            attrs = {key: _attr_from_h5(value) for key, value in h5.attrs.items()}
            if "dynfab_version" not in attrs or attrs.get("units") != "SI":
                raise UserError(f"'{path}' is not a dynfab result file")
            reference, ref_units = _read_group(h5, "reference", wanted)
            steps, step_units = _read_group(h5, "steps", wanted)
            frames, frame_units = _read_group(h5, "frames", wanted)
    except ValueError as error:
        raise UserError(f"result file '{path}' is damaged: {error}") from None
    except (OSError, KeyError, RuntimeError) as error:
        reason = str(error).splitlines()[0] if str(error) else type(error).__name__
        raise UserError(f"cannot read result file '{path}': {reason}") from None
    results = Results(attrs, reference, steps, frames, {**ref_units, **step_units, **frame_units})
    try:
        results.step_count, results.frame_count
    except ValueError as error:
        raise UserError(f"result file '{path}' is damaged: {error}") from None
    return results


def read_results(path: str | os.PathLike, only: Iterable[str] | None = None) -> Results:
    """Read a result file into memory: every finished step and frame.

    ``only`` (full dataset paths, e.g. ``steps/load``) reads just those
    datasets, for a summary of a large file. Raises UserError with a
    one-line message for a missing file or a file that is not a dynfab result.
    """
    return _load(Path(path), only)


def finished_counts(path: str | os.PathLike) -> tuple[int, int] | None:
    """(finished load steps, finished frames) of a result file; None if it is not readable."""
    try:
        with h5py.File(path, "r") as h5:
            counts = []
            for group in ("steps", "frames"):
                count = _finished_rows(h5, group)
                if count is None:
                    lengths = {d.shape[0] for d in _group_datasets(h5, group).values() if d.ndim}
                    count = min(lengths) if lengths else 0
                counts.append(count)
            return counts[0], counts[1]
    except (OSError, KeyError, RuntimeError, ValueError):
        return None


def _tmp_path(target: Path, pid: int | None = None) -> Path:
    """The temporary file a process writes before renaming it onto ``target``."""
    return target.with_name(f"{target.name}.tmp-{os.getpid() if pid is None else pid}")


def _remove_stale_tmp(target: Path) -> None:
    """Delete temporary files left next to ``target`` by killed writers (dead pids)."""
    for tmp in target.parent.glob(f"{glob.escape(target.name)}.tmp-*"):
        pid_text = tmp.name.rsplit("-", 1)[1]
        if not pid_text.isdigit() or int(pid_text) == os.getpid():
            continue
        try:
            os.kill(int(pid_text), 0)
        except ProcessLookupError:
            with contextlib.suppress(OSError):
                tmp.unlink()
        except PermissionError:
            pass  # alive, owned by someone else


def _fsync_directory(directory: Path) -> None:
    """Make a rename in ``directory`` durable (no-op where directories cannot be opened)."""
    try:
        fd = os.open(directory, os.O_RDONLY | getattr(os, "O_DIRECTORY", 0))
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)


_BLOCK_BYTES = 64 * 2**20
"""Rows are copied between files in blocks of about this size, never a whole dataset."""

_FLOCK = struct.Struct("hhqqi4x")
"""Linux ``struct flock`` (l_type, l_whence, l_start, l_len, l_pid), for F_OFD_SETLK."""


def _try_lock(fd: int) -> bool:
    """Take the exclusive writer lock on ``fd``'s open file description; False if held elsewhere.

    An OFD lock (Linux) lives with the open file description, like ``flock``,
    but in the fcntl lock space, so it neither blocks nor is blocked by the
    ``flock`` HDF5 takes when any process opens the file. Elsewhere, a POSIX
    ``lockf`` (per process) stands in.
    """
    import fcntl  # POSIX only; imported here so that reading files needs none of this

    try:
        if hasattr(fcntl, "F_OFD_SETLK"):
            fcntl.fcntl(fd, fcntl.F_OFD_SETLK, _FLOCK.pack(fcntl.F_WRLCK, 0, 0, 0, 0))
        else:
            fcntl.lockf(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except OSError as error:
        if error.errno in (errno.EAGAIN, errno.EACCES):
            return False
        raise
    return True


def _busy(path: Path) -> UserError:
    return UserError(f"output file '{path}' is being written by another dynfab process: "
                      "wait for it to finish or write another file")


def _lock_existing(path: Path) -> int:
    """Open ``path`` read-write and take the writer lock; the locked fd.

    UserError if another writer holds it. The lock is taken on what was
    opened, then checked to still be the file at ``path`` (a writer may have
    replaced it meanwhile: then try again).
    """
    while True:
        try:
            fd = os.open(path, os.O_RDWR)
        except FileNotFoundError:
            raise UserError(f"result file '{path}' does not exist") from None
        except OSError as error:
            raise UserError(f"cannot open '{path}' for writing: {error.strerror}") from None
        try:
            if not _try_lock(fd):
                raise _busy(path)
            opened, now = os.fstat(fd), os.stat(path)
        except BaseException:
            os.close(fd)
            raise
        if (opened.st_dev, opened.st_ino) == (now.st_dev, now.st_ino):
            return fd
        os.close(fd)


def _is_locked(path: Path) -> bool:
    """True if a dynfab writer holds ``path`` (False if it cannot be opened)."""
    try:
        fd = os.open(path, os.O_RDWR)
    except OSError:
        return False
    try:
        return not _try_lock(fd)
    finally:
        os.close(fd)  # releases the lock just taken, if any


def _write_all(fd: int, data: bytes, offset: int) -> None:
    """``os.pwrite`` until every byte is written."""
    view = memoryview(data)
    while view:
        written = os.pwrite(fd, view, offset)
        view, offset = view[written:], offset + written


def _fill_value(dtype: np.dtype):
    """The value of rows not yet written: NaN, -1 (or the largest unsigned), False."""
    if dtype.kind == "f":
        return np.nan
    if dtype.kind == "i":
        return -1
    if dtype.kind == "u":
        return np.iinfo(dtype).max
    return False


def _create_rows(h5: h5py.File, name: str, dtype: np.dtype, shape: tuple, units: str
                 ) -> h5py.Dataset:
    """A contiguous dataset allocated and filled at creation, so later raw writes need no
    HDF5 metadata change."""
    dcpl = h5py.h5p.create(h5py.h5p.DATASET_CREATE)
    dcpl.set_alloc_time(h5py.h5d.ALLOC_TIME_EARLY)
    dcpl.set_fill_time(h5py.h5d.FILL_TIME_ALLOC)
    dataset = h5.create_dataset(name, shape=shape, dtype=dtype, fillvalue=_fill_value(dtype),
                                dcpl=dcpl)
    dataset.attrs["units"] = units
    return dataset


def _raw_offset(dataset: h5py.Dataset) -> int | None:
    """The file offset of a dataset writable in place as raw bytes, else None.

    Needs contiguous, unfiltered, allocated storage in native byte order.
    """
    dtype = dataset.dtype
    if (dataset.chunks is not None or dataset.compression is not None
            or dtype.kind not in "biuf" or not dtype.isnative):
        return None
    if dataset.size == 0:
        return 0
    offset = dataset.id.get_offset()
    if offset is None or dataset.id.get_storage_size() != dataset.size * dtype.itemsize:
        return None
    return int(offset)


@dataclass
class _Column:
    """One per-entry dataset: row dtype and shape, and where its rows sit in the file."""

    dtype: np.dtype
    row_shape: tuple
    offset: int | None = None
    """File offset of row 0 (None: not writable in place; the next append rewrites)."""

    @property
    def row_bytes(self) -> int:
        return int(np.prod(self.row_shape, dtype=np.int64)) * self.dtype.itemsize


class _Series:
    """The entries (load steps or frames) of one group: their columns, count and capacity."""

    def __init__(self, group: str, capacity_hint: int | None = None) -> None:
        self.group = group
        self.columns: dict[str, _Column] = {}
        self.count = 0
        self.capacity = 0
        self.capacity_hint = capacity_hint
        self.count_offset: int | None = None
        self.last: dict[str, np.ndarray] = {}

    @classmethod
    def from_file(cls, h5: h5py.File, group: str, capacity_hint: int | None) -> "_Series":
        """The series as stored (any dynfab layout, older ones included)."""
        series = cls(group, capacity_hint)
        datasets = _group_datasets(h5, group)
        count = _finished_rows(h5, group)
        lengths = {d.shape[0] for d in datasets.values() if d.ndim}
        if any(d.ndim == 0 for d in datasets.values()) or (count is None and len(lengths) > 1):
            raise ValueError(f"{group} datasets have different lengths {sorted(lengths)}")
        series.capacity = min(lengths) if lengths else 0
        series.count = series.capacity if count is None else count
        if series.count > series.capacity:
            raise ValueError(f"{COUNT_DATASETS[group]} = {count} exceeds the {series.capacity} rows")
        for name, dataset in datasets.items():
            series.columns[name] = _Column(dataset.dtype, dataset.shape[1:], _raw_offset(dataset))
            if series.count:
                series.last[name] = dataset[series.count - 1]
        if count is not None:
            series.count_offset = _raw_offset(h5[COUNT_DATASETS[group]])
        if not datasets:
            series.count = series.capacity = 0
        return series

    @property
    def writable_in_place(self) -> bool:
        """True if the next entry can go in as raw bytes (room left, offsets known)."""
        return (bool(self.columns) and self.count < self.capacity and self.count_offset is not None
                and all(c.offset is not None for c in self.columns.values()))

    def next_capacity(self) -> int:
        """Rows to allocate at the next rewrite: the expected count if still ahead, else
        double the count (so the copies cost O(1) per entry, amortised)."""
        if self.capacity_hint is not None and self.capacity_hint > self.count:
            return self.capacity_hint
        return max(8, 2 * self.count)

    def check(self, entry: Mapping[str, Any], load_control: str | None) -> dict[str, np.ndarray]:
        """Validate one entry against the units table and the first entry's names and shapes."""
        if not entry:
            raise ValueError(f"empty {self.group} entry")
        arrays = {}
        for name, value in entry.items():
            units_of(f"{self.group}/{name}", load_control)
            arrays[name] = _as_entry(f"{self.group}/{name}", value)
        if not self.columns:
            return arrays
        missing = sorted(set(self.columns) - set(arrays))
        extra = sorted(set(arrays) - set(self.columns))
        if missing or extra:
            raise ValueError(f"{self.group} entry keys differ from the first entry's: "
                             f"missing {missing}, unexpected {extra}")
        for name, array in arrays.items():
            column = self.columns[name]
            if array.shape != column.row_shape:
                raise ValueError(f"{self.group}/{name}: shape {array.shape} differs from the "
                                 f"first entry's {column.row_shape}")
            if not np.can_cast(array.dtype, column.dtype, casting="same_kind"):
                raise ValueError(f"{self.group}/{name}: {array.dtype} values cannot be stored "
                                 f"as the first entry's {column.dtype}")
            arrays[name] = array.astype(column.dtype, copy=False)
        return arrays


class ResultFile:
    """A result file being written: after every append the file holds every finished entry.

    Use as a context manager (or call `close`): closing trims the datasets to
    the finished entries and releases the writer lock.
    """

    def __init__(self, path: Path, attrs: dict[str, Any], steps: _Series, frames: _Series,
                 views: Callable[[h5py.File], None] | None = None) -> None:
        """Use `create` or `resume`."""
        self.path = path
        self._views = views
        self._attrs = attrs
        self._reference: dict[str, np.ndarray] | None = None
        self._series = {"steps": steps, "frames": frames}
        self._fd: int | None = None
        """The file, open read-write and holding the writer lock (None once closed)."""
        self._attrs_changed = False

    @classmethod
    def create(cls, path: str | os.PathLike, *, attrs: dict[str, Any],
               reference: dict[str, np.ndarray], overwrite: bool = False,
               step_capacity: int | None = None, frame_capacity: int | None = None,
               views: Callable[[h5py.File], None] | None = None) -> "ResultFile":
        """Start a new result file and write it at once (no steps yet).

        ``attrs`` are root attributes and must include ``scene`` and
        ``solver``; ``dynfab_version`` defaults to the installed version and
        ``units`` is always "SI". ``reference`` holds datasets stored under
        ``reference/``. An existing ``path`` is refused with UserError, and
        left untouched, unless ``overwrite``; so is a file another process
        creates at the same moment, or one another dynfab process writes.
        ``step_capacity`` and ``frame_capacity``, the expected numbers of
        entries, size the datasets at the first entry (more still fit).
        ``views`` (`dynfab.results.views.add_views`) adds ``view/`` whenever the
        structure is written, after every other dataset.
        """
        target = Path(path)
        if target.is_dir():
            raise UserError(f"output file '{path}' is a directory")
        if target.exists() and not overwrite:
            raise _exists(target)
        if not target.parent.is_dir():
            raise UserError(f"output directory '{target.parent}' does not exist")
        missing = [key for key in _REQUIRED_ATTRS if key not in attrs]
        if missing:
            raise ValueError(f"result file attributes lack {missing}")
        if attrs.get("units", "SI") != "SI":
            raise ValueError(f"attribute units must be 'SI', got {attrs['units']!r}")
        all_attrs = {"dynfab_version": dynfab_version(), **attrs, "units": "SI"}
        all_attrs = {key: _check_attr(key, value) for key, value in all_attrs.items()}
        ref = {}
        for name, value in reference.items():
            units_of(f"reference/{name}")
            ref[name] = np.array(value, copy=True)
        result = cls(target, all_attrs, _Series("steps", step_capacity),
                     _Series("frames", frame_capacity), views)
        result._reference = ref
        _remove_stale_tmp(target)
        try:
            result._rewrite(publish="overwrite" if overwrite else "new")
        except OSError as error:
            raise UserError(f"cannot write output file '{path}': {error.strerror or error}") from None
        return result

    @classmethod
    def resume(cls, path: str | os.PathLike, *, step_capacity: int | None = None,
               frame_capacity: int | None = None,
               views: Callable[[h5py.File], None] | None = None) -> "ResultFile":
        """Re-open an existing result file to append to it (only the last entries are read).

        ``views`` as in `create`: the next write of the structure adds them
        (`flush` writes it now).

        UserError if the file is missing, unreadable, not a dynfab result,
        or being written by another dynfab process.
        """
        target = Path(path)
        _load(target, only=())  # one-line errors for a missing or foreign file
        fd = _lock_existing(target)
        try:
            with h5py.File(target, "r") as h5:
                attrs = {key: _attr_from_h5(value) for key, value in h5.attrs.items()}
                series = {group: _Series.from_file(h5, group, hint) for group, hint in
                          (("steps", step_capacity), ("frames", frame_capacity))}
                names = [f"{group}/{name}" for group in series for name in series[group].columns]
                names += [f"reference/{name}" for name in _group_datasets(h5, "reference")]
        except (OSError, ValueError, KeyError) as error:
            os.close(fd)
            raise UserError(f"cannot resume '{path}': {str(error).splitlines()[0]}") from None
        for name in names:
            try:
                units_of(name, attrs.get("load_control"))
            except ValueError as error:
                os.close(fd)
                raise UserError(f"cannot resume '{path}': {error}") from None
        attrs = {key: _check_attr(key, value) for key, value in attrs.items()}
        _remove_stale_tmp(target)
        result = cls(target, attrs, series["steps"], series["frames"], views)
        result._fd = fd
        return result

    def append_step(self, step: Mapping[str, Any]) -> None:
        """Append one finished load step; on return it is on disk.

        Keys are dataset names under ``steps/`` ("load", "positions",
        "energy/stretch", ...); values are arrays or numbers. The first step
        fixes the key set and shapes; a later mismatch, or a name not in
        `UNITS`, raises ValueError and nothing is appended.
        """
        self._append(self._series["steps"], step)

    def append_frame(self, frame: Mapping[str, Any]) -> None:
        """Append one transient frame (datasets under ``frames/``); on return it is on disk."""
        self._append(self._series["frames"], frame)

    def _append(self, series: _Series, entry: Mapping[str, Any]) -> None:
        """Validate, make room (a rewrite, rarely), write the rows, then the count."""
        self._require_open()
        arrays = series.check(entry, self._load_control())
        if not series.columns:
            series.columns = {name: _Column(a.dtype, a.shape) for name, a in arrays.items()}
        if not series.writable_in_place:
            series.capacity = series.next_capacity()
            self._rewrite(publish="replace")
        for name, array in arrays.items():
            column = series.columns[name]
            if column.row_bytes:
                _write_all(self._fd, np.ascontiguousarray(array).tobytes(),
                           column.offset + series.count * column.row_bytes)
        # The rows reach the disk before the count that declares them finished; the count
        # itself reaches it with the next append's sync (or close): a power failure may
        # lose the last step, never count an unwritten one. A kill loses nothing: the
        # count is in the page cache, which outlives the process.
        os.fdatasync(self._fd)
        _write_all(self._fd, np.int64(series.count + 1).tobytes(), series.count_offset)
        series.count += 1
        series.last = arrays

    def set_attrs(self, **attrs: Any) -> None:
        """Set root attributes; they are written with `flush` (or `close`)."""
        if "units" in attrs and attrs["units"] != "SI":
            raise ValueError(f"attribute units must be 'SI', got {attrs['units']!r}")
        if ("load_control" in attrs and "load" in self._series["steps"].columns
                and attrs["load_control"] != self._attrs.get("load_control")):
            raise ValueError("load_control cannot change once load steps are written")
        self._attrs.update({key: _check_attr(key, value) for key, value in attrs.items()})
        self._attrs_changed = True

    def flush(self) -> None:
        """Rewrite the file atomically, attributes included (every append is already on disk)."""
        self._require_open()
        self._rewrite(publish="replace")

    def close(self, trim: bool = True) -> None:
        """Trim the datasets to the finished entries (one atomic rewrite, if any row is spare
        or an attribute changed) and release the writer lock. Idempotent."""
        if self._fd is None:
            return
        try:
            spare = any(s.columns and s.capacity > s.count for s in self._series.values())
            if trim and (spare or self._attrs_changed):
                for series in self._series.values():
                    series.capacity = series.count
                self._rewrite(publish="replace")
            else:
                os.fdatasync(self._fd)  # the last count
        finally:
            os.close(self._fd)
            self._fd = None

    def __del__(self) -> None:
        """An abandoned writer releases its lock; its file stays valid, untrimmed."""
        fd, self._fd = getattr(self, "_fd", None), None
        if fd is not None:
            with contextlib.suppress(OSError):
                os.close(fd)

    def __enter__(self) -> "ResultFile":
        return self

    def __exit__(self, kind, value, traceback) -> None:
        self.close(trim=kind is None or issubclass(kind, Exception))

    def _require_open(self) -> None:
        if self._fd is None:
            raise ValueError(f"result file '{self.path}' is closed")

    def _load_control(self) -> str | None:
        value = self._attrs.get("load_control")
        return value.decode() if isinstance(value, bytes) else value

    def _rewrite(self, publish: str) -> None:
        """Write the whole file at the series' capacities to a temporary file and publish it.

        ``publish``: "new" (exclusive: fails if ``path`` exists), "overwrite"
        (exclusive, else replace a file no other writer holds) or "replace"
        (the file this object holds locked). Rows already written are copied
        from the current file in blocks; the new file is locked before it
        becomes visible, so the lock never lapses.
        """
        tmp = _tmp_path(self.path)
        fd = None
        try:
            with h5py.File(tmp, "w") as h5:
                self._fill(h5)
            fd = os.open(tmp, os.O_RDWR)
            _try_lock(fd)
            with h5py.File(tmp, "r") as h5:
                for group, series in self._series.items():
                    self._locate(h5, group, series)
            os.fsync(fd)
            self._publish(tmp, publish)
        except BaseException:
            if fd is not None:
                os.close(fd)
            with contextlib.suppress(OSError):
                tmp.unlink()
            raise
        _fsync_directory(self.path.parent)
        old, self._fd = self._fd, fd
        if old is not None:
            os.close(old)
        self._attrs_changed = False

    def _publish(self, tmp: Path, publish: str) -> None:
        """Put the finished temporary file at ``path`` (see `_rewrite`)."""
        if publish == "replace":
            os.replace(tmp, self.path)
            return
        try:
            _create_exclusively(tmp, self.path)
        except FileExistsError:
            if publish == "new":  # another process created it since the checks
                raise _busy(self.path) if _is_locked(self.path) else _exists(self.path) from None
            self._fd = _lock_existing(self.path)  # released once the new file is in place
            os.replace(tmp, self.path)

    def _fill(self, h5: h5py.File) -> None:
        """Attributes, reference, every series at its capacity with its finished rows, then
        the views (if any) of them all."""
        for key, value in self._attrs.items():
            h5.attrs[key] = value
        source = h5py.File(self.path, "r") if self._fd is not None else None
        try:
            h5.require_group("reference")
            reference = self._reference
            if reference is None:
                reference = {name: d[()] for name, d in _group_datasets(source, "reference").items()}
                self._reference = reference
            for name, value in reference.items():
                dataset = h5.create_dataset(f"reference/{name}", data=value)
                dataset.attrs["units"] = units_of(f"reference/{name}")
            for group, series in self._series.items():
                h5.require_group(group)
                count = _create_rows(h5, COUNT_DATASETS[group], np.dtype(np.int64), (1,),
                                     units_of(COUNT_DATASETS[group]))
                count[0] = series.count
                for name, column in series.columns.items():
                    full = f"{group}/{name}"
                    dataset = _create_rows(h5, full, column.dtype,
                                           (series.capacity, *column.row_shape),
                                           units_of(full, self._load_control()))
                    if series.count:
                        _copy_rows(source[full], dataset, series.count)
            if self._views is not None:
                self._views(h5)
        finally:
            if source is not None:
                source.close()

    @staticmethod
    def _locate(h5: h5py.File, group: str, series: _Series) -> None:
        """Record where the new file keeps each column's rows and the count."""
        series.count_offset = _raw_offset(h5[COUNT_DATASETS[group]])
        for name, column in series.columns.items():
            column.offset = _raw_offset(h5[f"{group}/{name}"])

    @property
    def step_count(self) -> int:
        """Load steps appended so far (including those found on `resume`)."""
        return self._series["steps"].count

    @property
    def frame_count(self) -> int:
        """Frames appended so far (including those found on `resume`)."""
        return self._series["frames"].count

    def last_step(self) -> dict[str, np.ndarray]:
        """The last appended step's arrays, by name (empty dict if none)."""
        return {name: value.copy() for name, value in self._series["steps"].last.items()}

    def step_column(self, name: str) -> np.ndarray:
        """Every finished step's `steps/<name>`, read back from the file (rows, ...)."""
        with h5py.File(self.path, "r") as h5:
            return h5[f"steps/{name}"][:self.step_count]

    def last_frame(self) -> dict[str, np.ndarray]:
        """The last appended frame's arrays, by name (empty dict if none)."""
        return {name: value.copy() for name, value in self._series["frames"].last.items()}

    @property
    def attrs(self) -> dict[str, Any]:
        """A copy of the root attributes as they will be written."""
        return {key: _attr_from_h5(value) for key, value in self._attrs.items()}


def _create_exclusively(tmp: Path, target: Path) -> None:
    """Put ``tmp`` at ``target`` unless ``target`` exists (FileExistsError), atomically.

    ``os.link`` does it in one step; on a file system without hard links, an
    empty ``target`` is claimed with O_EXCL, then replaced.
    """
    try:
        os.link(tmp, target)
    except FileExistsError:
        raise
    except OSError:
        os.close(os.open(target, os.O_WRONLY | os.O_CREAT | os.O_EXCL))
        os.replace(tmp, target)
        return
    tmp.unlink()


def _exists(path: Path) -> UserError:
    """The refusal to replace an existing file (or one another process just created)."""
    return UserError(f"output file '{path}' exists: pass --overwrite to replace it "
                      f"or --resume to continue it")


def _copy_rows(source: h5py.Dataset, target: h5py.Dataset, count: int) -> None:
    """Copy rows [0, count) in blocks of about `_BLOCK_BYTES`."""
    row_bytes = max(1, int(np.prod(source.shape[1:], dtype=np.int64)) * source.dtype.itemsize)
    block = max(1, _BLOCK_BYTES // row_bytes)
    for start in range(0, count, block):
        stop = min(count, start + block)
        target[start:stop] = source[start:stop]
