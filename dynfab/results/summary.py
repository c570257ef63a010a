"""What a run prints of its result file: a line per finished load step while it runs, the
table of every step and the run's summary at its end (docs/model.md sections 1-10 name the
quantities; `dynfab.results.file` their units).

Each number says whose it is: a yarn's, a family's mean over its loaded yarns, a pull-out's
pulled warp. The table and the summary read a result file's datasets (`Results`), so they
print what a file holds, also a file written by an earlier run.
"""

from __future__ import annotations

import sys
from typing import Callable, NamedTuple

import numpy as np

from dynfab.errors import UserError
from dynfab.model.domain import SLIP_LIMIT
from dynfab.results.file import Results


def step_line(index: int, total: int, record: dict, attrs: dict, unit: str) -> str:
    """The progress line of a finished load step: its quantities (`_step_quantities`, `attrs`
    the result file's root attributes), worst residual, iterations, time."""
    return _progress_line(index, total, record, unit, _step_quantities(attrs, record, unit))


def _progress_line(index: int, total: int, record: dict, unit: str, quantities: str) -> str:
    """One line per finished load step: the step's `quantities` (`_step_quantities`), worst
    residual, iterations, time."""
    steps = record.get("time_steps", record["iterations"])
    what = "time steps" if "time_steps" in record else "iterations"
    buckled, stable = record.get("buckled"), record.get("stable")
    note = ("  (buckled: left an unstable state)" if buckled is not None and buckled.any() else "")
    if stable is not None and not stable.all():
        note += "  (unstable: no escape lowered the energy; see steps/lowest_eigenvalue)"
    return (f"[{index + 1:>{len(str(total))}}/{total}] {quantities}  "
            f"residual {np.max(record['residual']):.2e} N  {what} {int(np.max(steps))}  "
            f"{record['wall_time']:.3f} s{note}")


def _step_quantities(attrs: dict, record: dict, unit: str) -> str:
    """What a progress line shows of a step, each quantity saying whose it is (the kind's
    `quantities`, `KINDS`)."""
    return _kind(attrs).quantities(attrs, record, unit)


def _yarn_quantities(attrs: dict, record: dict, unit: str) -> str:
    """The one-yarn model's load and end displacement (the largest over its yarns when it has
    several)."""
    load = np.atleast_1d(record["load"])
    u = 1e3 * np.atleast_1d(record["end_displacement"])
    whose = f" (largest of {u.size} yarns)" if u.size > 1 else ""
    return f"load {load[0]:.6g} {unit}  end displacement {u.max():.4f} mm{whose}"


def _fabric_quantities(attrs: dict, record: dict, unit: str) -> str:
    """A fabric's loads (warp, weft) and then, in a pull-out (`attrs["pullout_warp"]`), the
    pulled warp's end displacement and pull force and the wefts' mean strain, otherwise both
    families' strain and stress (means over their loaded yarns, docs/model.md section 10), and
    its largest slip ratio (`dynfab.model.domain.slip_ratios`)."""
    load = np.atleast_1d(record["load"])
    text = f"load {load[0]:.6g}, {load[1]:.6g} {unit} (warp, weft)  "
    strain, stress = 100 * np.asarray(record["strain"]), np.asarray(record["stress"])
    if "pullout_warp" in attrs:
        k = int(attrs["pullout_warp"])
        text += (f"warp {k} (pulled): end displacement "
                 f"{1e3 * record['end_displacement'][k - 1]:.4f} mm, pull force "
                 f"{record['end_force'][k - 1]:.4g} N  wefts' mean strain {strain[1]:.4f} %")
    else:
        text += (f"mean strain {strain[0]:.4f}, {strain[1]:.4f} %, stress {stress[0]:.4g}, "
                 f"{stress[1]:.4g} N/m (warp, weft)")
    return text + _slip_text(record)


def _slip_text(record: dict) -> str:
    """A step's largest slip of a fixed crossing's nodes over their segment, or where the
    crossings slide (docs/model.md 11.13) its largest slide along a yarn."""
    if "slip" in record:
        slide = np.nanmax(np.abs(np.asarray(record["slip"], float)), initial=0.0)
        return f"  slide {1e3 * slide:.4g} mm (largest)"
    return f"  slip {float(record['slip_ratio']):.3f} of a segment"


def _specimen_quantities(attrs: dict, record: dict, unit: str) -> str:
    """A shear specimen's clamp displacement and force, shear angles and largest slip
    (docs/model.md section 11)."""
    load = np.atleast_1d(record["load"])
    gamma = np.degrees(np.asarray(record["shear_angle"]))
    return (f"d {1e3 * load[0]:.4g} mm  clamp force {float(record['clamp_force']):.4g} N  "
            f"shear angle {np.median(gamma):.3g} deg (median), {gamma.max():.3g} (largest)"
            + _slip_text(record))


