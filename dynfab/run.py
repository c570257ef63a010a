"""Running a scene's load path with a solver, writing each finished step at once.

`run(scene, solver=...)` is the Python API behind `dynfab run`: it builds the
model, solves the load steps in order from the as-woven state (or from the
last step of the file with `resume=True`), appends every finished step to the
crash-safe result file, and returns the same arrays as `read_results` would.
A solver failure keeps every finished step on disk and re-raises the
`SolverError` with the load step named. Solvers are driven through their
contracts (`dynfab.solvers.contract`): `Solver.step` per load value, or `Transient.advance`
for a transient run.
"""

from __future__ import annotations

import contextlib
import signal
import threading
import time
import warnings
from pathlib import Path
from typing import Callable

import numpy as np

from dynfab.budget import check_budget
from dynfab.compiling import compile_seconds, start_clock
from dynfab.errors import DynfabError, SolverError, UserError
from dynfab.options import apply_run_options
from dynfab.model.builders import build_model
from dynfab.results.file import ResultFile, Results, dynfab_version, finished_counts, read_results
from dynfab.scene import Scene, scene_to_toml
from dynfab.solvers.contract import RunModel, Solver, Transient
from dynfab.solvers.by_name import make_solver
from dynfab.results.summary import step_line
from dynfab.results.views import add_views
from dynfab.results.xdmf import XdmfSync, has_views, xdmf_path

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
            view.finish()  # the XDMF beside it (dynfab.results.xdmf), up to date with the finished
                           # steps
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
    except BaseException as error:
        if sink is not None:
            if isinstance(error, SolverError):
                sink.set_attrs(**stop_attrs(error, sink))
            sink.close()  # a solver failure: the finished steps, trimmed (and the stop)
            _finish_view(view, out)
        raise
    sink.close()
    view.finish()  # the trimmed file's dataset sizes
    return written


STOP_ATTRS = ("stop_message", "stop_step", "stop_exit_status")
"""The root attributes of a run that a solver failure stopped: its one-line message, the
1-based entry (load step, or frame of a transient) it stopped at, and its exit status."""


def stop_attrs(error: SolverError, sink) -> dict:
    """`STOP_ATTRS` of a run stopped by `error` after the entries `sink` holds."""
    entries = sink.frame_count if sink.step_count == 0 and sink.frame_count else sink.step_count
    return dict(zip(STOP_ATTRS, (str(error), int(entries) + 1, int(error.exit_status))))


def _finish_view(view: XdmfSync, out) -> None:
    """Bring the XDMF file up to date after a failure or an interrupt, without masking it."""
    if Path(out).exists():
        with contextlib.suppress(DynfabError, OSError):
            view.finish()


