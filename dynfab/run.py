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
from dynfab.domain import check_not_folded
from dynfab.errors import DynfabError, SolverError, UserError
from dynfab.options import apply_run_options, check_solver
from dynfab.model import Model, State, build_model, initial_state, width_per_yarn
from dynfab.results import ResultFile, Results, dynfab_version, finished_counts, read_results
from dynfab.scene import Scene, scene_to_toml, yarn_count
from dynfab.solver import Solver, Transient
from dynfab.xdmf import XdmfSync, nodal_point_data, xdmf_path

def make_solver(model: Model, solver: str, device: str | None = None,
                progress=None) -> Solver | Transient:
    """The solver object named `solver`, built for `model` (its options are the scene's): a
    `Solver` driven by load step, or for dynamic.mode = "transient" a `Transient` driven by
    time (`dynfab.solver`); the dynamic solver reports each launch to `progress`."""
    if check_solver(solver) == "static":
        if device is not None:
            raise UserError(f"--device {device}: the static solver runs on the CPU (numba); "
                             "a device is for --solver dynamic")
        from dynfab.static import StaticSolver
        return StaticSolver(model)
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
    finished load step or frame, `status` the dynamic solver's line within a
    step, once per launch (None: silent).
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
    (KeyboardInterrupt) before the first one leaves no file behind (this run
    made it).
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
    """Hold Ctrl-C (SIGINT) back while the block runs; it takes effect right after.

    A Python-level handler, not a signal mask: the mask is per thread, and a
    process-directed SIGINT goes to any thread not masking it (numba's, Warp's).
    """
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    caught = []
    previous = signal.signal(signal.SIGINT, lambda signum, frame: caught.append(signum))
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, previous)
    if caught:
        signal.raise_signal(signal.SIGINT)  # to the handler held back (KeyboardInterrupt)


def _build(scene: Scene, solver: str, out, status, device: str | None, options: dict):
    """The model and the solver, the run options set on the scene (`dynfab.options`) and the
    run's memory and result file (`out`, None: not checked) estimated first (`dynfab.budget`,
    a fabric's too);
    the dynamic solver reports its launches to `status`."""
    if scene.geometry.model == "fabric":  # docs/model.md section 10
        from dynfab.fabric.from_scene import build_run
        check_budget(scene, out)
        return build_run(scene, solver, device, options)
    scene = apply_run_options(scene, solver, **options)
    check_budget(scene, out)
    model = build_model(scene)
    return model, make_solver(model, solver, device, status)


def _solve(model: Model, engine: Solver | Transient, sink, progress) -> int:
    """Solve the load steps (or the transient) the sink lacks; the number of entries added."""
    if _is_transient(engine):
        return _run_transient(model, engine, sink, progress)
    state = _start_state(model, sink)
    values = model.load_values
    unit = "N" if model.control == "force" else "m"
    first, floors, total = sink.step_count, [], len(values)
    labels = ((lambda: model.attrs()["yarn_labels"]) if _is_fabric(model)
              else (lambda: yarn_labels(model.scene)))  # made only for a folded yarn's message
    for index in range(first, total):
        started = time.perf_counter()
        load = float(values[index]) if values.ndim == 1 else values[index]  # fabric: (warp, weft)
        try:
            state, record = engine.step(state, load)
            check_not_folded(record, labels)
        except SolverError as error:
            shown = " ".join(f"{v:.6g}" for v in np.atleast_1d(load))
            raise SolverError(f"load step {index + 1}/{total} (load {shown} {unit}): "
                              f"{error}; the {index} finished steps are kept") from error
        record["wall_time"] = time.perf_counter() - started
        _add_point_data(model, record, sink.last_step() if sink.step_count else None)
        sink.append_step(record)
        floors.append(bool(np.any(record["rounding_floor"])))
        if progress is not None:
            progress(_progress_line(index, total, record, unit, pair=values.ndim == 2))
    _warn_rounding_floor(floors)
    return sink.step_count - first


_TRANSIENT_KINDS: dict[type, bool] = {}
"""Whether each solver class met is a `Transient` (a Protocol's isinstance check costs more
than a small run's bookkeeping)."""


def _is_transient(engine: Solver | Transient) -> bool:
    """`isinstance(engine, Transient)`, looked at once per solver class: driven in time (a
    transient run) or by load step (`dynfab.solver`)."""
    kind = type(engine)
    if kind not in _TRANSIENT_KINDS:
        _TRANSIENT_KINDS[kind] = isinstance(engine, Transient)
    return _TRANSIENT_KINDS[kind]


def _is_fabric(model) -> bool:
    """A fabric's run (docs/model.md section 10): its model is
    `dynfab.fabric.from_scene.FabricModel`."""
    return model.scene.geometry.model == "fabric"