def _solver_time(steps) -> str:
    """"X s in the solver" over the steps (`steps/wall_time`), the time spent compiling
    (`steps/compile_time`, a first run's: later runs load the kernels from the caches) said
    apart."""
    wall = float(np.sum(steps["wall_time"]))
    compiling = float(np.sum(steps["compile_time"])) if "compile_time" in steps else 0.0
    text = f"{wall - compiling:.3f} s in the solver"
    if compiling > 0.0:
        text += f" and {compiling:.1f} s compiling kernels (first run only)"
    return text


def print_summary(results: Results, file=None) -> None:
    """The summary table (per step, or per frame of a transient run), then the run's summary
    (`run_summary`): its steps, solver time and final state; to `file`, else the standard
    output at the time of the call (not at import: a caller may have replaced it since)."""
    file = sys.stdout if file is None else file
    if results.step_count == 0:
        _print_frames_summary(results, file)
    else:
        _kind(results.attrs).table(results, file)
    for line in run_summary(results):
        print(line, file=file)


def _print_yarn_summary(results: Results, file) -> None:
    """The one-yarn model's table: per step and yarn, load, end displacement, end force,
    largest contact force, residual, time."""
    steps = results.steps
    unit = "N" if results.attrs.get("load_control") == "force" else "m"
    labels = results.attrs.get("yarn_labels") or []
    header = (f"{'step':>4} {'yarn':>4} {'load [' + unit + ']':>12} {'u_end [mm]':>11} "
              f"{'P [N]':>11} {'max R [N]':>11} {'residual [N]':>12} {'time [s]':>9}")
    print(header, file=file)
    contact = steps.get("contact_force")
    for i in range(results.step_count):
        for k in range(steps["load"].shape[1]):
            largest = float(contact[i, k].max()) if contact is not None and contact.shape[-1] else 0.0
            print(f"{i + 1:>4} {k + 1:>4} {steps['load'][i, k]:>12.6g} "
                  f"{1e3 * steps['end_displacement'][i, k]:>11.5f} {steps['end_force'][i, k]:>11.5g} "
                  f"{largest:>11.5g} {steps['residual'][i, k]:>12.3e} {steps['wall_time'][i]:>9.4f}",
                  file=file)
    for k, label in enumerate(labels):
        print(f"yarn {k + 1}: {label}", file=file)


def _slip_column(steps, count: int) -> tuple[list[str], str]:
    """(each step's entry with its header first, what they are) of a table's slip column:
    the largest slip ratio of a fixed crossing's node, or where the crossings slide
    (docs/model.md 11.13) the largest slide of a crossing along a yarn [mm]."""
    if "slip" in steps:
        slide = np.abs(np.asarray(steps["slip"], float)).reshape(count, -1)
        largest = 1e3 * np.nanmax(slide, axis=1, initial=0.0)
        return ([f"{'slide [mm]':>10}"] + [f"{v:>10.4g}" for v in largest],
                "slide [mm]: the largest slide of a crossing along a yarn (docs/model.md 11.13)")
    ratio = np.asarray(steps.get("slip_ratio", np.full(count, np.nan)), float)
    return ([f"{'slip/seg':>8}"] + [f"{v:>8.3f}" for v in ratio],
            "slip/seg: the largest slip ratio of a crossing node")


def _print_specimen_summary(results: Results, file) -> None:
    """A shear specimen's table (docs/model.md section 11): per step (step 1 is step 0, the
    preload relaxed) the clamp displacement d, the clamp force along it, the median and
    largest shear angle over the crossings, the largest contact force, slip ratio and slope,
    the residual, the time."""
    steps = results.steps
    slip, slip_key = _slip_column(steps, results.step_count)
    print(f"{'step':>4} {'d [mm]':>9} {'F [N]':>10} {'gamma med':>9} {'gamma max':>9} "
          f"{'max R [N]':>10} {slip[0]} {'slope':>6} {'residual':>10} {'time [s]':>9}",
          file=file)
    for i in range(results.step_count):
        gamma = np.degrees(np.asarray(steps["shear_angle"][i]))
        print(f"{i + 1:>4} {1e3 * steps['load'][i, 0]:>9.4g} {steps['clamp_force'][i]:>10.4g} "
              f"{np.median(gamma):>9.3f} {gamma.max():>9.3f} "
              f"{steps['contact_force'][i].max():>10.4g} {slip[i + 1]} "
              f"{steps['max_slope'][i]:>6.3f} {float(np.max(steps['residual'][i])):>10.3e} "
              f"{steps['wall_time'][i]:>9.4f}", file=file)
    print("gamma: shear angle [deg] from step 0 over the crossings; F: force on the moved clamp "
          f"(frame corner) along d; {slip_key}", file=file)


