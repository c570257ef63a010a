"""A measured traction curve for `dynfab fit`: CSV reading and validation.

The CSV's header names datasets with SI units in brackets. First the load path
of the scene's control; then the measured per-step observables of the scene's
model, each optionally followed by its noise level `<name> sigma [unit]`
(docs/model.md "Fitting parameters"):

- the one-yarn model (geometry.model = "yarn"): the load column `load [N]`
  (force control) or `end_displacement [m]` (displacement control); measured
  `end_displacement [m]`, `end_force [N]`, `crimp [-]`;
- the woven fabric (geometry.model = "fabric"): the warps' load column as
  above, then optionally the wefts' `weft_load [N]` or `weft_end_displacement
  [m]` (absent: the wefts' load is 0 at every step, the scene's default without
  load.weft_values); measured `warp_strain [-]`, `weft_strain [-]`, `warp_crimp
  [-]`, `weft_crimp [-]`, `warp_stress [N/m]`, `weft_stress [N/m]` (each family's
  entry of the step record's strain, crimp, stress; `dynfab.model.fabric.model`);
- an in-plane shear specimen (a `[specimen]` scene, docs/model.md section 11): the clamp
  displacement `end_displacement [m]`, measured `clamp_force [N]`.

A column that is the load itself under the scene's control (a strain under
displacement control, a stress or end force under force control) is refused.
A new measurable column is one `Column` entry in its model's table. Every
mistake is a UserError of one line naming the column (or row) and what is
allowed; a column of the other model names that model.
"""

from __future__ import annotations

import csv
import math
import re
from dataclasses import dataclass
from pathlib import Path
from typing import NamedTuple

import numpy as np

from dynfab.errors import UserError


@dataclass(frozen=True)
class Column:
    """A measured column a curve may hold: its SI unit and where a solved step has it."""

    unit: str
    dataset: str
    """The step record's dataset holding it (`dynfab.results.file.UNITS`); the one-yarn model's
    are the names of `dynfab.fitting.sensitivity.OBSERVABLES`."""
    index: int | None = None
    """Its entry in that dataset: 0 the warps', 1 the wefts' of a per-family (2,) dataset;
    None: the dataset's one value."""
    prescribed: str = ""
    """The control under which the column is the load itself, not a measurement."""
    family: str = ""
    """"warp", "weft", or "" (the one-yarn model's): the label of its curve in a figure."""

    def read(self, record: dict) -> float:
        """The column's value in a step's record."""
        value = np.asarray(record[self.dataset], float)
        return float(value.ravel()[0] if self.index is None else value[self.index])


MEASURABLE = {
    "end_displacement": Column("m", "end_displacement", prescribed="displacement"),
    "end_force": Column("N", "end_force", prescribed="force"),
    "crimp": Column("-", "crimp"),
}
"""The one-yarn model's measured columns (the result file's names)."""

FABRIC_MEASURABLE = {
    "warp_strain": Column("-", "strain", 0, "displacement", "warp"),
    "weft_strain": Column("-", "strain", 1, "displacement", "weft"),
    "warp_crimp": Column("-", "crimp", 0, "", "warp"),
    "weft_crimp": Column("-", "crimp", 1, "", "weft"),
    "warp_stress": Column("N/m", "stress", 0, "force", "warp"),
    "weft_stress": Column("N/m", "stress", 1, "force", "weft"),
}
"""The woven fabric's measured columns: each family's entry of the record's strain, crimp
and stress (`dynfab.model.fabric.model`)."""

LOAD_COLUMN = {"force": ("load", "N"), "displacement": ("end_displacement", "m")}
"""The first column under each control: the load-path variable (of the warps, in a fabric)."""

WEFT_LOAD_COLUMN = {"force": ("weft_load", "N"), "displacement": ("weft_end_displacement", "m")}
"""A fabric curve's optional second column under each control: the wefts' load path."""

SPECIMEN_MEASURABLE = {
    "clamp_force": Column("N", "clamp_force"),
}
"""An in-plane shear specimen's measured column: the force on the moved clamp (frame corner)
along its displacement (`dynfab.model.fabric.specimen_model`, docs/model.md section 11)."""

class CurveKind(NamedTuple):
    """What a measured curve of one kind of scene holds."""

    words: str
    """Its name in a message."""
    columns: dict
    """Its measured columns, name -> Column."""
    weft_load: bool
    """Whether a second load column, the wefts' path, may follow the first."""
    controls: tuple
    """The load controls its scenes run."""


