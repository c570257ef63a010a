"""The `dynfab` command line: `dynfab run`, `dynfab plot`, `dynfab fit`, `dynfab xdmf` and
`dynfab study`.

A user's mistake exits with status 2 and one line; a solver failure with
status 3 and one line (finished steps kept on disk); an interrupt (Ctrl-C,
SIGINT), at any moment, imports included, with 130 and one line naming what is
on disk. SIGTERM (`kill`, a batch system's time limit) is taken the same way,
with the word "terminated" and exit status 143 (128 + 15, what a shell reports
for a process SIGTERM ended): the finished steps are kept, a file this run made
holding none is removed.

When the process is the command (the console script, or ``python -m
dynfab.cli``), a Ctrl-C or SIGTERM during the imports ends it at once with that
line (nothing is written yet); `main` then hands both to its handler.
Its top-level imports are light, and the heavy ones (numpy, h5py, numba,
matplotlib) are made inside `main`, under that handler.

Progress (stderr, none with --quiet): a line per finished step or frame; on a
terminal a live line within a step; and, before kernels are compiled (the first
run of a scene's kernel variants; later runs load them from the caches), the
line "compiling kernels (first run only)", on a terminal or not.
"""

from __future__ import annotations

import os
import signal
import sys

from dynfab import _catch_while_starting

DESCRIPTION = ("Yarn-scale simulation of a plain-woven fabric (docs/model.md): run a scene, "
               "plot or view its results, fit its keys to a measured curve, run a study, "
               "and the reports.")
"""`dynfab --help`'s description: whole sentences (the module docstring's first line, which
it was, stopped mid-sentence)."""

if __name__ == "__main__":  # python -m dynfab.cli (the console script's is set by dynfab)
    _catch_while_starting()

import argparse  # noqa: E402 (after the handler, on purpose)
import contextlib  # noqa: E402
import importlib  # noqa: E402
import io  # noqa: E402
import shutil  # noqa: E402
import time  # noqa: E402
import warnings  # noqa: E402
from pathlib import Path  # noqa: E402

from dynfab.errors import DynfabError, SolverError, UserError  # noqa: E402

from dynfab.options import run_flags  # noqa: E402 (light: the scene schema only)

RUN_FLAGS = run_flags()
"""`dynfab run` flag -> (type, help): the run options of dynfab.options, from the scene keys."""


def _parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="dynfab", description=DESCRIPTION)
    commands = parser.add_subparsers(dest="command", required=True)
    run = commands.add_parser("run", help="solve a scene's load path and write an HDF5 result file")
    run.add_argument("scene", type=Path, help="scene file (TOML, SI units)")
    run.add_argument("--solver", choices=("static", "dynamic"), default="static")
    run.add_argument("--out", type=Path, help="result file (default: <scene name>.h5)")
    run.add_argument("--overwrite", action="store_true", help="replace an existing result file")
    run.add_argument("--resume", action="store_true", help="continue an interrupted result file")
    run.add_argument("--device", help="Warp device of the dynamic solver (cpu, the default; cuda)")
    run.add_argument("--quiet", action="store_true", help="no progress lines, no summary table")
    for flag, (kind, text) in RUN_FLAGS.items():
        run.add_argument(flag, type=kind, help=text)
    plot = commands.add_parser("plot", help="draw the PNG figures of a result file (or of a "
                                            "study's study.nc)")
    plot.add_argument("results", type=Path, help="result file (HDF5), or a study's table (.nc)")
    plot.add_argument("--out", type=Path, required=True, help="folder for the PNG files")
    plot.add_argument("--data", type=Path, default=None,
                      help="a measured curve (CSV, the columns of `dynfab fit --data`) drawn "
                           "over the computed one, labelled with its file's name")
    xdmf = commands.add_parser("xdmf", help="(re)write <result>.xdmf, the view of a result file "
                                            "for ParaView and meshio (a run writes it too)")
    xdmf.add_argument("results", type=Path, help="result file (HDF5)")
    for name, text in REPORTS.items():
        report = commands.add_parser(name, help=text)
        if name == "precision":
            report.add_argument("scene", type=Path, nargs="?",
                                help="scene file (default: the paper scene, with and without friction)")
        report.add_argument("--out", type=Path, required=True, help="folder for the report's files")
        report.add_argument("--quick", action="store_true",
                            help="a reduced scene and few settings, that runs in seconds")
        report.add_argument("--quiet", action="store_true", help="no progress lines")
    _add_fit_parser(commands)
    _add_study_parser(commands)
    return parser


