"""How much the regularised friction onset (docs/model.md section 4, friction.onset_force) moves the
paper's friction results, and what the as-woven onset path costs the static solver.

Run:  python benchmarks/onset.py   (prints the figures, writes benchmarks/onset.json)

- runs/paper_fig5.toml (prestressed, displacement control, 40 steps; friction entry 0),
  static solver, with the default R_0 = 1e-5 N against the literal law (R_0 = 0):
  max over steps and yarns of |delta end force| / max |end force| and of
  |delta contact force| / max |contact force| (the paper's contact forces are 1e-3 N
  and above, where exp(-R/R_0) < 1e-40: the change should be rounding).
  runs/paper_fig3.toml has no [friction] table: the key cannot change it.
- the as-woven onset path (paper friction, as_woven, force control, 0.005 -> 0.6 N in
  400 steps) at 224 segments: wall time and Newton iterations per step.
"""

from __future__ import annotations

import json
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

from dynfab.model.yarn import initial_state
from dynfab.model.builders import build_model
from dynfab.scene import load_scene, with_key
from dynfab.solvers.static import StaticSolver

ROOT = Path(__file__).resolve().parent.parent


def traction(scene):
    """(end force (steps, yarns), contact force (steps, yarns, C), iterations (steps,))."""
    model = build_model(scene)
    solver, state = StaticSolver(model), initial_state(model)
    ends, contacts, iterations = [], [], []
    for value in model.load_values:
        state, record = solver.step(state, value)
        ends.append(record["end_force"].copy())
        contacts.append(record["contact_force"].copy())
        iterations.append(int(record["iterations"].max()))
    return np.array(ends), np.array(contacts), np.array(iterations)


def paper_change() -> dict:
    """Relative change of Fig. 5's friction curve between R_0 = 1e-5 N and R_0 = 0."""
    scene = load_scene(ROOT / "runs" / "paper_fig5.toml")
    regularised = traction(with_key(scene, "friction.onset_force", 1e-5))
    literal = traction(with_key(scene, "friction.onset_force", 0.0))
    end = np.abs(regularised[0] - literal[0]).max() / np.abs(literal[0]).max()
    contact = np.abs(regularised[1] - literal[1]).max() / np.abs(literal[1]).max()
    smallest = literal[1][literal[1] > 0].min()
    return {"scene": "runs/paper_fig5.toml", "relative_end_force_change": float(end),
            "relative_contact_force_change": float(contact),
            "smallest_closed_contact_force_N": float(smallest)}


def onset_path(segments: int = 224) -> dict:
    """The as-woven onset path at `segments`: time and iterations."""
    scene = replace(load_scene(ROOT / "runs" / "paper_fig5.toml"), sweep=())  # friction entry
    for key, value in (("geometry.reference", "as_woven"), ("geometry.segments", segments),
                       ("load.control", "force"),
                       ("load.values", [float(v) for v in np.linspace(0.005, 0.6, 400)])):
        scene = with_key(scene, key, value)
    start = time.perf_counter()
    _, _, iterations = traction(scene)
    seconds = time.perf_counter() - start
    return {"segments": segments, "steps": int(iterations.size), "seconds": seconds,
            "iterations_max": int(iterations.max()),
            "iterations_median": float(np.median(iterations)),
            "iterations_total": int(iterations.sum())}


def main() -> None:
    results = {"paper_change": paper_change(), "onset_path": onset_path()}
    print(json.dumps(results, indent=2))
    (ROOT / "benchmarks" / "onset.json").write_text(json.dumps(results, indent=2) + "\n")


if __name__ == "__main__":
    main()