MODELS = {"yarn": CurveKind('the one-yarn model (geometry.model = "yarn")', MEASURABLE, False,
                            ("force", "displacement")),
          "fabric": CurveKind('the woven fabric (geometry.model = "fabric")', FABRIC_MEASURABLE,
                              True, ("force", "displacement")),
          "specimen": CurveKind("a shear specimen (a [specimen] scene)", SPECIMEN_MEASURABLE,
                                False, ("displacement",))}
"""Each kind of scene (`dynfab.model.builders.scene_kind`) -> what its curves hold (a specimen is loaded by its
clamp displacement only)."""

_HEADER = re.compile(
    r"^\s*(?P<name>[A-Za-z_][A-Za-z0-9_]*)(?P<sigma>\s+sigma)?\s*\[(?P<unit>[^\]]*)\]\s*$")


def measurable(model: str) -> dict:
    """The measured columns of `model` (`MODELS`), name -> Column."""
    return MODELS[model].columns


@dataclass(frozen=True)
class CurveData:
    """A validated measured curve."""

    load: np.ndarray
    """The load path, the first column (points,) [N or m] (the warps', in a fabric)."""
    measured: dict
    """name -> measured values (points,) in SI units."""
    sigma: dict
    """name -> noise level (points,) for columns that have one; empty when none has."""
    source: str = "<data>"
    control: str = "force"
    """The control whose load path the first column is."""
    model: str = "yarn"
    """The model whose columns the curve holds: "yarn" or "fabric"."""
    weft_load: np.ndarray | None = None
    """A fabric curve's wefts' load path (points,) [N or m]; None: no such column (0)."""

    @property
    def points(self) -> int:
        return self.load.size

    @property
    def residual_count(self) -> int:
        return self.load.size * len(self.measured)

    @property
    def path(self) -> np.ndarray:
        """The load path the scene takes: (points,) for one yarn, (points, 2) (warp value,
        weft value) for a fabric, the weft's 0 without a weft column."""
        if not MODELS[self.model].weft_load:
            return self.load
        weft = np.zeros_like(self.load) if self.weft_load is None else self.weft_load
        return np.column_stack([self.load, weft])

    def column(self, name: str) -> Column:
        return measurable(self.model)[name]


def read_curve(path, control: str, model: str = "yarn") -> CurveData:
    """Read and validate the CSV curve at `path` for a scene of `model` under `control`."""
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise UserError(f"data file '{path}' not found") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise UserError(f"cannot read data file '{path}': {exc}") from None
    rows = [row for row in csv.reader(text.splitlines()) if row and any(c.strip() for c in row)
            and not row[0].lstrip().startswith("#")]
    if len(rows) < 2:
        raise UserError(f"{path}: needs a header line and at least one row of numbers")
    return curve_from_columns(rows[0], rows[1:], control, str(path), model)


def curve_from_columns(header, rows, control: str, source: str = "<data>",
                       model: str = "yarn") -> CurveData:
    """Validate a header (column names with units) and rows of numbers (strings or floats)
    for a scene of `model` ("yarn" or "fabric") under `control`. A header that does not fit
    is refused in one line that names the columns expected and those found."""
    try:
        columns = [_parse_header(source, text) for text in header]
        _check_load_column(source, columns[0], control)
        loads = _check_names(columns, header, control, source, model)
    except UserError as error:
        found = ", ".join(f"'{text.strip()}'" for text in header)
        raise UserError(f"{error}; {expected_columns(model, control)}; found {found}") from None
    return _validated(columns, header, rows, loads, control, source, model)


def _check_names(columns, header, control: str, source: str, model: str) -> int:
    """The header's columns past the load path (names, units, order), before any number;
    returns how many load columns it starts with (`_load_columns`)."""
    loads = _load_columns(columns, control, model)
    if loads == 2:
        _check_unit(source, header[1].strip(), columns[1][2], WEFT_LOAD_COLUMN[control][1])
    measured = {}
    for index, (name, is_sigma, unit) in enumerate(columns[loads:], start=loads):
        label = header[index].strip()
        if is_sigma:
            _check_sigma_column(source, label, name, unit, measured, model)
            continue
        _check_measured(source, label, name, unit, control, measured, model)
        measured[name] = None
    if not measured:
        raise UserError(f"{source}: no measured column after '{header[loads - 1].strip()}': "
                         "give one of " + _listing(model, control))
    return loads


