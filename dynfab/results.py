"""Crash-safe HDF5 result files: every finished load step is on disk at once.

A plain HDF5 file being written can be left corrupt by a kill. A
`ResultFile` therefore keeps the whole result in memory and, at each append,
writes the complete file anew to ``<name>.tmp-<pid>`` in the same directory,
flushes and fsyncs it, renames it onto the target with `os.replace` (atomic
on POSIX) and fsyncs the directory. Whatever the moment of a kill, even
``kill -9``, the target is either the previous complete file or the new one.

The layout is a contract (scripts read it; never rename):

* root attributes: ``scene`` (TOML text), ``solver``, ``dynfab_version``,
  ``units = "SI"``, plus the caller's (``load_control``, ``projected_length``,
  ``width_per_yarn``, ``reference_state``, ``title``, ``yarn_labels``, ...);
* ``reference/<name>``: the as-woven state;
* ``steps/<name>``: one entry per finished load step, stacked on axis 0;
* ``frames/<name>``: one entry per output frame of a transient run.

Every dataset carries a ``units`` attribute taken from `UNITS`, the one table
of dataset names; a name not in it is refused at append, so a new dataset
must be documented here before it can be written.
"""

from __future__ import annotations

import contextlib
import glob
import importlib.metadata
import os
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Mapping

import h5py
import numpy as np

from dynfab.errors import SceneError

ENERGY_TERM = "<term>"
"""Placeholder in `UNITS` for any energy term name (``energy/stretch``, ...)."""

LOAD_CONTROL_UNITS = "<load_control>"
"""Placeholder in `UNITS`: the units follow the root attribute ``load_control``."""

LOAD_UNITS = {"force": "N", "displacement": "m"}
"""Units of ``steps/load`` for each value of the root attribute ``load_control``."""

UNITS: dict[str, str] = {
    # As-woven reference state.
    "reference/positions": "m",  # (yarns, N+1, 2) node (x, z)
    "reference/crossing_nodes": "-",  # (crossings,) node index of each crossing
    # One entry per finished load step (axis 0 = steps).
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
    "steps/time_steps": "-",  # dynamic solver: time steps taken
    "steps/force_evaluations": "-",  # dynamic solver
    "steps/dt": "s",  # dynamic solver time step
    "steps/stable": "-",  # (steps, yarns) bool: no negative pivot of the frozen-F_T Hessian
    "steps/buckled": "-",  # (steps, yarns) bool: the step left a saddle (an escape was taken)
    "steps/lowest_eigenvalue": "N/m",  # (steps, yarns) estimate of lambda_min of that Hessian
    "steps/error_estimate": "m",  # (steps, yarns) residual x est ||H^-1||_inf, position error bound
    "steps/tolerance": "N",  # dynamic solver: the residual each load step had to reach
    # Transient runs: one entry per output frame (axis 0 = frames).
    "frames/time": "s",  # (frames,)
    "frames/positions": "m",  # (frames, yarns, N+1, 2)
    "frames/velocities": "m/s",  # (frames, yarns, N+1, 2)
    "frames/force": "N",  # (frames, yarns, N+1, 2) nodal force the next time step uses (resume)
    "frames/contact_force": "N",  # (frames, yarns, crossings)
    "frames/anchors": "m",
    f"frames/energy/{ENERGY_TERM}": "J",  # (frames, yarns)
}
"""Units of every dataset a result file may hold; the only list of names."""

_ENERGY_PREFIXES = ("steps/energy/", "frames/energy/")
_TERM_NAME = re.compile(r"[A-Za-z0-9_]+\Z")
_REQUIRED_ATTRS = ("scene", "solver")
_GROUPS = ("reference", "steps", "frames")


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
    if name not in UNITS or ENERGY_TERM in name:
        raise ValueError(
            f"dataset {name!r} is not in dynfab.results.UNITS: add it there with its units"
        )
    units = UNITS[name]
    if units == LOAD_CONTROL_UNITS:
        if load_control not in LOAD_UNITS:
            raise ValueError(
                f"dataset {name!r} needs root attribute load_control in "
                f"{sorted(LOAD_UNITS)}, got {load_control!r}"
            )
        return LOAD_UNITS[load_control]
    return units


def dynfab_version() -> str:
    """The installed dynfab version, or "unknown" when run from a source tree."""
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


def _entry_count(group: Mapping[str, np.ndarray], what: str) -> int:
    """Common first dimension of a group's stacked datasets (0 when empty)."""
    counts = {len(array) for array in group.values()}
    if len(counts) > 1:
        raise ValueError(f"{what} datasets have different lengths {sorted(counts)}")
    return counts.pop() if counts else 0


