"""Running a scene's load path with a solver, writing each finished step at once.

`run(scene, solver=...)` is the Python API behind `dynfab run`: it builds the
model, solves the load steps in order from the as-woven state (or from the
last step of the file with `resume=True`), appends every finished step to the
crash-safe result file, and returns the same arrays as `read_results` would.
A solver failure keeps every finished step on disk and re-raises the
`SolverError` with the load step named. Solvers are driven through their
contracts (`dynfab.solver`): `Solver.step` per load value, or `Transient.advance`
for a transient run.
"""

from __future__ import annotations

import contextlib
import signal
import sys
import threading
import time
import warnings
from pathlib import Path
from typing import Callable

import numpy as np

from dynfab.budget import check_budget
from dynfab.domain import SLIP_LIMIT, check_not_folded
from dynfab.errors import DynfabError, SolverError, UserError
from dynfab.options import apply_run_options, check_solver
from dynfab.model import Model, State, build_model, initial_state, width_per_yarn
from dynfab.results import ResultFile, Results, dynfab_version, finished_counts, read_results
from dynfab.scene import Scene, expand_sweep, scene_to_toml
from dynfab.solver import Solver, Transient
from dynfab.views import add_views
from dynfab.xdmf import XdmfSync, has_views, nodal_point_data, xdmf_path

def make_solver(model: Model, solver: str, device: str | None = None,
                progress=None) -> Solver | Transient:
    """The solver object named `solver`, built for `model` (its options are the scene's): a
    `Solver` driven by load step, or for dynamic.mode = "transient" a `Transient` driven by
    time (`dynfab.solver`); within a step, the dynamic solver reports each launch to
    `progress`, the static one each yarn solved (a batch's)."""
    if check_solver(solver) == "static":
        if device is not None:
            raise UserError(f"--device {device}: the static solver runs on the CPU (numba); "
                             "a device is for --solver dynamic")
        from dynfab.static import StaticSolver
        return StaticSolver(model, status=progress)
    from dynfab.dynamic import DynamicSolver, DynamicTransient
    kind = DynamicTransient if model.scene.dynamic.mode == "transient" else DynamicSolver
    return kind(model, device=device or "cpu", progress=progress)


def run(scene: Scene, solver: str = "static", out: str | Path | None = None, *,
        overwrite: bool = False, resume: bool = False,
        progress: Callable[[str], None] | None = None,
        status: Callable[[str], None] | None = None, device: str | None = None,
        **options) -> Results:
    """Solve the scene's load path; write `out` (HDF5) if given; return the results.

    `solver` is "static" or "dynamic"; `device` the Warp device of the dynamic
    solver ("cpu", "cuda", ...). `options` are the solver's options, the same
    as the command line's (`dynfab.options`): static `tolerance` [N],
    `accuracy`, `max_iterations`; dynamic `mode`, `method`, `damping`,
    `damping_coefficient` [1/s], `masses`, `dt` [s], `safety`, `tolerance` [N],
    `accuracy`, `max_steps`, `precision` (meanings and defaults:
    `dynfab.scene.Static`, `dynfab.scene.Dynamic`). They are set on the scene,
    so the result file's `scene` attribute is the scene actually run; an option
    the solver does not take is a UserError. `progress` receives one line per
    finished load step or frame, `status` the solver's line within a step
    (None: silent): the static solvers' per Newton iteration (the one-yarn
    model's per yarn of a batch, whose Newton runs compiled), the dynamic
    ones' per launch of their kernels (at most about every half second).
    """
    if out is not None:
        run_to_file(scene, solver, out, overwrite=overwrite, resume=resume, progress=progress,
                    status=status, device=device, **options)
        return read_results(out)
    if overwrite or resume:
        raise UserError("--overwrite and --resume need an output file")
    model, engine = _build(scene, solver, None, status, device, options)
    sink = _MemorySink(_root_attrs(model, engine), _reference(model))
    _solve(model, engine, sink, progress)
    return sink.results()