class _ViewedSink:
    """A result file whose XDMF view (`dynfab.results.xdmf.XdmfSync`) follows every appended
    entry."""

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
    run's memory and result file (`out`, None: not checked) estimated first (`dynfab.budget`);
    the solver reports within each step to `status`."""
    scene = apply_run_options(scene, solver, **options)
    check_budget(scene, out)
    model = build_model(scene)
    return model, make_solver(model, solver, device, status)


def _solve(model: RunModel, engine: Solver | Transient, sink, progress) -> int:
    """Solve the load steps (or the transient) the sink lacks; the number of entries added."""
    if _is_transient(engine):
        return _run_transient(model, engine, sink, progress)
    state = _start_state(model, sink)
    unit = "N" if model.control == "force" else "m"
    first, floors, total = sink.step_count, [], len(model.load_values)
    attrs = model.attrs() if progress is not None else {}  # the progress line's only
    start_clock()  # a step's compile_time: what it spent compiling (a first run's)
    for index in range(first, total):
        started, compiled = time.perf_counter(), compile_seconds()
        load = model.step_load(index)
        try:
            state, record = engine.step(state, load)
            model.check_step(record)  # the model's domain (docs/model.md, section 10)
        except SolverError as error:
            shown = " ".join(f"{v:.6g}" for v in np.atleast_1d(load))
            raise SolverError(f"load step {index + 1}/{total} (load {shown} {unit}): "
                              f"{error}; the {index} finished steps are kept") from error
        record["wall_time"] = time.perf_counter() - started
        record["compile_time"] = compile_seconds() - compiled
        _add_point_data(model, record)
        sink.append_step(_like_previous(record, sink.last_step() if sink.step_count else None))
        floors.append(bool(np.any(record["rounding_floor"])))
        if progress is not None:
            progress(step_line(index, total, record, attrs, unit))
    _warn_rounding_floor(floors)
    return sink.step_count - first


def _like_previous(entry: dict, previous: dict | None) -> dict:
    """The entry without the datasets the file's previous entry lacks: a file written by an
    earlier version (without the XDMF point data, `stress` or `slip_ratio`) is continued
    with the datasets it has, since every entry of a file has the same ones."""
    if previous is None:
        return entry
    return {name: value for name, value in entry.items() if name in previous}


_TRANSIENT_KINDS: dict[type, bool] = {}
"""Whether each solver class met is a `Transient` (a Protocol's isinstance check costs more
than a small run's bookkeeping)."""


def _is_transient(engine: Solver | Transient) -> bool:
    """`isinstance(engine, Transient)`, looked at once per solver class: driven in time (a
    transient run) or by load step (`dynfab.solvers.contract`)."""
    kind = type(engine)
    if kind not in _TRANSIENT_KINDS:
        _TRANSIENT_KINDS[kind] = isinstance(engine, Transient)
    return _TRANSIENT_KINDS[kind]


def _add_point_data(model: RunModel, entry: dict) -> None:
    """Add the nodal point data of the XDMF view (`RunModel.point_data`) to a step or frame
    (`_like_previous` drops them where the file continued has none)."""
    entry.update(model.point_data(entry))


def _warn_rounding_floor(floors: list) -> None:
    """One warning at the end of a run for the steps whose residual stopped falling above the
    tolerance (docs/model.md sections 5, 6); each such step also passed the accuracy check of its
    solver."""
    count = sum(floors)
    if count:
        warnings.warn(f"{count} of {len(floors)} load steps stopped at the rounding floor, above "
                      f"their tolerance (steps/rounding_floor); their error bounds are in "
                      f"steps/error_estimate", RuntimeWarning, stacklevel=3)


def frame_times(model: RunModel) -> np.ndarray:
    """The output times of a transient run [s]: 0, every output_interval, and the duration."""
    options = model.scene.dynamic
    return np.append(np.arange(0.0, options.duration, options.output_interval), options.duration)


def _run_transient(model: RunModel, engine: Transient, sink, progress) -> int:
    """A transient run (docs/model.md section 5): append every frame as it comes; resume from the
    last one."""
    resume_from = sink.last_frame() if sink.frame_count else None
    duration = model.scene.dynamic.duration
    if resume_from is not None and float(resume_from["time"]) >= duration:
        return 0
    first = sink.frame_count
    for frame in engine.advance(model.initial_state(), resume_from):
        _add_point_data(model, frame)
        sink.append_frame(_like_previous(frame, sink.last_frame() if sink.frame_count else None))
        if progress is not None:
            kinetic = np.max(frame["energy/kinetic"])
            progress(f"frame {sink.frame_count}: t = {frame['time']:.6g} s of {duration:g} s  "
                     f"kinetic energy {kinetic:.4g} J")
    return sink.frame_count - first


def _open_sink(model: RunModel, engine: Solver | Transient, out, *, overwrite: bool,
               resume: bool) -> ResultFile:
    """The result file: created, overwritten or resumed, sized for the run's entries."""
    capacity = ({"frame_capacity": frame_times(model).size} if _is_transient(engine)
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
        if STOP_ATTRS[0] in sink.attrs:
            sink.close(trim=False)
            raise SolverError(f"'{out}' stopped at entry {sink.attrs['stop_step']} when it "
                              f"was run: {sink.attrs['stop_message']}; resuming the same scene "
                              "would stop there again: change the scene (or the run options) "
                              "and run it with --overwrite")
        if not has_views(out):  # written before dynfab.results.views: add them now
            sink.flush()
        return sink
    return ResultFile.create(out, attrs=_root_attrs(model, engine), reference=_reference(model),
                             overwrite=overwrite, views=add_views, **capacity)


def _start_state(model: RunModel, sink):
    """The as-woven start, or the last finished step of a resumed file (with the columns of
    every finished step a model names in `history_keys`: a specimen's path of clamp forces)."""
    if not sink.step_count:
        return model.initial_state()
    return model.state_from_step(sink.last_step(),
                                 {name: sink.step_column(name) for name in model.history_keys})


def _root_attrs(model: RunModel, engine: Solver | Transient) -> dict:
    """Root attributes of the result file (HDF5 layout in dynfab/results/file.py): the run's, the
    model's (`RunModel.attrs`) and the solver's."""
    scene = model.scene
    attrs = {"scene": scene_to_toml(scene), "scene_source": scene.text,
             "solver": engine.name, "dynfab_version": dynfab_version(),
             "title": scene.title, "load_control": model.control}
    return {**attrs, **model.attrs(), **engine.attrs()}


def _reference(model: RunModel) -> dict:
    return model.reference()


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


