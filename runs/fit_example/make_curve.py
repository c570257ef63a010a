"""Make the example's curves, stand-ins for measured ones, from known parameters plus Gaussian
noise of 0.2 % of each column's range (seed 2026). Run: python runs/fit_example/make_curve.py

- curve.csv: the end force of scene.toml (the quarter paper yarn with friction) at
  warp.EA = 13.72 N, friction.alpha = 0.2 (the paper's values), pulled to 2.5 mm in 10 points;
- fabric_curve.csv: the warp and weft strains and crimps of fabric_scene.toml (a periodic
  2 x 2 cell pulled 2:1) at warp.EA = 13.72 N, weft.EA = 10 N, the warps' load to 0.5 N in
  10 points, the wefts' half of it;
- frame_curve.csv: the clamp force of frame_scene.toml (a 30 mm picture frame of the Cao
  fabric) at crossing.preload = 0.06 N (the Cao scenes' estimate), sheared to d = 4 mm in 8
  points.
"""

from pathlib import Path

import numpy as np

from dynfab.fitting.models import FabricFit
from dynfab.scene import load_scene, with_key
from dynfab.fitting.sensitivity import solve_path

HERE = Path(__file__).parent
NOISE, SEED = 2e-3, 2026
YARN_TRUTH = {"warp.EA": 13.72, "friction.alpha": 0.2}
FABRIC_TRUTH = {"warp.EA": 13.72, "weft.EA": 10.0}
FABRIC_COLUMNS = ("warp_strain", "weft_strain", "warp_crimp", "weft_crimp")
FRAME_TRUTH = {"crossing.preload": 0.06}


def with_keys(scene, values: dict):
    for key, value in values.items():
        scene = with_key(scene, key, value)
    return scene


def noisy(curve, rng):
    return curve + rng.normal(0.0, NOISE * np.abs(curve).max(), curve.size)


def write(path, header, columns):
    lines = [",".join(header)] + [",".join(f"{v:.6e}" for v in row) for row in zip(*columns)]
    path.write_text("\n".join(lines) + "\n")


def yarn_curve():
    displacement = np.linspace(2.5e-4, 2.5e-3, 10)
    scene = with_keys(load_scene(HERE / "scene.toml"),
                      {**YARN_TRUTH, "load.values": list(displacement)})
    force = solve_path(scene).observables["end_force"]
    write(HERE / "curve.csv", ["end_displacement [m]", "end_force [N]"],
          [displacement, noisy(force, np.random.default_rng(SEED))])


def fabric_curve():
    warp = np.linspace(0.05, 0.5, 10)
    weft = 0.5 * warp
    scene = with_keys(load_scene(HERE / "fabric_scene.toml"),
                      {**FABRIC_TRUTH, "load.values": list(warp), "load.weft_values": list(weft)})
    curves = FabricFit.solve(scene, FABRIC_COLUMNS).observables
    rng = np.random.default_rng(SEED)
    write(HERE / "fabric_curve.csv",
          ["load [N]", "weft_load [N]", *(f"{name} [-]" for name in FABRIC_COLUMNS)],
          [warp, weft, *(noisy(curves[name], rng) for name in FABRIC_COLUMNS)])


def frame_curve():
    d = np.linspace(5e-4, 4e-3, 8)
    scene = with_keys(load_scene(HERE / "frame_scene.toml"), {**FRAME_TRUTH, "load.values": list(d)})
    force = FabricFit.solve(scene, ("clamp_force",)).observables["clamp_force"]
    write(HERE / "frame_curve.csv", ["end_displacement [m]", "clamp_force [N]"],
          [d, noisy(force, np.random.default_rng(SEED))])


if __name__ == "__main__":
    yarn_curve()
    fabric_curve()
    frame_curve()