def run_to_file(scene: Scene, solver: str, out: str | Path, *, overwrite: bool = False,
                resume: bool = False, progress: Callable[[str], None] | None = None,
                status: Callable[[str], None] | None = None, device: str | None = None,
                **options) -> int:
    """`run` writing `out` without reading it back: the number of steps (or frames) written.

    0 with `resume` means the file was already complete and nothing was
    written. The file holds every finished entry at any moment; an interrupt
    (KeyboardInterrupt, which the command raises for SIGTERM too) before the
    first one leaves no file behind (this run made it).
    """
    if overwrite and resume:
        raise UserError("--overwrite and --resume exclude each other: pick one")
    model, engine = _build(scene, solver, None if resume else out, status, device, options)
    sink, view = None, XdmfSync(out)
    try:
        with _interrupts_held_back():  # a Ctrl-C finds the file either not made or in `sink`
            sink = _open_sink(model, engine, out, overwrite=overwrite, resume=resume)
        if resume:
            view.finish()  # the XDMF beside it (dynfab.xdmf), up to date with the finished steps
        else:
            xdmf_path(out).unlink(missing_ok=True)  # a replaced file's view is stale
        written = _solve(model, engine, _ViewedSink(sink, view), progress)
    except KeyboardInterrupt:
        if sink is not None:
            if not resume and finished_counts(out) == (0, 0):
                Path(out).unlink(missing_ok=True)  # made by this run, still under its lock
                xdmf_path(out).unlink(missing_ok=True)
            sink.close(trim=False)
            _finish_view(view, out)
        raise
    except BaseException:
        if sink is not None:
            sink.close()  # a solver failure: the finished steps, trimmed
            _finish_view(view, out)
        raise
    sink.close()
    view.finish()  # the trimmed file's dataset sizes
    return written


def _finish_view(view: XdmfSync, out) -> None:
    """Bring the XDMF file up to date after a failure or an interrupt, without masking it."""
    if Path(out).exists():
        with contextlib.suppress(DynfabError, OSError):
            view.finish()


class _ViewedSink:
    """A result file whose XDMF view (`dynfab.xdmf.XdmfSync`) follows every appended entry."""

    def __init__(self, sink: ResultFile, view: XdmfSync) -> None:
        self.sink, self.view = sink, view

    def __getattr__(self, name: str):
        return getattr(self.sink, name)

    def append_step(self, record: dict) -> None:
        self.sink.append_step(record)
        self.view.update()

    def append_frame(self, frame: dict) -> None:
        self.sink.append_frame(frame)
        self.view.update()


@contextlib.contextmanager
def _interrupts_held_back():
    """Hold Ctrl-C (SIGINT) and SIGTERM back while the block runs; they take effect right
    after.

    A Python-level handler, not a signal mask: the mask is per thread, and a
    process-directed signal goes to any thread not masking it (numba's, Warp's).
    """
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    caught = []
    held = (signal.SIGINT, signal.SIGTERM)
    previous = {signum: signal.signal(signum, lambda signum, frame: caught.append(signum))
                for signum in held}
    try:
        yield
    finally:
        for signum in held:
            signal.signal(signum, previous[signum])
    if caught:
        signal.raise_signal(caught[0])  # to the handler held back (KeyboardInterrupt)


def _build(scene: Scene, solver: str, out, status, device: str | None, options: dict):
    """The model and the solver, the run options set on the scene (`dynfab.options`) and the
    run's memory and result file (`out`, None: not checked) estimated first (`dynfab.budget`,
    a fabric's too);
    the solver reports within each step to `status`."""
    if scene.geometry.model == "fabric":  # docs/model.md section 10
        from dynfab.fabric.from_scene import build_run
        check_budget(scene, out)
        return build_run(scene, solver, device, options, status)
    scene = apply_run_options(scene, solver, **options)
    check_budget(scene, out)
    model = build_model(scene)
    return model, make_solver(model, solver, device, status)


def _solve(model: Model, engine: Solver | Transient, sink, progress) -> int:
    """Solve the load steps (or the transient) the sink lacks; the number of entries added."""
    if isinstance(engine, Transient):
        return _run_transient(model, engine, sink, progress)
    state = _start_state(model, sink)
    values = model.load_values
    unit = "N" if model.control == "force" else "m"
    first, floors, total = sink.step_count, [], len(values)
    attrs = model.attrs() if _is_fabric(model) else {}
    labels = attrs["yarn_labels"] if attrs else yarn_labels(model.scene)
    for index in range(first, total):
        started = time.perf_counter()
        load = float(values[index]) if values.ndim == 1 else values[index]  # fabric: (warp, weft)
        try:
            state, record = engine.step(state, load)
            check_not_folded(record, labels)
            if _is_fabric(model):
                model.check_crossings_held(record)  # docs/model.md section 10
        except SolverError as error:
            shown = " ".join(f"{v:.6g}" for v in np.atleast_1d(load))
            raise SolverError(f"load step {index + 1}/{total} (load {shown} {unit}): "
                              f"{error}; the {index} finished steps are kept") from error
        record["wall_time"] = time.perf_counter() - started
        _add_point_data(model, record)
        sink.append_step(_like_previous(record, sink.last_step() if sink.step_count else None))
        floors.append(np.any(record["rounding_floor"]))
        if progress is not None:
            progress(_progress_line(index, total, record, unit,
                                    _step_quantities(attrs, record, unit)))
    _warn_rounding_floor(floors)
    return sink.step_count - first