def _load_columns(columns, control: str, model: str) -> int:
    """1, or 2 where a fabric's curve gives its wefts' load path second."""
    return 1 + (model == "fabric" and len(columns) > 1
                and columns[1][0] == WEFT_LOAD_COLUMN[control][0] and not columns[1][1])


def expected_columns(model: str, control: str) -> str:
    """The columns a curve of `model` under `control` takes, in words."""
    load, unit = LOAD_COLUMN[control]
    weft = (f", then optionally '{WEFT_LOAD_COLUMN[control][0]} "
            f"[{WEFT_LOAD_COLUMN[control][1]}]'" if MODELS[model].weft_load else "")
    return (f"{MODELS[model][0]} under {control} control takes '{load} [{unit}]' first{weft}, "
            f"then one or more of {_listing(model, control)} (each optionally with its "
            "'<name> sigma [unit]')")


def columns_help() -> str:
    """`dynfab fit --help`'s list of the CSV columns each kind of scene takes."""
    lines = ["CSV columns (a header of 'name [unit]' in SI units, then one row per point):"]
    for model in MODELS:
        for control in ("force", "displacement"):
            if control not in MODELS[model].controls:
                continue
            lines.append(f"  - {expected_columns(model, control)}")
    return "\n".join(lines)


def _validated(columns, header, rows, loads: int, control: str, source: str,
               model: str) -> CurveData:
    """`curve_from_columns` past its header (`_check_names`, which counted its `loads`
    columns): the numbers."""
    values = _numbers(source, header, rows)
    _check_path(source, [h.strip() for h in header[:loads]], values[:, :loads])
    measured, sigma = {}, {}
    for index, (name, is_sigma, unit) in enumerate(columns[loads:], start=loads):
        label = header[index].strip()
        if is_sigma:
            _check_positive(source, label, values[:, index])
            sigma[name] = values[:, index]
            continue
        measured[name] = values[:, index]
    if sigma and set(sigma) != set(measured):
        missing = sorted(set(measured) - set(sigma))
        raise UserError(f"{source}: a sigma column for some measured columns but not for "
                         f"{', '.join(missing)}: give one for each or for none")
    return CurveData(load=values[:, 0], measured=measured, sigma=sigma, source=source,
                     control=control, model=model,
                     weft_load=values[:, 1] if loads == 2 else None)


def _listing(model: str, control: str) -> str:
    """The measured columns of `model` under `control`, as a message lists them."""
    return ", ".join(f"'{n} [{c.unit}]'" for n, c in measurable(model).items()
                     if c.prescribed != control)


def _parse_header(source, text: str):
    match = _HEADER.match(text)
    if match is None:
        raise UserError(f"{source}: column '{text.strip()}' is not 'name [unit]' "
                         "(e.g. 'end_force [N]', 'end_force sigma [N]')")
    return match["name"], match["sigma"] is not None, match["unit"].strip()


def _check_load_column(source, column, control: str) -> None:
    name, is_sigma, unit = column
    want_name, want_unit = LOAD_COLUMN[control]
    if is_sigma or name != want_name:
        raise UserError(f"{source}: the first column must be '{want_name} [{want_unit}]', the "
                         f"load path of a scene under {control} control; got '{name}'")
    if unit != want_unit:
        raise UserError(f"{source}: column '{name}' is in [{unit}]; it must be in SI "
                         f"[{want_unit}]")


def _check_unit(source, label: str, unit: str, want: str) -> None:
    if unit != want:
        raise UserError(f"{source}: column '{label}' is in [{unit}]; it must be in SI [{want}]")


def _check_measured(source, label, name, unit, control, measured, model: str) -> None:
    columns = measurable(model)
    if name not in columns:
        raise _foreign_column(source, label, name, control, model)
    if unit != columns[name].unit:
        raise UserError(f"{source}: column '{label}' is in [{unit}]; '{name}' is in SI "
                         f"[{columns[name].unit}]")
    if columns[name].prescribed == control:
        raise UserError(f"{source}: column '{label}' is the prescribed load under {control} "
                         "control, not a measurement")
    if name in measured:
        raise UserError(f"{source}: column '{label}' appears twice")