def _add_study_parser(commands) -> None:
    study = commands.add_parser("study", help="run the cases of a study file (a scene, keys to "
                                              "vary, observables) on a Dask cluster; gather "
                                              "study.nc")
    study.add_argument("study", type=Path, help="study file (TOML)")
    study.add_argument("--out", type=Path, required=True,
                       help="folder for cases/*.h5 and study.nc")
    study.add_argument("--scheduler", help="address of a running Dask scheduler "
                                           "(tcp://HOST:PORT); default: a local cluster")
    study.add_argument("--workers", type=int,
                       help="worker processes of the local cluster (default: one per core)")
    study.add_argument("--resume", action="store_true",
                       help="continue a study: run only the cases whose file is not complete")
    study.add_argument("--sync", choices=("steps", "end"), default="steps",
                       help="steps (default): every finished step of a case written and synced "
                            "as it arrives; end: a case's file written once it ends")
    study.add_argument("--stream-interval", type=float, metavar="SECONDS",
                       help="with --sync steps: how soon a running case's finished steps reach "
                            "its file (default 1 s; a case that ends sooner comes back whole)")
    study.add_argument("--quiet", action="store_true", help="no live line, no summary")


def _add_fit_parser(commands) -> None:
    from dynfab.results.measured_curve import columns_help

    fit = commands.add_parser("fit", help="fit scene keys to a measured traction curve (CSV)",
                              epilog=columns_help(),
                              formatter_class=argparse.RawDescriptionHelpFormatter)
    fit.add_argument("scene", type=Path, help="scene file (TOML, SI units)")
    fit.add_argument("--data", type=Path, required=True, help="curve CSV: load column first")
    fit.add_argument("--fit", required=True, help="scene keys to fit, e.g. warp.EA,warp.kawabata_K")
    fit.add_argument("--out", type=Path, required=True, help="folder for fit.json, fitted.toml, PNGs")
    fit.add_argument("--bounds", action="append", help="KEY=LOWER:UPPER (repeatable)")
    fit.add_argument("--substeps", type=int, help="load steps per data interval")
    fit.add_argument("--starts", type=int, default=1,
                     help="fit from K starting points on a Dask cluster, keep the best")
    fit.add_argument("--scheduler", help="with --starts: a running Dask scheduler's address "
                                         "(default: a local cluster)")
    fit.add_argument("--workers", type=int, help="with --starts: the local cluster's workers")
    fit.add_argument("--quiet", action="store_true", help="no progress lines")


REPORTS = {
    "precision": "error against run time of every dynamic method, against the static reference",
    "stability": "stiff and extreme cases against every method: stable time step, convergence",
    "figures": "the paper's Fig. 3a, 3b and 5, static and dynamic, with shapes and friction states",
    "convergence": "mesh, load-increment and stick-stiffness convergence of the paper scenes",
    "fabric": "biaxial load-strain and crimp interchange of the periodic fabric cell, its shape",
}
"""The report subcommands (dynfab/reports/<name>.py, each with run_<name>(out, quick=, progress=))."""


class _Progress:
    """Progress on stderr: one line per finished step or frame, a line before kernels are
    compiled and, on a terminal only, a live status line within a step (the solver's
    Newton iterations or time steps and residual against its tolerance, and the time spent
    in the step), overwritten in place."""

    def __init__(self, stream=None) -> None:
        self.stream = sys.stderr if stream is None else stream
        self.live = self.stream.isatty()
        self.showing = False
        self.step_started = time.monotonic()

    def line(self, text: str) -> None:
        """A finished step (or frame): a line of its own."""
        self.notice(text)
        self.step_started = time.monotonic()

    def notice(self, text: str) -> None:
        """A line of its own within a step ("compiling kernels"), on a terminal or not."""
        self.clear()
        print(text, file=self.stream, flush=True)

    def status(self, text: str) -> None:
        """Within a step: replace the live line (nothing when stderr is not a terminal)."""
        if not self.live:
            return
        elapsed = time.monotonic() - self.step_started
        self.show(f"step running {elapsed:.0f} s: {text}")

    def show(self, text: str) -> None:
        """Replace the live line by `text` (nothing when stderr is not a terminal; "" clears)."""
        if not self.live:
            return
        if not text:
            self.clear()
            return
        try:
            width = os.get_terminal_size(self.stream.fileno()).columns
        except (AttributeError, OSError, ValueError, io.UnsupportedOperation):
            width = 0
        width = width or shutil.get_terminal_size().columns  # 0: a terminal of unknown size
        self.stream.write("\r" + text[:max(width - 1, 10)] + "\x1b[K")
        self.stream.flush()
        self.showing = True

    def clear(self) -> None:
        """Erase the live line, if shown, so the next line starts clean."""
        if self.showing:
            self.stream.write("\r\x1b[K")
            self.stream.flush()
            self.showing = False


