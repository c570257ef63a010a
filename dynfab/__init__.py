"""dynfab: yarn-scale mass-spring simulation of a plain-woven fabric (Ben Boubaker et al. 2007).

The public surface::

    scene = dynfab.load_scene("runs/paper_fig3.toml")
    results = dynfab.run(scene, solver="static", out="fig3.h5")   # or solver="dynamic"
    results.steps["end_force"]                                  # (steps, yarns) [N]
    dynfab.read_results("fig3.h5")                              # the same arrays, from disk
    dynfab.fit(scene, "curve.csv", ["warp.EA"])                 # parameters from a measured curve
"""

from dynfab.errors import DynfabError, SceneError, SolverError
from dynfab.fit import FitResult, fit
from dynfab.model import build_model
from dynfab.plot import plot_results
from dynfab.results import Results, read_results
from dynfab.run import run
from dynfab.scene import load_scene, parse_scene_text

__version__ = "0.1.0"

__all__ = ["DynfabError", "FitResult", "Results", "SceneError", "SolverError", "build_model", "fit",
           "load_scene", "parse_scene_text", "plot_results", "read_results", "run", "__version__"]