def _foreign_column(source, label, name, control, model: str) -> UserError:
    """The error for a column `model` does not measure: another model's, a misplaced or
    mismatched weft load, or unknown."""
    this = MODELS[model][0]
    weft_names = {n: c for c, (n, _) in WEFT_LOAD_COLUMN.items()}
    if name in weft_names:
        if not MODELS[model].weft_load:
            return UserError(f"{source}: column '{label}' is the wefts' load of the woven fabric; "
                             f"this scene is {this}, which takes no wefts' load")
        if weft_names[name] != control:
            want, unit = WEFT_LOAD_COLUMN[control]
            return UserError(f"{source}: column '{label}' is the wefts' load under "
                             f"{weft_names[name]} control; this scene is under {control} "
                             f"control: '{want} [{unit}]'")
        return UserError(f"{source}: column '{label}', the wefts' load path, must be the second "
                         f"column, right after '{LOAD_COLUMN[control][0]} "
                         f"[{LOAD_COLUMN[control][1]}]'")
    for other, kind in MODELS.items():
        if other != model and name in kind.columns:
            return UserError(f"{source}: column '{label}' is a measurement of {kind.words}; "
                             f"this scene is {this}, whose measured columns are "
                             + _listing(model, control))
    return UserError(f"{source}: unknown column '{label}': a measured column of {this} is one "
                     "of " + _listing(model, control))


def _check_sigma_column(source, label, name, unit, measured, model: str) -> None:
    """A sigma column follows its measured column `name` and has its units."""
    if name not in measured:
        raise UserError(f"{source}: column '{label}' does not follow a measured column "
                         f"'{name} [...]'")
    want = measurable(model)[name].unit
    if unit != want:
        raise UserError(f"{source}: column '{label}' is in [{unit}]; it must be in "
                         f"[{want}] like '{name}'")


def _check_positive(source, label, values) -> None:
    """Every value of a sigma column `label` > 0."""
    if not (values > 0).all():
        row = int(np.argmin(values > 0)) + 2
        raise UserError(f"{source}: row {row}: '{label}' must be positive")


def _numbers(source, header, rows) -> np.ndarray:
    values = np.empty((len(rows), len(header)))
    for r, row in enumerate(rows):
        line = r + 2  # the header is line 1
        if len(row) != len(header):
            raise UserError(f"{source}: row {line} has {len(row)} values; the header has "
                             f"{len(header)} columns")
        for c, cell in enumerate(row):
            try:
                value = float(cell)
            except (TypeError, ValueError):
                raise UserError(f"{source}: row {line}, column '{header[c].strip()}': "
                                 f"'{str(cell).strip()}' is not a number") from None
            if not math.isfinite(value):
                raise UserError(f"{source}: row {line}, column '{header[c].strip()}': {value} "
                                 "(every value must be a finite number)")
            values[r, c] = value
    return values


def _check_path(source, labels, load) -> None:
    """The load path (points, columns) must move away from the unloaded start on one branch:
    each column monotonic (never reversing) from 0, and each row a new load (a first row at 0,
    the unloaded state, is allowed). One column (the one-yarn model's, or a fabric's without
    a weft column) is then strictly monotonic; a fabric's weft or warp column may stay
    constant (at 0, say) while the other moves."""
    start = 1 if load.shape[0] > 1 and not load[0].any() else 0
    moving = load[start:]
    first_row = 2 + start
    steps = np.diff(np.vstack([np.zeros((1, load.shape[1])), moving]), axis=0)
    if load.shape[1] == 1:
        steps = steps[:, 0]
        if not ((steps > 0).all() or (steps < 0).all()):
            bad = int(np.argmax(steps <= 0) if steps[0] > 0 else np.argmax(steps >= 0))
            raise UserError(f"{source}: column '{labels[0]}' must move strictly away from 0 "
                             f"(strictly monotonic from the unloaded start); row "
                             f"{bad + first_row} does not")
        return
    for c, label in enumerate(labels):
        sign = np.sign(steps[np.flatnonzero(steps[:, c])[:1], c])
        reverse = np.flatnonzero(np.sign(steps[:, c]) == -sign) if sign.size else []
        if len(reverse):
            raise UserError(f"{source}: column '{label}' must move away from 0 (monotonic from "
                             f"the unloaded start); row {reverse[0] + first_row} turns back")
    still = np.flatnonzero(~steps.any(axis=1))
    if still.size:
        raise UserError(f"{source}: row {still[0] + first_row} repeats the load of the row "
                         f"before ('{', '.join(labels)}'): each row must be a new load step")