_progress: _Progress | None = None
"""The running command's progress display (warnings and the interrupt line clear it)."""


def _check_run_output(out: Path, args) -> None:
    """Refuse a bad --out before any work: a directory, or an existing file without
    --overwrite or --resume; create its folder."""
    if out.is_dir():
        raise UserError(f"output file '{out}' is a directory")
    if out.exists() and not (args.overwrite or args.resume):
        raise UserError(f"output file '{out}' exists: pass --overwrite to replace it "
                         f"or --resume to continue it")
    if args.resume and not out.exists():
        raise UserError(f"result file '{out}' does not exist: nothing to resume")
    try:
        out.parent.mkdir(parents=True, exist_ok=True)
    except OSError as error:
        raise UserError(f"cannot create the folder of '{out}': {error.strerror or error}") from None


def _command_run(args, context: dict) -> None:
    global _progress
    from dynfab.scene import load_scene

    scene = load_scene(args.scene)
    out = args.out or Path(args.scene.stem + ".h5")
    _check_run_output(out, args)
    context["out"] = out
    from dynfab.run import run_to_file
    from dynfab.results.summary import print_summary
    from dynfab.results.file import read_results

    _progress = None if args.quiet else _Progress()
    options = {flag[2:].replace("-", "_"): getattr(args, flag[2:].replace("-", "_"))
               for flag in RUN_FLAGS}
    try:
        with _compiles_announced(None if args.quiet else _progress.notice):
            written = run_to_file(scene, args.solver, out, overwrite=args.overwrite,
                                  resume=args.resume,
                                  progress=None if args.quiet else _progress.line,
                                  status=None if args.quiet else _progress.status,
                                  device=args.device, **options)
    except SolverError:
        _summarise_the_finished(out, args)  # the table of what is kept, then the error line
        raise
    if args.quiet:
        return
    _progress.clear()
    if written == 0 and args.resume:
        print(f"'{out}' is already complete: nothing to do", file=sys.stderr)
        return
    print_summary(read_results(out, only=SUMMARY_DATASETS))
    print(f"wrote {out}", file=sys.stderr)


def _summarise_the_finished(out: Path, args) -> None:
    """Before a stop's error line: the summary table of the steps the file kept (none with
    --quiet, or when it kept none or was not this run's to summarise)."""
    from dynfab.results.file import finished_counts, read_results
    from dynfab.results.summary import print_summary

    if args.quiet or not out.exists():
        return
    with contextlib.suppress(DynfabError, OSError):
        if finished_counts(out) != (0, 0):
            _progress.clear()
            print_summary(read_results(out, only=SUMMARY_DATASETS))


def _compiles_announced(say):
    """`dynfab.compiling.announcing(say)`: say "compiling kernels (first run only)" before a
    compile that will really happen; nothing for `say` None (--quiet)."""
    if say is None:
        return contextlib.nullcontext()
    from dynfab.compiling import announcing

    return announcing(say)


def _stderr_line(text: str) -> None:
    print(text, file=sys.stderr, flush=True)


SUMMARY_DATASETS = ("steps/load", "steps/end_displacement", "steps/end_force",
                    "steps/contact_force", "steps/residual", "steps/wall_time",
                    "steps/compile_time", "frames/time",
                    "frames/energy/kinetic", "frames/contact_force", "frames/load",
                    "frames/clamp_force", "steps/strain",
                    "steps/stress", "steps/slip_ratio", "steps/clamp_force", "steps/shear_angle",
                    "steps/max_slope", "steps/slip", "steps/crossing_present")
"""What the summary table reads: not the positions, which may not fit in memory."""


class Terminated(KeyboardInterrupt):
    """A SIGTERM, raised where the program stands as a Ctrl-C's KeyboardInterrupt is, so that
    it takes the same way out (`dynfab.run` keeps the finished steps, removes a file this run
    made without any), ending with "terminated" and exit status 143."""