def _read_group(h5: h5py.File, group: str) -> tuple[dict[str, np.ndarray], dict[str, str]]:
    """All datasets under ``group`` (names relative to it) and their units."""
    data: dict[str, np.ndarray] = {}
    units: dict[str, str] = {}
    if group not in h5:
        return data, units

    def visit(name: str, obj: Any) -> None:
        if isinstance(obj, h5py.Dataset):
            data[name] = obj[()]
            units[f"{group}/{name}"] = _attr_from_h5(obj.attrs.get("units", ""))

    h5[group].visititems(visit)
    return data, units


def _load(path: Path) -> Results:
    """Read a whole result file; SceneError (one line) if missing or not a dynfab file."""
    if not path.exists():
        raise SceneError(f"result file '{path}' does not exist")
    if not path.is_file():
        raise SceneError(f"result file '{path}' is not a file")
    try:
        with h5py.File(path, "r") as h5:
            attrs = {key: _attr_from_h5(value) for key, value in h5.attrs.items()}
            if "dynfab_version" not in attrs or attrs.get("units") != "SI":
                raise SceneError(f"'{path}' is not a dynfab result file")
            reference, ref_units = _read_group(h5, "reference")
            steps, step_units = _read_group(h5, "steps")
            frames, frame_units = _read_group(h5, "frames")
    except (OSError, KeyError, RuntimeError) as error:
        reason = str(error).splitlines()[0] if str(error) else type(error).__name__
        raise SceneError(f"cannot read result file '{path}': {reason}") from None
    results = Results(attrs, reference, steps, frames, {**ref_units, **step_units, **frame_units})
    try:
        results.step_count, results.frame_count
    except ValueError as error:
        raise SceneError(f"result file '{path}' is damaged: {error}") from None
    return results


def read_results(path: str | os.PathLike) -> Results:
    """Read a result file into memory.

    Raises SceneError with a one-line message for a missing file or a file
    that is not a dynfab result.
    """
    return _load(Path(path))


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


def _write_dataset(h5: h5py.File, name: str, data: np.ndarray, units: str) -> None:
    """Write one dataset with its ``units`` attribute."""
    dataset = h5.create_dataset(name, data=data)
    dataset.attrs["units"] = units


def write_atomically(target: Path, fill: Callable[[h5py.File], None]) -> None:
    """Write an HDF5 file with ``fill(h5)`` and put it at ``target`` atomically.

    The file is written to ``<target>.tmp-<pid>``, flushed, fsynced and renamed
    onto ``target``; the directory is then fsynced. A kill at any moment leaves
    ``target`` either as it was or complete with the new content.
    """
    tmp = _tmp_path(target)
    try:
        with h5py.File(tmp, "w") as h5:
            fill(h5)
        fd = os.open(tmp, os.O_RDONLY)
        try:
            os.fsync(fd)
        finally:
            os.close(fd)
        os.replace(tmp, target)
    except BaseException:
        with contextlib.suppress(OSError):
            tmp.unlink()
        raise
    _fsync_directory(target.parent)


class _Series:
    """Entries (load steps or frames) of one group, kept in memory."""

    def __init__(self, group: str, data: dict[str, np.ndarray] | None = None) -> None:
        """Start empty, or from stacked arrays read back from a file."""
        self.group = group
        self.entries: dict[str, list[np.ndarray]] = {
            name: list(stacked) for name, stacked in (data or {}).items()
        }

    @property
    def count(self) -> int:
        """Entries appended so far."""
        return len(next(iter(self.entries.values()))) if self.entries else 0

    def check(self, entry: Mapping[str, Any], load_control: str | None) -> dict[str, np.ndarray]:
        """Validate one entry against the units table and the earlier entries."""
        if not entry:
            raise ValueError(f"empty {self.group} entry")
        arrays = {}
        for name, value in entry.items():
            units_of(f"{self.group}/{name}", load_control)
            arrays[name] = _as_entry(f"{self.group}/{name}", value)
        if self.entries:
            missing = sorted(set(self.entries) - set(arrays))
            extra = sorted(set(arrays) - set(self.entries))
            if missing or extra:
                raise ValueError(
                    f"{self.group} entry keys differ from the first entry's: "
                    f"missing {missing}, unexpected {extra}"
                )
            for name, array in arrays.items():
                first = self.entries[name][0]
                if array.shape != first.shape:
                    raise ValueError(
                        f"{self.group}/{name}: shape {array.shape} differs from the "
                        f"first entry's {first.shape}"
                    )
        return arrays

    def add(self, arrays: dict[str, np.ndarray]) -> None:
        """Append one validated entry."""
        for name, array in arrays.items():
            self.entries.setdefault(name, []).append(array)

    def stacked(self) -> dict[str, np.ndarray]:
        """Each dataset with the entries stacked along a new first axis."""
        return {name: np.stack(values) for name, values in self.entries.items()}

    def last(self) -> dict[str, np.ndarray]:
        """Copies of the last entry's arrays (empty dict if none)."""
        return {name: values[-1].copy() for name, values in self.entries.items()}


