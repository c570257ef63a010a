"""The gathered table of a study (`study.nc`): an xarray Dataset written as netCDF-4 (HDF5).

One dimension ``case`` (the cases in the study's order: case i is ``cases/case-000i.h5``),
the varied keys as coordinates along it (named as the keys, "friction.alpha"; a ``units``
attribute each; a list-valued key's lists as their text), and per observable
(`dynfab.studies.file.Observable`) a variable named as it is:

* ``at = "path"``: (case, step, ...) the dataset at every load step, NaN past a case's
  finished steps (a failed case, or a shorter path); ``load`` (case, step) is the load
  path's value at each step (load.values, a fabric's warps'), in the control's units;
* ``at = "last"``: (case, ...) the last step's value, NaN for a failed case;
* ``at = LOAD``: (case, ...) the value where the path passes LOAD, linear between the two
  steps around it, a step's own value at a step (NaN where a failed case did not get
  there); the attribute ``at`` holds LOAD.

A dataset's further axes are dimensions ``<name>_1``, ``<name>_2``, ... (a yarn, a family).
Values are float64 (the datasets' values exactly; bools and counts converted), each with
its ``units`` attribute (`dynfab.results.file.UNITS`). Per case: ``status`` ("finished",
"failed"), ``message`` (a failure's, else ""), ``steps_done`` and ``solver_time`` [s] (the
sum of its steps' wall_time). Root attributes: ``title``, ``design``, ``solver``,
``parameters`` (the varied keys, one per line), ``study`` (the study file's text),
``base_scene`` (the base scene's TOML), ``dynfab_version``.

A grid's cases unstack into one dimension per key with xarray:
``ds.set_index(case=ds.attrs["parameters"].split()).unstack("case")``.
Written through a temporary file and renamed: a ``study.nc`` present is complete.
"""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np

from dynfab.studies.file import AT_LAST, AT_PATH, Observable, Study, load_position, observable_units

STEP = "step"
CASE = "case"


def gather(plan: Study, folder):
    """The table (an xarray Dataset) of the study `plan` from the case files in `folder`
    (`dynfab.studies.study.StudyFolder`)."""
    import xarray as xr

    from dynfab.results.file import dynfab_version, read_results

    wanted = sorted({f"steps/{o.dataset}" for o in plan.observables})
    rows, status, messages, done, solver_time = [], [], [], [], []
    for case in plan.cases:
        state, message = folder.state(case)
        path = folder.case_path(case)
        results = read_results(path, only=wanted + ["steps/wall_time"]) if path.exists() \
            else None
        steps = results.steps if results is not None else {}
        rows.append(steps)
        status.append(state if state in ("finished", "failed") else "missing")
        messages.append(message)
        done.append(len(steps.get("wall_time", ())))
        solver_time.append(float(np.sum(steps["wall_time"])) if "wall_time" in steps
                           else np.nan)
    control = plan.base.load.control
    longest = max(case.steps for case in plan.cases)
    variables = {
        "load": ((CASE, STEP), _padded([c.path for c in plan.cases], longest),
                 {"units": "N" if control == "force" else "m",
                  "long_name": "load path value (load.values)"}),
        "status": (CASE, np.array(status, dtype=str)),
        "message": (CASE, np.array(messages, dtype=str)),
        "steps_done": (CASE, np.array(done, dtype=np.int64)),
        "solver_time": (CASE, np.array(solver_time), {"units": "s"}),
    }
    for observable in plan.observables:
        values = [_value(observable, row, case, state == "finished")
                  for row, case, state in zip(rows, plan.cases, status)]
        variables[observable.name] = _variable(observable, values, longest, control)
    coords = {CASE: np.arange(len(plan.cases))}
    units = plan.parameter_units()
    for i, key in enumerate(plan.parameters):
        column = _coordinate([case.values[i] for case in plan.cases])
        coords[key] = (CASE, column, {"units": units[key]} if units[key] else {})
    attrs = {"title": plan.title, "design": plan.design, "solver": plan.solver,
             "parameters": "\n".join(plan.parameters), "study": plan.text,
             "base_scene": plan.base.text, "dynfab_version": dynfab_version()}
    if plan.design == "latin_hypercube":
        attrs.update(count=plan.count, seed=plan.seed)
    return xr.Dataset(variables, coords=coords, attrs=attrs)


def write_table(plan: Study, folder, path: Path) -> Path:
    """Gather the table and write it to `path` (netCDF-4 by h5netcdf), atomically."""
    table = gather(plan, folder)
    tmp = path.with_name(f"{path.name}.part-{os.getpid()}")
    table.to_netcdf(tmp, engine="h5netcdf")
    with open(tmp, "rb+") as handle:
        os.fsync(handle.fileno())
    os.replace(tmp, path)
    return path


def _value(observable: Observable, steps: dict, case, finished: bool):
    """One case's value of an observable (None: none, NaN in the table)."""
    data = steps.get(observable.dataset)
    if data is None or len(data) == 0:
        return None
    data = np.asarray(data, dtype=np.float64)
    if observable.at == AT_PATH:
        return data
    if observable.at == AT_LAST:
        return data[-1] if finished else None
    index, weight = load_position(case.path, observable.at)
    if index >= len(data):
        return None
    if weight == 1.0:
        return data[index]
    return (1.0 - weight) * data[index - 1] + weight * data[index]


def _variable(observable: Observable, values: list, longest: int, control: str):
    """(dims, array, attrs) of an observable over the cases, NaN where a case has none."""
    shapes = {np.shape(v)[1:] if observable.at == AT_PATH else np.shape(v)
              for v in values if v is not None}
    if len(shapes) > 1:
        from dynfab.errors import UserError

        raise UserError(f"observe.{observable.name}: steps/{observable.dataset} has different "
                        f"shapes in different cases ({', '.join(map(str, sorted(shapes)))}): "
                        "gather it at one of its entries per case in a script")
    trailing = shapes.pop() if shapes else ()
    lead = (len(values), longest) if observable.at == AT_PATH else (len(values),)
    array = np.full(lead + trailing, np.nan)
    for i, value in enumerate(values):
        if value is None:
            continue
        if observable.at == AT_PATH:
            array[i, :len(value)] = value
        else:
            array[i] = value
    dims = (CASE, STEP) if observable.at == AT_PATH else (CASE,)
    dims += tuple(f"{observable.name}_{k + 1}" for k in range(len(trailing)))
    attrs = {"units": observable_units(observable, control),
             "dataset": f"steps/{observable.dataset}"}
    attrs["at"] = observable.at
    return dims, array, attrs


def _coordinate(values: list) -> np.ndarray:
    """A varied key's values as a coordinate: numbers, strings, or a list-valued key's lists
    as their TOML text ("[0.1, 0.2]")."""
    if any(isinstance(v, (list, tuple)) for v in values):
        return np.array([json.dumps(list(v)) for v in values], dtype=str)
    return np.asarray(values)


def _padded(arrays: list[np.ndarray], longest: int) -> np.ndarray:
    out = np.full((len(arrays), longest), np.nan)
    for i, array in enumerate(arrays):
        out[i, :len(array)] = array
    return out
