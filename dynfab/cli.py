"""The `dynfab` command line: `dynfab run`, `dynfab plot` and `dynfab fit`.

A user's mistake exits with status 2 and one line; a solver failure with
status 3 and one line (finished steps kept on disk); an interrupt with 130
(finished steps kept, `--resume` continues).
"""

from __future__ import annotations

import argparse
import sys
import warnings
from pathlib import Path

from dynfab.errors import DynfabError

RUN_FLAGS = {
    # flag: (type, help); each is an option of dynfab.options (the same for dynfab.run)
    "--tolerance": (float, "force residual to reach [N] (static or dynamic)"),
    "--accuracy": (float, "largest accepted position error bound of a step, relative to its "
                          "largest displacement (static or dynamic)"),
    "--max-iterations": (int, "static solver: Newton iterations per load step"),
    "--mode": (str, "dynamic solver: quasi_static or transient"),
    "--method": (str, "dynamic solver: explicit or semi_implicit"),
    "--damping": (str, "dynamic solver: kinetic, viscous or fire"),
    "--damping-coefficient": (float, "dynamic solver: viscous c [1/s]"),
    "--masses": (str, "dynamic solver: fictitious or physical"),
    "--dt": (float, "dynamic solver: time step [s]"),
    "--safety": (float, "dynamic solver: fraction of the predicted stable time step"),
    "--max-steps": (int, "dynamic solver: time steps allowed per load step"),
    "--precision": (str, "dynamic solver: float64 or float32"),
}


def _parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="dynfab", description=__doc__.splitlines()[0])
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
    plot = commands.add_parser("plot", help="draw the PNG figures of a result file")
    plot.add_argument("results", type=Path, help="result file (HDF5)")
    plot.add_argument("--out", type=Path, required=True, help="folder for the PNG files")
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
    return parser


def _add_fit_parser(commands) -> None:
    fit = commands.add_parser("fit", help="fit scene keys to a measured traction curve (CSV)")
    fit.add_argument("scene", type=Path, help="scene file (TOML, SI units)")
    fit.add_argument("--data", type=Path, required=True, help="curve CSV: load column first")
    fit.add_argument("--fit", required=True, help="scene keys to fit, e.g. warp.EA,warp.kawabata_K")
    fit.add_argument("--out", type=Path, required=True, help="folder for fit.json, fitted.toml, PNGs")
    fit.add_argument("--bounds", action="append", help="KEY=LOWER:UPPER (repeatable)")
    fit.add_argument("--substeps", type=int, help="load steps per data interval")
    fit.add_argument("--quiet", action="store_true", help="no progress lines")


REPORTS = {
    "precision": "error against run time of every dynamic method, against the static reference",
    "stability": "stiff and extreme cases against every method: stable time step, convergence",
    "figures": "the paper's Fig. 3a, 3b and 5, static and dynamic, with shapes and friction states",
    "convergence": "mesh, load-increment and stick-stiffness convergence of the paper scenes",
}
"""The report subcommands (dynfab/reports/<name>.py, each with run_<name>(out, quick=, progress=))."""


def _command_run(args) -> None:
    from dynfab.run import print_summary, run
    from dynfab.scene import load_scene

    scene = load_scene(args.scene)
    out = args.out or Path(args.scene.stem + ".h5")
    out.parent.mkdir(parents=True, exist_ok=True)
    report = None if args.quiet else (lambda line: print(line, file=sys.stderr, flush=True))
    options = {flag[2:].replace("-", "_"): getattr(args, flag[2:].replace("-", "_"))
               for flag in RUN_FLAGS}
    try:
        results = run(scene, solver=args.solver, out=out, overwrite=args.overwrite,
                      resume=args.resume, progress=report, device=args.device, **options)
    except KeyboardInterrupt:
        print(f"dynfab: interrupted; every finished load step is in '{out}': "
              f"continue with --resume", file=sys.stderr)
        raise SystemExit(130)
    if not args.quiet:
        print_summary(results)
        print(f"wrote {out}", file=sys.stderr)


def _command_fit(args) -> None:
    from dynfab.fit import fit, parse_bounds
    from dynfab.scene import load_scene

    report = None if args.quiet else (lambda line: print(line, file=sys.stderr, flush=True))
    result = fit(load_scene(args.scene), args.data, args.fit, bounds=parse_bounds(args.bounds),
                 substeps=args.substeps, progress=report, out=args.out)
    print(result.table())
    for name in ("fit.json", "fitted.toml", "fit_curve.png", "fit_correlation.png"):
        print(f"wrote {args.out / name}", file=sys.stderr)


def _command_plot(args) -> None:
    from dynfab.plot import plot_results

    for path in plot_results(args.results, args.out):
        print(f"wrote {path}")


def _command_report(args) -> None:
    """Run the report `args.command` (dynfab/reports/<name>.py) and list the files it wrote."""
    import importlib

    module = importlib.import_module(f"dynfab.reports.{args.command}")
    report = None if args.quiet else (lambda line: print(line, file=sys.stderr, flush=True))
    options = {"scene": args.scene} if getattr(args, "scene", None) is not None else {}
    summary = getattr(module, f"run_{args.command}")(args.out, quick=args.quick, progress=report,
                                                      **options)
    for path in summary["files"]:
        print(f"wrote {path}")
    if not args.quiet:
        print(f"{args.command} report: {summary['wall_time_s']:.1f} s", file=sys.stderr)


def _show_warning(message, category, filename, lineno, file=None, line=None) -> None:
    """Warnings (a dt above the bound, a rounding floor) as one line each, without source."""
    print(f"dynfab: warning: {message}", file=sys.stderr, flush=True)


def main(argv: list[str] | None = None) -> None:
    """Entry point of the `dynfab` console script."""
    args = _parser().parse_args(argv)
    warnings.showwarning = _show_warning
    try:
        commands = {"run": _command_run, "plot": _command_plot, "fit": _command_fit}
        commands.get(args.command, _command_report)(args)
    except DynfabError as error:
        print(f"dynfab: error: {error}", file=sys.stderr)
        raise SystemExit(error.exit_status)


if __name__ == "__main__":
    main()