def _terminate(signum, frame) -> None:
    """SIGTERM's handler while a command runs."""
    raise Terminated


HELD_IMPORTS = {"run": ("numba",), "fit": ("numba",), "study": ("numba",)}
"""Modules a command imports with its signals held (`_import_holding_signals`): numba's C
extension turns a Ctrl-C during its import into an ImportError ("numba._devicearray failed
to import") after printing the interrupt's traceback, and it takes a third of a second
of the command's start."""


def _import_holding_signals(names) -> None:
    """Import the modules `names` with SIGINT and SIGTERM recorded, not raised, until they are
    in; then raise the last one received as its handler would have (KeyboardInterrupt,
    `Terminated`), so it takes the command's one way out."""
    received = []
    held = (signal.SIGINT, signal.SIGTERM)
    previous = {signum: signal.signal(signum, lambda signum, frame: received.append(signum))
                for signum in held}
    try:
        for name in names:
            importlib.import_module(name)
    finally:
        for signum, handler in previous.items():
            signal.signal(signum, handler)
    if received:
        raise Terminated if received[-1] == signal.SIGTERM else KeyboardInterrupt


def _interrupted_line(context: dict, word: str = "interrupted") -> str:
    """The message after Ctrl-C (`word` "terminated" after SIGTERM): what the output file
    holds, if this command writes one; nothing was written before a command began (the
    arguments still being parsed)."""
    if "study" in context:
        return _study_interrupted_line(context["study"], word)
    out = context.get("out")
    if out is None or not Path(out).is_file():
        wrote_nothing = "out" in context or not context.get("began")
        return f"dynfab: {word}; nothing was written" if wrote_nothing else f"dynfab: {word}"
    from dynfab.results.file import finished_counts

    counts = finished_counts(out) or (0, 0)
    for count, what in zip(counts, ("load step", "frame")):
        if count:
            plural = "s are" if count > 1 else " is"
            return (f"dynfab: {word}; {count} finished {what}{plural} in '{out}': "
                    f"continue with --resume")
    return f"dynfab: {word}; no finished step is in '{out}'"


def _study_interrupted_line(study: tuple, word: str) -> str:
    """After an interrupt of `dynfab study`: the cases ended in its folder."""
    from dynfab.studies.study import ended_counts

    out, plan = study
    ended, total = ended_counts(out, plan)
    return (f"dynfab: {word}; {ended} of {total} cases are finished in '{out}': "
            "continue with --resume")


def _command_study(args, context: dict) -> None:
    global _progress
    from dynfab.studies.study import study
    from dynfab.studies.file import load_study

    plan = load_study(args.study)
    _progress = None if args.quiet else _Progress()
    context["study"] = (args.out, plan)
    result = study(plan, args.out, scheduler=args.scheduler, workers=args.workers,
                   resume=args.resume, sync=args.sync, stream_interval_s=args.stream_interval,
                   progress=None if args.quiet else _progress.notice,
                   status=None if args.quiet else _progress.show)
    if args.quiet:
        return
    _progress.clear()
    print(result.summary(), file=sys.stderr)  # each failed case had its line as it ended
    print(f"wrote {result.table}", file=sys.stderr)


def _command_fit(args, context: dict) -> None:
    from dynfab.fitting.fit import fit, parse_bounds
    from dynfab.scene import load_scene

    report = None if args.quiet else _stderr_line
    options = dict(bounds=parse_bounds(args.bounds), substeps=args.substeps, progress=report,
                   out=args.out)
    with _compiles_announced(report):
        scene = load_scene(args.scene)
        if args.starts != 1 or args.scheduler is not None or args.workers is not None:
            from dynfab.fitting.starts import fit_from_starts  # Dask: imported only here

            result = fit_from_starts(scene, args.data, args.fit, starts=args.starts,
                                     scheduler=args.scheduler, workers=args.workers, **options)
        else:
            result = fit(scene, args.data, args.fit, **options)
    print(result.table())
    for name in ("fit.json", "fitted.toml", "fit_curve.png", "fit_correlation.png"):
        print(f"wrote {args.out / name}", file=sys.stderr)


def _command_plot(args, context: dict) -> None:
    from dynfab.plots.figures import plot_results

    for path in plot_results(args.results, args.out, args.data):
        print(f"wrote {path}")