def _add_point_data(model: Model, entry: dict, previous: dict | None) -> None:
    """Add the nodal point data of the XDMF view (`dynfab.xdmf.nodal_point_data`) to a step
    or frame, unless it continues a file written without them (whose entries must match)."""
    if previous is not None and "xdmf/slip" not in previous:
        return
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
    count = sum(floors)
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
        _add_point_data(model, frame, sink.last_frame() if sink.frame_count else None)
        sink.append_frame(frame)
        if progress is not None:
            kinetic = np.max(frame["energy/kinetic"])
            progress(f"frame {sink.frame_count}: t = {frame['time']:.6g} s of {duration:g} s  "
                     f"kinetic energy {kinetic:.4g} J")
    return sink.frame_count - first


def _open_sink(model: Model, engine: Solver | Transient, out, *, overwrite: bool,
               resume: bool) -> ResultFile:
    """The result file: created, overwritten or resumed, sized for the run's entries."""
    capacity = ({"frame_capacity": frame_times(model).size} if _is_transient(engine)
                else {"step_capacity": len(model.load_values)})
    if resume:
        sink = ResultFile.resume(out, **capacity)
        if sink.attrs.get("scene") != scene_to_toml(model.scene):
            sink.close(trim=False)
            raise UserError(f"cannot resume '{out}': it was written from a different scene "
                             "(or with other command-line options)")
        if sink.attrs.get("solver") != engine.name:
            sink.close(trim=False)
            raise UserError(f"cannot resume '{out}': it was written by the "
                             f"{sink.attrs.get('solver')!r} solver, not {engine.name!r}")
        return sink
    return ResultFile.create(out, attrs=_root_attrs(model, engine), reference=_reference(model),
                             overwrite=overwrite, **capacity)


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
                for i in range(yarn_count(scene))]
    return [f"yarn {k + 1} (s={'+' if k % 2 == 0 else '-'}1)" for k in range(scene.geometry.yarns)]


def _progress_line(index: int, total: int, record: dict, unit: str, pair: bool = False) -> str:
    """One line per finished load step: load (a fabric's `pair`: warp, weft), worst residual,
    iterations, time."""
    steps = record.get("time_steps", record["iterations"])
    what = "time steps" if "time_steps" in record else "iterations"
    buckled, stable = record.get("buckled"), record.get("stable")
    note = ("  (buckled: left an unstable state)" if buckled is not None and buckled.any() else "")
    if stable is not None and not stable.all():
        note += "  (unstable: no escape lowered the energy; see steps/lowest_eigenvalue)"
    load = (f"load {record['load'][0]:.6g}, {record['load'][1]:.6g} {unit} (warp, weft)" if pair
            else f"load {record['load'][0]:.6g} {unit}")
    return (f"[{index + 1:>{len(str(total))}}/{total}] {load}  "
            f"end displacement {1e3 * record['end_displacement'].max():.4f} mm  "
            f"residual {record['residual'].max():.2e} N  {what} {int(np.max(steps))}  "
            f"{record['wall_time']:.3f} s{note}")


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
    """Records of equal keys stacked along a new first axis (as np.stack, which costs several
    times more for a few records)."""
    names = records[0].keys() if records else ()
    return {name: np.array([r[name] for r in records]) for name in names}


def print_summary(results: Results, file=sys.stdout) -> None:
    """The summary table: load, end displacement, end force, largest contact force, residual, time."""
    steps = results.steps
    if results.step_count == 0:
        _print_frames_summary(results, file)
        return
    if results.attrs.get("model") == "fabric":
        _print_fabric_summary(results, file)
        return
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
    """A fabric's table (docs/model.md section 10): per step, the (warp, weft) loads and strains,
    the mean end force per family, the largest contact force, the residual and the time."""
    steps, attrs = results.steps, results.attrs
    unit = "N" if attrs.get("load_control") == "force" else "m"
    warps = int(steps["contact_force"].shape[1])
    print(f"{'step':>4} {'warp load':>11} {'weft load':>11} {'strain wa':>10} {'strain we':>10} "
          f"{'P_wa [N]':>10} {'P_we [N]':>10} {'max R [N]':>10} {'residual':>10} "
          f"{'time [s]':>9}   (loads in {unit})", file=file)
    for i in range(results.step_count):
        force = steps["end_force"][i]
        strain = steps["strain"][i] if "strain" in steps else (np.nan, np.nan)
        print(f"{i + 1:>4} {steps['load'][i, 0]:>11.5g} {steps['load'][i, 1]:>11.5g} "
              f"{strain[0]:>10.4g} {strain[1]:>10.4g} {force[:warps].mean():>10.4g} "
              f"{force[warps:].mean():>10.4g} {steps['contact_force'][i].max():>10.4g} "
              f"{float(steps['residual'][i]):>10.2e} {steps['wall_time'][i]:>9.3f}", file=file)


def _print_frames_summary(results: Results, file) -> None:
    """A transient run's table: per frame, time, kinetic energy and largest contact force."""
    frames = results.frames
    print(f"{'frame':>5} {'time [s]':>11} {'kinetic [J]':>12} {'max R [N]':>11}", file=file)
    contact = frames.get("contact_force")
    for i, time_s in enumerate(frames.get("time", [])):
        largest = float(contact[i].max()) if contact is not None and contact[i].size else 0.0
        print(f"{i:>5} {time_s:>11.6g} {frames['energy/kinetic'][i].max():>12.4g} {largest:>11.5g}",
              file=file)