def _is_fabric(model) -> bool:
    """A fabric's run (docs/model.md section 10): its model is
    `dynfab.fabric.model.FabricModel`."""
    return model.scene.geometry.model == "fabric"


def _like_previous(entry: dict, previous: dict | None) -> dict:
    """The entry without the datasets the file's previous entry lacks: a file written by an
    earlier version (without the XDMF point data, `stress` or `slip_ratio`) is continued
    with the datasets it has, since every entry of a file has the same ones."""
    if previous is None:
        return entry
    return {name: value for name, value in entry.items() if name in previous}


def _add_point_data(model: Model, entry: dict) -> None:
    """Add the nodal point data of the XDMF view (`dynfab.xdmf.nodal_point_data`) to a step
    or frame (`_like_previous` drops them where the file continued has none)."""
    if _is_fabric(model):
        entry.update(model.point_data(entry))
        return
    entry.update(nodal_point_data(np.asarray(entry["positions"]), np.asarray(entry["anchors"]),
                                  np.asarray(entry["contact_force"]),
                                  model.yarns[0].crossing_node))


def _warn_rounding_floor(floors: list) -> None:
    """One warning at the end of a run for the steps whose residual stopped falling above the
    tolerance (docs/model.md sections 5, 6); each such step also passed the accuracy check of its
    solver."""
    count = int(np.sum(floors))
    if count:
        warnings.warn(f"{count} of {len(floors)} load steps stopped at the rounding floor, above "
                      f"their tolerance (steps/rounding_floor); their error bounds are in "
                      f"steps/error_estimate", RuntimeWarning, stacklevel=3)


def frame_times(model: Model) -> np.ndarray:
    """The output times of a transient run [s]: 0, every output_interval, and the duration."""
    options = model.scene.dynamic
    return np.append(np.arange(0.0, options.duration, options.output_interval), options.duration)


def _run_transient(model: Model, engine: Transient, sink, progress) -> int:
    """A transient run (docs/model.md section 5): append every frame as it comes; resume from the
    last one."""
    resume_from = sink.last_frame() if sink.frame_count else None
    duration = model.scene.dynamic.duration
    if resume_from is not None and float(resume_from["time"]) >= duration:
        return 0
    first = sink.frame_count
    for frame in engine.advance(initial_state(model), resume_from):
        _add_point_data(model, frame)
        sink.append_frame(_like_previous(frame, sink.last_frame() if sink.frame_count else None))
        if progress is not None:
            kinetic = np.max(frame["energy/kinetic"])
            progress(f"frame {sink.frame_count}: t = {frame['time']:.6g} s of {duration:g} s  "
                     f"kinetic energy {kinetic:.4g} J")
    return sink.frame_count - first


def _open_sink(model: Model, engine: Solver | Transient, out, *, overwrite: bool,
               resume: bool) -> ResultFile:
    """The result file: created, overwritten or resumed, sized for the run's entries."""
    capacity = ({"frame_capacity": frame_times(model).size} if isinstance(engine, Transient)
                else {"step_capacity": len(model.load_values)})
    if resume:
        sink = ResultFile.resume(out, views=add_views, **capacity)
        if sink.attrs.get("scene") != scene_to_toml(model.scene):
            sink.close(trim=False)
            raise UserError(f"cannot resume '{out}': it was written from a different scene "
                             "(or with other command-line options)")
        if sink.attrs.get("solver") != engine.name:
            sink.close(trim=False)
            raise UserError(f"cannot resume '{out}': it was written by the "
                             f"{sink.attrs.get('solver')!r} solver, not {engine.name!r}")
        if not has_views(out):  # written before dynfab.views: add them now
            sink.flush()
        return sink
    return ResultFile.create(out, attrs=_root_attrs(model, engine), reference=_reference(model),
                             overwrite=overwrite, views=add_views, **capacity)