def _print_fabric_summary(results: Results, file) -> None:
    """A fabric's table (docs/model.md section 10), each column saying whose it is: per step
    the (warp, weft) loads; in a pull-out the pulled warp's end displacement and pull force
    and the wefts' mean strain and stress, otherwise each family's strain and stress (means
    over its loaded yarns); the largest contact force and slip ratio, the residual, the time."""
    steps, attrs = results.steps, results.attrs
    unit = "N" if attrs.get("load_control") == "force" else "m"
    pulled = attrs.get("pullout_warp")
    strain, stress = _family_arrays(results, "strain"), _family_arrays(results, "stress")
    slip, slip_key = _slip_column(steps, results.step_count)
    if pulled is not None:
        k = int(pulled)
        middle = (f"{f'u w{k} [mm]':>10} {f'P w{k} [N]':>10} {'strain we':>10} "
                  f"{'N_we [N/m]':>10}")
        key = (f"w{k}: the pulled warp {k} (end displacement u, pull force P); strain we, "
               f"N_we: the wefts' mean strain and load per unit width")
    else:
        middle = f"{'strain wa':>10} {'strain we':>10} {'N_wa [N/m]':>10} {'N_we [N/m]':>10}"
        key = ("strain, N [N/m]: each family's mean strain and load per unit width over its "
               "loaded yarns (wa: warps, we: wefts)")
    print(f"{'step':>4} {'warp load':>11} {'weft load':>11} {middle} {'max R [N]':>10} "
          f"{slip[0]} {'residual':>10} {'time [s]':>9}", file=file)
    for i in range(results.step_count):
        if pulled is not None:
            values = (f"{1e3 * steps['end_displacement'][i, k - 1]:>10.5f} "
                      f"{steps['end_force'][i, k - 1]:>10.4g} {strain[i, 1]:>10.4g} "
                      f"{stress[i, 1]:>10.4g}")
        else:
            values = (f"{strain[i, 0]:>10.4g} {strain[i, 1]:>10.4g} {stress[i, 0]:>10.4g} "
                      f"{stress[i, 1]:>10.4g}")
        print(f"{i + 1:>4} {steps['load'][i, 0]:>11.5g} {steps['load'][i, 1]:>11.5g} {values} "
              f"{steps['contact_force'][i].max():>10.4g} {slip[i + 1]} "
              f"{float(steps['residual'][i]):>10.2e} {steps['wall_time'][i]:>9.3f}", file=file)
    print(f"loads in {unit}; {key}; {slip_key} (docs/model.md section 10)", file=file)


def _family_arrays(results: Results, name: str) -> np.ndarray:
    """(steps, 2) a fabric's per-family `steps/<name>`; NaN where the file lacks it (a file
    written before `stress` was recorded)."""
    value = results.steps.get(name)
    return np.full((results.step_count, 2), np.nan) if value is None else np.asarray(value, float)


def run_summary(results: Results) -> list[str]:
    """The lines printed after a run's table: its load steps (or frames) and the solver time
    summed over them (`steps/wall_time`), then the last step's state, each quantity saying
    whose it is (the kind's `last_step`, `KINDS`)."""
    if results.step_count == 0:
        times = results.frames.get("time", [])
        return [f"{len(times)} frames to t = {float(times[-1]) if len(times) else 0.0:.6g} s"]
    lines = [f"{results.step_count} load steps, {_solver_time(results.steps)}"]
    return lines + _kind(results.attrs).last_step(results)


def _yarn_summary(results: Results) -> list[str]:
    """`run_summary`'s lines on the one-yarn model's last step: per yarn its end force and
    displacement (and load per unit width, with a weft)."""
    steps, lines = results.steps, []
    labels = results.attrs.get("yarn_labels") or []
    stress = steps.get("stress")
    for k in range(np.asarray(steps["end_force"]).shape[1]):
        label = labels[k] if k < len(labels) else f"yarn {k + 1}"
        line = (f"last step, yarn {k + 1} ({label}): end force {steps['end_force'][-1, k]:.6g} N, "
                f"end displacement {1e3 * steps['end_displacement'][-1, k]:.5f} mm")
        if stress is not None:
            line += f", load per unit width {stress[-1, k]:.6g} N/m"
        lines.append(line)
    return lines


def _specimen_summary(results: Results) -> list[str]:
    """`run_summary`'s line on a shear specimen's last step (docs/model.md section 11)."""
    steps = results.steps
    gamma = np.degrees(np.asarray(steps["shear_angle"][-1]))
    line = (f"last step: d = {1e3 * float(steps['load'][-1, 0]):.5g} mm, clamp force "
            f"{float(steps['clamp_force'][-1]):.6g} N, shear angle "
            f"{np.median(gamma):.4g} deg (median over the crossings)")
    if "slip" in steps:  # crossings that slide (docs/model.md 11.13)
        return [line] + _slides(steps)
    return [line + f", largest slip {float(steps['slip_ratio'][-1]):.3g} of a segment"]


