"""The `dynfab` command line: `dynfab run` and `dynfab plot`.

A user's mistake exits with status 2 and one line; a solver failure with
status 3 and one line (finished steps kept on disk); an interrupt with 130
(finished steps kept, `--resume` continues).
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
import warnings
from pathlib import Path

from dynfab.errors import DynfabError

DYNAMIC_OPTIONS = {
    # flag: (Dynamic field, type, help)
    "--mode": ("mode", str, "quasi_static or transient"),
    "--method": ("method", str, "explicit or semi_implicit"),
    "--damping": ("damping", str, "kinetic, viscous or fire"),
    "--damping-coefficient": ("damping_coefficient", float, "viscous c [1/s]"),
    "--masses": ("masses", str, "fictitious or physical"),
    "--dt": ("dt", float, "time step [s]"),
    "--safety": ("safety", float, "fraction of the predicted stable time step"),
    "--max-steps": ("max_steps", int, "time steps allowed per load step"),
    "--precision": ("precision", str, "float64 or float32"),
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
    run.add_argument("--tolerance", type=float, help="force residual to reach [N]")
    run.add_argument("--accuracy", type=float,
                     help="largest accepted position error bound of a step, relative to its "
                          "largest displacement (static.accuracy or dynamic.accuracy)")
    run.add_argument("--device", default="cpu", help="Warp device of the dynamic solver (cpu, cuda)")
    run.add_argument("--quiet", action="store_true", help="no progress lines, no summary table")
    for flag, (_, kind, text) in DYNAMIC_OPTIONS.items():
        run.add_argument(flag, type=kind, help=f"dynamic solver: {text}")
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
    return parser


REPORTS = {
    "precision": "error against run time of every dynamic method, against the static reference",
    "stability": "stiff and extreme cases against every method: stable time step, convergence",
    "figures": "the paper's Fig. 3a, 3b and 5, static and dynamic, with shapes and friction states",
    "convergence": "mesh, load-increment and stick-stiffness convergence of the paper scenes",
}
"""The report subcommands (dynfab/reports/<name>.py, each with run_<name>(out, quick=, progress=))."""


def _scene_with_options(args):
    """The scene file with the command-line overrides applied and re-validated."""
    from dynfab.scene import load_scene, validate_scene

    scene = load_scene(args.scene)
    overrides = {field: getattr(args, flag[2:].replace("-", "_"))
                 for flag, (field, _, _) in DYNAMIC_OPTIONS.items()}
    overrides = {k: v for k, v in overrides.items() if v is not None}
    if args.tolerance is not None:
        if args.solver == "static":
            scene = dataclasses.replace(scene, static=dataclasses.replace(scene.static,
                                                                          tolerance=args.tolerance))
        else:
            overrides["tolerance"] = args.tolerance
    if args.accuracy is not None:
        if args.solver == "static":
            scene = dataclasses.replace(scene, static=dataclasses.replace(scene.static,
                                                                          accuracy=args.accuracy))
        else:
            overrides["accuracy"] = args.accuracy
    if overrides:
        scene = dataclasses.replace(scene, dynamic=dataclasses.replace(scene.dynamic, **overrides))
    return validate_scene(scene)


def _command_run(args) -> None:
    from dynfab.run import print_summary, run

    scene = _scene_with_options(args)
    out = args.out or Path(args.scene.stem + ".h5")
    out.parent.mkdir(parents=True, exist_ok=True)
    report = None if args.quiet else (lambda line: print(line, file=sys.stderr, flush=True))
    options = {"device": args.device} if args.solver == "dynamic" else {}
    try:
        results = run(scene, solver=args.solver, out=out, overwrite=args.overwrite,
                      resume=args.resume, progress=report, **options)
    except KeyboardInterrupt:
        print(f"dynfab: interrupted; every finished load step is in '{out}': "
              f"continue with --resume", file=sys.stderr)
        raise SystemExit(130)
    if not args.quiet:
        print_summary(results)
        print(f"wrote {out}", file=sys.stderr)


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
        commands = {"run": _command_run, "plot": _command_plot}
        commands.get(args.command, _command_report)(args)
    except DynfabError as error:
        print(f"dynfab: error: {error}", file=sys.stderr)
        raise SystemExit(error.exit_status)


if __name__ == "__main__":
    main()
