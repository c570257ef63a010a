"""dynfab: yarn-scale mass-spring simulation of a plain-woven fabric (Ben Boubaker et al. 2007).

The public surface::

    scene = dynfab.load_scene("runs/paper_fig3.toml")
    results = dynfab.run(scene, solver="static", out="fig3.h5")   # or solver="dynamic"
    results.steps["end_force"]                                  # (steps, yarns) [N]
    dynfab.read_results("fig3.h5")                              # the same arrays, from disk
    dynfab.write_xdmf("fig3.h5")                                # fig3.xdmf for ParaView, meshio (a run writes it)
    dynfab.fit(scene, "curve.csv", ["warp.EA"])                 # parameters from a measured curve
    dynfab.study("study.toml", "study_out")                     # many cases on a Dask cluster

The names are imported on first use, so that `import dynfab` (and the
`dynfab` command starting up) costs no heavy import. When the process is the
`dynfab` console script, a Ctrl-C (SIGINT) from here until `dynfab.cli.main` takes
over ends it with one line and exit status 130, a SIGTERM with 143 (nothing is
written yet).
"""

import importlib
import os
import signal
import sys
import types


def _interrupted_while_starting(signum, frame) -> None:
    """SIGINT or SIGTERM while the command line starts: one line, exit status 128 + the
    signal's number (130, 143), no traceback."""
    word = b"terminated" if signum == signal.SIGTERM else b"interrupted"
    os.write(2, b"dynfab: " + word + b"; nothing was written\n")
    os._exit(128 + signum)


def _catch_while_starting() -> None:
    """Send SIGINT and SIGTERM to `_interrupted_while_starting` (the command's start)."""
    for signum in (signal.SIGINT, signal.SIGTERM):
        signal.signal(signum, _interrupted_while_starting)


def _started_as_the_command() -> bool:
    """True when this process is the `dynfab` console script. Its own command line
    (`sys.orig_argv`: the interpreter, then the script), not `sys.argv`: a worker process
    that multiprocessing spawns (a study's local cluster) keeps its parent's `sys.argv`."""
    argv = getattr(sys, "orig_argv", None) or ["", *sys.argv]
    return len(argv) > 1 and os.path.basename(argv[1]) == "dynfab"


if _started_as_the_command():
    _catch_while_starting()

from dynfab.errors import DynfabError, UserError, SolverError

__version__ = "0.1.0"

_HOMES = {"build_model": "dynfab.model.builders", "plot_results": "dynfab.plots.figures",
          "Results": "dynfab.results.file", "read_results": "dynfab.results.file",
          "run": "dynfab.run", "load_scene": "dynfab.scene", "parse_scene_text": "dynfab.scene",
          "fit": "dynfab.fitting.fit", "FitResult": "dynfab.fitting.fit",
          "write_xdmf": "dynfab.results.xdmf", "study": "dynfab.studies.study",
          "load_study": "dynfab.studies.file"}
"""Module defining each public name."""

__all__ = ["DynfabError", "FitResult", "Results", "SolverError", "UserError", "build_model",
           "fit", "load_scene", "load_study", "parse_scene_text", "plot_results", "read_results",
           "run", "study", "write_xdmf", "__version__"]


def __getattr__(name: str):
    """Import a public name from its module on first use."""
    if name not in _HOMES:
        raise AttributeError(f"module 'dynfab' has no attribute {name!r}")
    value = getattr(importlib.import_module(_HOMES[name]), name)
    globals()[name] = value
    return value


class _Package(types.ModuleType):
    """Keeps `dynfab.run` the function: importing the module of that name (`dynfab/run.py`)
    would otherwise rebind the package attribute to the module."""

    def __setattr__(self, name: str, value) -> None:
        if name == "run" and isinstance(value, types.ModuleType):
            value = getattr(value, name)
        super().__setattr__(name, value)


sys.modules[__name__].__class__ = _Package