class ResultFile:
    """A result file being written: every append leaves a complete, readable file."""

    def __init__(
        self,
        path: Path,
        attrs: dict[str, Any],
        reference: dict[str, np.ndarray],
        steps: _Series,
        frames: _Series,
    ) -> None:
        """Use `create` or `resume`."""
        self.path = path
        self._attrs = attrs
        self._reference = reference
        self._steps = steps
        self._frames = frames

    @classmethod
    def create(
        cls,
        path: str | os.PathLike,
        *,
        attrs: dict[str, Any],
        reference: dict[str, np.ndarray],
        overwrite: bool = False,
    ) -> "ResultFile":
        """Start a new result file and write it at once (no steps yet).

        ``attrs`` are root attributes and must include ``scene`` and
        ``solver``; ``dynfab_version`` defaults to the installed version and
        ``units`` is always "SI". ``reference`` holds datasets stored under
        ``reference/``. An existing ``path`` is refused with SceneError, and
        left untouched, unless ``overwrite``.
        """
        target = Path(path)
        if target.exists() and not overwrite:
            raise SceneError(
                f"output file '{path}' exists: pass --overwrite to replace it "
                f"or --resume to continue it"
            )
        if target.is_dir():
            raise SceneError(f"output file '{path}' is a directory")
        if not target.parent.is_dir():
            raise SceneError(f"output directory '{target.parent}' does not exist")
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
        result = cls(target, all_attrs, ref, _Series("steps"), _Series("frames"))
        _remove_stale_tmp(target)
        try:
            result.flush()
        except OSError as error:
            raise SceneError(f"cannot write output file '{path}': {error.strerror or error}") from None
        return result

    @classmethod
    def resume(cls, path: str | os.PathLike) -> "ResultFile":
        """Re-open an existing result file to append to it; everything is loaded into memory.

        SceneError if the file is missing, unreadable or not a dynfab result.
        """
        target = Path(path)
        results = _load(target)
        for name in results.units:
            try:
                units_of(name, results.attrs.get("load_control"))
            except ValueError as error:
                raise SceneError(f"cannot resume '{path}': {error}") from None
        attrs = {key: _check_attr(key, value) for key, value in results.attrs.items()}
        _remove_stale_tmp(target)
        return cls(
            target,
            attrs,
            dict(results.reference),
            _Series("steps", results.steps),
            _Series("frames", results.frames),
        )

    def append_step(self, step: Mapping[str, Any]) -> None:
        """Append one finished load step and rewrite the file atomically.

        Keys are dataset names under ``steps/`` ("load", "positions",
        "energy/stretch", ...); values are arrays or numbers. The first step
        fixes the key set and shapes; a later mismatch, or a name not in
        `UNITS`, raises ValueError and nothing is appended.
        """
        self._steps.add(self._steps.check(step, self._attrs.get("load_control")))
        self.flush()

    def append_frame(self, frame: Mapping[str, Any]) -> None:
        """Append one transient frame (datasets under ``frames/``) and rewrite the file."""
        self._frames.add(self._frames.check(frame, self._attrs.get("load_control")))
        self.flush()

    def set_attrs(self, **attrs: Any) -> None:
        """Set root attributes; they are written with the next append (or `flush`)."""
        if "units" in attrs and attrs["units"] != "SI":
            raise ValueError(f"attribute units must be 'SI', got {attrs['units']!r}")
        if (
            "load_control" in attrs
            and self.step_count
            and "load" in self._steps.entries
            and attrs["load_control"] != self._attrs.get("load_control")
        ):
            raise ValueError("load_control cannot change once load steps are written")
        self._attrs.update({key: _check_attr(key, value) for key, value in attrs.items()})

    def flush(self) -> None:
        """Rewrite the whole file atomically from memory."""
        load_control = self._attrs.get("load_control")
        if isinstance(load_control, bytes):
            load_control = load_control.decode()
        groups = {
            "reference": self._reference,
            "steps": self._steps.stacked(),
            "frames": self._frames.stacked(),
        }

        def fill(h5: h5py.File) -> None:
            for key, value in self._attrs.items():
                h5.attrs[key] = value
            for group, datasets in groups.items():
                h5.require_group(group)
                for name, data in datasets.items():
                    full = f"{group}/{name}"
                    _write_dataset(h5, full, data, units_of(full, load_control))

        write_atomically(self.path, fill)

    @property
    def step_count(self) -> int:
        """Load steps appended so far (including those found on `resume`)."""
        return self._steps.count

    @property
    def frame_count(self) -> int:
        """Frames appended so far (including those found on `resume`)."""
        return self._frames.count

    def last_step(self) -> dict[str, np.ndarray]:
        """The last appended step's arrays, by name (empty dict if none)."""
        return self._steps.last()

    def last_frame(self) -> dict[str, np.ndarray]:
        """The last appended frame's arrays, by name (empty dict if none)."""
        return self._frames.last()

    @property
    def attrs(self) -> dict[str, Any]:
        """A copy of the root attributes as they will be written."""
        return {key: _attr_from_h5(value) for key, value in self._attrs.items()}