def _start_state(model: Model, sink) -> State:
    """The as-woven start, or the last finished step of a resumed file."""
    if _is_fabric(model):
        return model.state_from_step(sink.last_step()) if sink.step_count else \
            model.initial_state()
    if sink.step_count == 0:
        return initial_state(model)
    last = sink.last_step()
    return State(positions=np.array(last["positions"]), anchors=np.array(last["anchors"]),
                 dissipated=np.array(last["dissipated"]), load=np.array(last["load"]))


def _root_attrs(model: Model, engine: Solver | Transient) -> dict:
    """Root attributes of the result file (HDF5 layout in dynfab/results.py)."""
    scene = model.scene
    attrs = {"scene": scene_to_toml(scene), "scene_source": scene.text,
             "solver": engine.name, "dynfab_version": dynfab_version(),
             "title": scene.title, "load_control": model.control}
    if _is_fabric(model):
        return {**attrs, **model.attrs(), **engine.attrs()}
    attrs = {**attrs,
             "projected_length": scene.geometry.length,
             "reference_state": scene.geometry.reference, "yarn_labels": yarn_labels(scene),
             "terms": list(model.terms)}
    width = width_per_yarn(scene)
    if width is not None:
        attrs["width_per_yarn"] = width
    attrs.update(engine.attrs())
    return attrs


def _reference(model: Model) -> dict:
    if _is_fabric(model):
        return model.reference()
    return {"positions": model.stacked("rest_position"),
            "crossing_nodes": model.yarns[0].crossing_node}


def yarn_labels(scene: Scene) -> list[str]:
    """One label per simulated yarn: its sweep entry, or its index and phase s_k."""
    if scene.sweep:
        return [", ".join(f"{key}={values[i]:g}" for key, values in scene.sweep)
                for i in range(len(expand_sweep(scene)))]
    return [f"yarn {k + 1} (s={'+' if k % 2 == 0 else '-'}1)" for k in range(scene.geometry.yarns)]


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
    """What a progress line shows of a step, each quantity saying whose it is: the load and
    end displacement of the one-yarn model (the largest over its yarns when it has several);
    a fabric's loads (warp, weft) and then, in a pull-out (`attrs["pullout_warp"]`), the
    pulled warp's end displacement and pull force and the wefts' mean strain, otherwise
    both families' strain and stress (means over their loaded yarns, docs/model.md
    section 10), and its largest slip ratio (`dynfab.domain.slip_ratios`)."""
    load = np.atleast_1d(record["load"])
    if attrs.get("model") != "fabric":
        u = 1e3 * np.atleast_1d(record["end_displacement"])
        whose = f" (largest of {u.size} yarns)" if u.size > 1 else ""
        return f"load {load[0]:.6g} {unit}  end displacement {u.max():.4f} mm{whose}"
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
    return text + f"  slip {float(record['slip_ratio']):.3f} of a segment"


class _MemorySink:
    """Collects steps in memory for `run(..., out=None)`."""

    def __init__(self, attrs: dict, reference: dict):
        self.attrs, self.reference, self.steps, self.frames = attrs, reference, [], []

    @property
    def step_count(self) -> int:
        return len(self.steps)

    @property
    def frame_count(self) -> int:
        return len(self.frames)

    def append_step(self, record: dict) -> None:
        self.steps.append({k: np.asarray(v) for k, v in record.items()})

    def append_frame(self, frame: dict) -> None:
        self.frames.append({k: np.asarray(v) for k, v in frame.items()})

    def last_step(self) -> dict:
        return self.steps[-1] if self.steps else {}

    def last_frame(self) -> dict:
        return self.frames[-1] if self.frames else {}

    def results(self) -> Results:
        return Results(attrs=self.attrs, reference=self.reference, steps=_stack(self.steps),
                       frames=_stack(self.frames))


def _stack(records: list[dict]) -> dict:
    """Records of equal keys stacked along a new first axis."""
    names = records[0].keys() if records else ()
    return {name: np.stack([r[name] for r in records]) for name in names}


def print_summary(results: Results, file=sys.stdout) -> None:
    """The summary table (per step, or per frame of a transient run), then the run's summary
    (`run_summary`): its steps, solver time and final state."""
    if results.step_count == 0:
        _print_frames_summary(results, file)
    elif results.attrs.get("model") == "fabric":
        _print_fabric_summary(results, file)
    else:
        _print_yarn_summary(results, file)
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