def _command_xdmf(args, context: dict) -> None:
    from dynfab.results.xdmf import write_xdmf

    print(f"wrote {write_xdmf(args.results)}")


def _command_report(args, context: dict) -> None:
    """Run the report `args.command` (dynfab/reports/<name>.py) and list the files it wrote."""
    module = importlib.import_module(f"dynfab.reports.{args.command}")
    report = None if args.quiet else _stderr_line
    options = {"scene": args.scene} if getattr(args, "scene", None) is not None else {}
    with _compiles_announced(report):
        summary = getattr(module, f"run_{args.command}")(args.out, quick=args.quick,
                                                          progress=report, **options)
    for path in summary["files"]:
        print(f"wrote {path}")
    if not args.quiet:
        print(f"{args.command} report: {summary['wall_time_s']:.1f} s", file=sys.stderr)


def _show_warning(message, category, filename, lineno, file=None, line=None) -> None:
    """Warnings (a dt above the bound, a rounding floor) as one line each, without source."""
    if _progress is not None:
        _progress.clear()
    print(f"dynfab: warning: {message}", file=sys.stderr, flush=True)


def _redeliver_swallowed_interrupt(unraisable) -> None:
    """A Ctrl-C (or SIGTERM) that met a C callback (numba's compiler calls back into Python)
    is printed and dropped there ("Exception ignored ..."): deliver it again, to the code that
    runs next, so that it interrupts the run instead."""
    if issubclass(unraisable.exc_type, KeyboardInterrupt):
        import threading  # from another thread, so that it arrives once the callback is over

        signum = signal.SIGTERM if issubclass(unraisable.exc_type, Terminated) else signal.SIGINT
        threading.Timer(0.05, os.kill, (os.getpid(), signum)).start()
        return
    sys.__unraisablehook__(unraisable)


def main(argv: list[str] | None = None) -> None:
    """Entry point of the `dynfab` console script."""
    context: dict = {}
    try:  # the handlers are set inside it: a signal between the two is caught here too
        signal.signal(signal.SIGINT, signal.default_int_handler)  # Ctrl-C: KeyboardInterrupt
        signal.signal(signal.SIGTERM, _terminate)  # SIGTERM: Terminated, a KeyboardInterrupt
        sys.unraisablehook = _redeliver_swallowed_interrupt
        _main(argv, context)
    except KeyboardInterrupt as stop:
        for signum in (signal.SIGINT, signal.SIGTERM):  # a second one must not cut the message
            signal.signal(signum, signal.SIG_IGN)
        if _progress is not None:
            _progress.clear()
        terminated = isinstance(stop, Terminated)
        print(_interrupted_line(context, "terminated" if terminated else "interrupted"),
              file=sys.stderr, flush=True)
        sys.stdout.flush()
        # Not SystemExit: after a Ctrl-C during the imports, the interpreter's shutdown then
        # ended the process by SIGINT (status -2) about once in twelve tries; os._exit never.
        os._exit(128 + (signal.SIGTERM if terminated else signal.SIGINT))
    finally:
        if _is_the_command():  # done and said: a signal while Python shuts down changes nothing
            for signum in (signal.SIGINT, signal.SIGTERM):
                signal.signal(signum, signal.SIG_IGN)


def _is_the_command() -> bool:
    """True when this process is the `dynfab` command (not a program calling `main`)."""
    spec = getattr(sys.modules.get("__main__"), "__spec__", None)
    return ((spec is not None and spec.name == "dynfab.cli")
            or os.path.basename(sys.argv[0]) == "dynfab")


def _main(argv: list[str] | None, context: dict) -> None:
    """Parse and run a command; `context` records that the command began and, for a run, its
    output file once it is known."""
    args = _parser().parse_args(argv)
    if args.command == "run":
        context["out"] = None  # a run writes a file; its name is set once checked
    warnings.showwarning = _show_warning
    context["began"] = True
    _import_holding_signals(HELD_IMPORTS.get(args.command, ()))
    try:
        commands = {"run": _command_run, "plot": _command_plot, "fit": _command_fit,
                    "xdmf": _command_xdmf, "study": _command_study}
        commands.get(args.command, _command_report)(args, context)
    except DynfabError as error:
        if _progress is not None:
            _progress.clear()
        print(f"dynfab: error: {error}", file=sys.stderr)
        raise SystemExit(error.exit_status)


if __name__ == "__main__":
    main()
