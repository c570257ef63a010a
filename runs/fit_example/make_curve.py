"""Make runs/fit_example/curve.csv: the scene's curve at warp.EA = 13.72 N, friction.alpha = 0.2
(the paper's values) with Gaussian noise of 0.2 % of the force range (seed 2026), as a stand-in
for a measured curve. Run: python runs/fit_example/make_curve.py
"""

from pathlib import Path

import numpy as np

from dynfab.scene import load_scene, with_key
from dynfab.sensitivity import solve_path

HERE = Path(__file__).parent
scene = load_scene(HERE / "scene.toml")
scene = with_key(with_key(scene, "warp.EA", 13.72), "friction.alpha", 0.2)
displacement = np.linspace(2.5e-4, 2.5e-3, 10)
scene = with_key(scene, "load.values", list(displacement))
force = solve_path(scene).observables["end_force"]
noisy = force + np.random.default_rng(2026).normal(0.0, 2e-3 * np.abs(force).max(), force.size)
lines = ["end_displacement [m],end_force [N]"]
lines += [f"{u:.6e},{f:.6e}" for u, f in zip(displacement, noisy)]
(HERE / "curve.csv").write_text("\n".join(lines) + "\n")