def _print_fabric_summary(results: Results, file) -> None:
    """A fabric's table (docs/model.md section 10), each column saying whose it is: per step
    the (warp, weft) loads; in a pull-out the pulled warp's end displacement and pull force
    and the wefts' mean strain and stress, otherwise each family's strain and stress (means
    over its loaded yarns); the largest contact force and slip ratio, the residual, the time."""
    steps, attrs = results.steps, results.attrs
    unit = "N" if attrs.get("load_control") == "force" else "m"
    pulled = attrs.get("pullout_warp")
    strain, stress = _family_arrays(results, "strain"), _family_arrays(results, "stress")
    slip = np.asarray(steps.get("slip_ratio", np.full(results.step_count, np.nan)), float)
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
          f"{'slip/seg':>8} {'residual':>10} {'time [s]':>9}", file=file)
    for i in range(results.step_count):
        if pulled is not None:
            values = (f"{1e3 * steps['end_displacement'][i, k - 1]:>10.5f} "
                      f"{steps['end_force'][i, k - 1]:>10.4g} {strain[i, 1]:>10.4g} "
                      f"{stress[i, 1]:>10.4g}")
        else:
            values = (f"{strain[i, 0]:>10.4g} {strain[i, 1]:>10.4g} {stress[i, 0]:>10.4g} "
                      f"{stress[i, 1]:>10.4g}")
        print(f"{i + 1:>4} {steps['load'][i, 0]:>11.5g} {steps['load'][i, 1]:>11.5g} {values} "
              f"{steps['contact_force'][i].max():>10.4g} {slip[i]:>8.3f} "
              f"{float(steps['residual'][i]):>10.2e} {steps['wall_time'][i]:>9.3f}", file=file)
    print(f"loads in {unit}; {key}; slip/seg: the largest slip ratio of a crossing node "
          f"(docs/model.md section 10)", file=file)


def _family_arrays(results: Results, name: str) -> np.ndarray:
    """(steps, 2) a fabric's per-family `steps/<name>`; NaN where the file lacks it (a file
    written before `stress` was recorded)."""
    value = results.steps.get(name)
    return np.full((results.step_count, 2), np.nan) if value is None else np.asarray(value, float)


def run_summary(results: Results) -> list[str]:
    """The lines printed after a run's table: its load steps (or frames) and the solver time
    summed over them (`steps/wall_time`), then the last step's state, each quantity saying
    whose it is: a fabric's strains and stresses per family (means over the loaded yarns),
    a pull-out's pulled warp and its peak pull force, the largest slip ratio; the one-yarn
    model's end force and displacement per yarn (and load per unit width, with a weft)."""
    if results.step_count == 0:
        times = results.frames.get("time", [])
        return [f"{len(times)} frames to t = {float(times[-1]) if len(times) else 0.0:.6g} s"]
    steps, attrs = results.steps, results.attrs
    lines = [f"{results.step_count} load steps, {float(np.sum(steps['wall_time'])):.3f} s "
             f"in the solver"]
    if attrs.get("model") == "fabric":
        return lines + _fabric_summary(results)
    labels = attrs.get("yarn_labels") or []
    stress = steps.get("stress")
    for k in range(np.asarray(steps["end_force"]).shape[1]):
        label = labels[k] if k < len(labels) else f"yarn {k + 1}"
        line = (f"last step, yarn {k + 1} ({label}): end force {steps['end_force'][-1, k]:.6g} N, "
                f"end displacement {1e3 * steps['end_displacement'][-1, k]:.5f} mm")
        if stress is not None:
            line += f", load per unit width {stress[-1, k]:.6g} N/m"
        lines.append(line)
    return lines


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
    if "slip_ratio" in steps:
        slip = np.asarray(steps["slip_ratio"], float)
        worst = int(np.argmax(slip))
        lines.append(f"largest slip of a crossing node: {slip[worst]:.3f} of its segment, at "
                     f"step {worst + 1} (a step stops above {SLIP_LIMIT:g}: docs/model.md "
                     f"section 10)")
    return lines


def _print_frames_summary(results: Results, file) -> None:
    """A transient run's table: per frame, time, kinetic energy and largest contact force."""
    frames = results.frames
    print(f"{'frame':>5} {'time [s]':>11} {'kinetic [J]':>12} {'max R [N]':>11}", file=file)
    contact = frames.get("contact_force")
    for i, time_s in enumerate(frames.get("time", [])):
        largest = float(contact[i].max()) if contact is not None and contact[i].size else 0.0
        print(f"{i:>5} {time_s:>11.6g} {frames['energy/kinetic'][i].max():>12.4g} {largest:>11.5g}",
              file=file)
