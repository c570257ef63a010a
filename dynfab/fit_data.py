"""A measured traction curve for `dynfab fit`: CSV reading and validation.

The CSV's header names datasets with SI units in brackets. The first column
is the load path of the scene's control (`load [N]` under force control,
`end_displacement [m]` under displacement control); the others are measured
per-step observables (`end_displacement [m]`, `end_force [N]`, `crimp [-]`),
each optionally followed by its noise level `<name> sigma [unit]`. Every
mistake is a UserError of one line naming the column (or row) and what is
allowed.
"""

from __future__ import annotations

import csv
import math
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from dynfab.errors import UserError

MEASURABLE = {"end_displacement": "m", "end_force": "N", "crimp": "-"}
"""Observables a curve may hold, with their SI units (the result file's names)."""

LOAD_COLUMN = {"force": ("load", "N"), "displacement": ("end_displacement", "m")}
"""The first column under each control: the load-path variable."""

_HEADER = re.compile(
    r"^\s*(?P<name>[A-Za-z_][A-Za-z0-9_]*)(?P<sigma>\s+sigma)?\s*\[(?P<unit>[^\]]*)\]\s*$")


@dataclass(frozen=True)
class CurveData:
    """A validated measured curve."""

    load: np.ndarray
    """The load path, the first column (points,) [N or m]."""
    measured: dict
    """name -> measured values (points,) in SI units."""
    sigma: dict
    """name -> noise level (points,) for columns that have one; empty when none has."""
    source: str = "<data>"
    control: str = "force"
    """The control whose load path the first column is."""

    @property
    def points(self) -> int:
        return self.load.size

    @property
    def residual_count(self) -> int:
        return self.load.size * len(self.measured)


def read_curve(path, control: str) -> CurveData:
    """Read and validate the CSV curve at `path` for a scene under `control`."""
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
    return curve_from_columns(rows[0], rows[1:], control, str(path))


def curve_from_columns(header, rows, control: str, source: str = "<data>") -> CurveData:
    """Validate a header (column names with units) and rows of numbers (strings or floats)."""
    columns = [_parse_header(source, text) for text in header]
    _check_load_column(source, columns[0], control)
    values = _numbers(source, header, rows)
    load = values[:, 0]
    _check_monotonic(source, header[0], load)
    measured, sigma = {}, {}
    for index, (name, is_sigma, unit) in enumerate(columns[1:], start=1):
        label = header[index].strip()
        if is_sigma:
            _check_sigma(source, label, name, unit, measured, values[:, index])
            sigma[name] = values[:, index]
            continue
        _check_measured(source, label, name, unit, control, measured)
        measured[name] = values[:, index]
    if not measured:
        raise UserError(f"{source}: no measured column after '{header[0].strip()}': give one "
                         "of " + ", ".join(f"'{n} [{u}]'" for n, u in MEASURABLE.items()))
    if sigma and set(sigma) != set(measured):
        missing = sorted(set(measured) - set(sigma))
        raise UserError(f"{source}: a sigma column for some measured columns but not for "
                         f"{', '.join(missing)}: give one for each or for none")
    return CurveData(load=load, measured=measured, sigma=sigma, source=source, control=control)


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


def _check_measured(source, label, name, unit, control, measured) -> None:
    if name not in MEASURABLE:
        raise UserError(f"{source}: unknown column '{label}': a measured column is one of "
                         + ", ".join(f"'{n} [{u}]'" for n, u in MEASURABLE.items()))
    if unit != MEASURABLE[name]:
        raise UserError(f"{source}: column '{label}' is in [{unit}]; '{name}' is in SI "
                         f"[{MEASURABLE[name]}]")
    if name == LOAD_COLUMN[control][0] or (control == "force" and name == "end_force"):
        raise UserError(f"{source}: column '{label}' is the prescribed load under {control} "
                         "control, not a measurement")
    if name in measured:
        raise UserError(f"{source}: column '{label}' appears twice")


def _check_sigma(source, label, name, unit, measured, values) -> None:
    if name not in measured:
        raise UserError(f"{source}: column '{label}' does not follow a measured column "
                         f"'{name} [...]'")
    if unit != MEASURABLE[name]:
        raise UserError(f"{source}: column '{label}' is in [{unit}]; it must be in "
                         f"[{MEASURABLE[name]}] like '{name}'")
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


def _check_monotonic(source, label, load) -> None:
    """The load path must be strictly monotonic from the unloaded start (a first row at 0, the
    unloaded state, is allowed): each data point a new load step on one branch."""
    moving = load[1:] if load.size > 1 and load[0] == 0.0 else load
    first_row = 2 + (load.size - moving.size)
    steps = np.diff(np.concatenate([[0.0], moving]))
    if not ((steps > 0).all() or (steps < 0).all()):
        bad = int(np.argmax(steps <= 0) if steps[0] > 0 else np.argmax(steps >= 0))
        raise UserError(f"{source}: column '{label.strip()}' must move strictly away from 0 "
                         f"(strictly monotonic from the unloaded start); row {bad + first_row} "
                         "does not")