def _fabric_summary(results: Results) -> list[str]:
    """`run_summary`'s lines on a fabric's last step, its pull-out and its slips."""
    steps, attrs = results.steps, results.attrs
    strain, stress = _family_arrays(results, "strain")[-1], _family_arrays(results, "stress")[-1]
    lines = [f"last step: mean strain {100 * strain[0]:.5g} %, {100 * strain[1]:.5g} % and load "
             f"per unit width {stress[0]:.6g}, {stress[1]:.6g} N/m (warp, weft: means over each "
             f"family's loaded yarns)"]
    if "pullout_warp" in attrs:
        k = int(attrs["pullout_warp"])
        force, u = steps["end_force"][:, k - 1], steps["end_displacement"][:, k - 1]
        peak = int(np.argmax(force))
        lines.append(f"pull-out of warp {k}: peak pull force {force[peak]:.6g} N at step "
                     f"{peak + 1} (end displacement {1e3 * u[peak]:.5f} mm); last step "
                     f"{force[-1]:.6g} N at {1e3 * u[-1]:.5f} mm")
    if "slip" in steps:  # crossings that slide (docs/model.md 11.13)
        lines += _slides(steps)
    elif "slip_ratio" in steps:
        slip = np.asarray(steps["slip_ratio"], float)
        worst = int(np.argmax(slip))
        lines.append(f"largest slip of a crossing node: {slip[worst]:.3f} of its segment, at "
                     f"step {worst + 1} (a step stops above {SLIP_LIMIT:g}: docs/model.md "
                     f"section 10)")
    return lines


def _slides(steps) -> list[str]:
    """Where the crossings slide: the largest slide of a crossing along a yarn and the
    crossings a yarn end has left, with the step it left the first."""
    slide = np.abs(np.asarray(steps["slip"], float))
    largest = np.nanmax(slide, axis=tuple(range(1, slide.ndim)), initial=0.0)
    worst = int(np.argmax(largest))
    lines = [f"largest slide of a crossing along a yarn: {1e3 * largest[worst]:.4g} mm, at "
             f"step {worst + 1} (crossings slide: docs/model.md 11.13)"]
    present = np.asarray(steps["crossing_present"], bool).reshape(slide.shape[0], -1)
    left = np.flatnonzero(~present.all(axis=1))
    if left.size:
        gone = int((~present[-1]).sum())
        lines.append(f"crossings a yarn end has left: {gone}, the first at step {left[0] + 1}")
    return lines


def _print_frames_summary(results: Results, file) -> None:
    """A transient run's table: per frame, time, kinetic energy and largest contact force, and
    where the frames hold them (a specimen's) d and the clamp force."""
    frames = results.frames
    clamp = "clamp_force" in frames and "load" in frames
    extra = f" {'d [m]':>11} {'clamp F [N]':>12}" if clamp else ""
    print(f"{'frame':>5} {'time [s]':>11} {'kinetic [J]':>12} {'max R [N]':>11}{extra}", file=file)
    contact = frames.get("contact_force")
    for i, time_s in enumerate(frames.get("time", [])):
        largest = float(contact[i].max()) if contact is not None and contact[i].size else 0.0
        row = (f" {float(np.ravel(frames['load'][i])[0]):>11.5g} "
               f"{float(frames['clamp_force'][i]):>12.5g}" if clamp else "")
        print(f"{i:>5} {time_s:>11.6g} {frames['energy/kinetic'][i].max():>12.4g} {largest:>11.5g}"
              f"{row}", file=file)


class KindSummary(NamedTuple):
    """What the summary prints of one kind of result file (its root attribute "model")."""

    quantities: Callable[[dict, dict, str], str]
    """(attrs, record, unit) -> a progress line's quantities."""
    table: Callable[[Results, object], None]
    """(results, file): the table of its steps."""
    last_step: Callable[[Results], list[str]]
    """results -> the summary's lines on its last step."""


KINDS = {"yarn": KindSummary(_yarn_quantities, _print_yarn_summary, _yarn_summary),
         "fabric": KindSummary(_fabric_quantities, _print_fabric_summary, _fabric_summary),
         "specimen": KindSummary(_specimen_quantities, _print_specimen_summary,
                                 _specimen_summary)}
"""Each kind of result file's summary (docs/model.md sections 1-9, 10 and 11)."""


def _kind(attrs) -> KindSummary:
    """The summary of a result file's kind (a file without the attribute: the one-yarn
    model's, as written before the fabric existed); a UserError for a kind it does not know."""
    kind = KINDS.get(attrs.get("model", "yarn"))
    if kind is None:
        raise UserError(f"a result file of a model this dynfab does not summarise "
                        f"({attrs.get('model')!r}; it summarises {', '.join(KINDS)})")
    return kind
