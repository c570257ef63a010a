"""PARDISO against SuperLU on the fabric's static paths (docs/model.md section 11.10).

Where MKL is installed, the Newton solves and the certificate factor by PARDISO's L D L^T;
SuperLU otherwise (`dynfab.model.fabric.ordering.symmetric_factor`). The two factorisations give
different rounding, not different equilibria: each run's error bound
(`steps/error_estimate`) bounds |x - x*|_inf of its positions from the step's exact
equilibrium x* (to first order), so where both reach the same equilibrium
|x_pardiso - x_superlu|_inf <= bound_pardiso + bound_superlu (tests/test_shear_dynamic.py's
argument). A wrong factorisation (a solve of another matrix, a count off by one) moves the
path by far more, or stops it. Both also count the same inertia and stop where the other
does.

Scenes: the issue's 60 mm picture frame (two load steps after step 0), the 30 x 60 mm bias
specimen held by strong friction (one), both as tests/test_shear_dynamic.py takes them, and
the planar fabric's periodic cell (runs/fabric_biaxial.toml) and clamped strip
(runs/fabric_strip.toml).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from dynfab import run
from dynfab.linalg import pardiso
from dynfab.scene import load_scene, parse_scene_text
from test_shear_dynamic import CASES
from test_shear_specimens import scene_text

pytestmark = pytest.mark.skipif(
    not pardiso.available(),
    reason="MKL (PARDISO) is not installed (wheels for x86-64 Linux and Windows only)")
RUNS = Path(__file__).resolve().parents[1] / "runs"


PLANAR = {"periodic": "fabric_biaxial.toml", "clamped": "fabric_strip.toml"}


def scene_of(name: str):
    if name in PLANAR:
        return load_scene(RUNS / PLANAR[name])
    specimen, values, friction = CASES[name]
    return parse_scene_text(scene_text(specimen, values, friction))


@pytest.mark.parametrize("name", ["frame", "bias", "periodic", "clamped"])
def test_pardiso_and_superlu_paths_agree_within_the_error_bounds(name, monkeypatch):
    monkeypatch.setattr(pardiso, "MIN_UNKNOWNS", 0)  # every matrix, however small
    with_pardiso = run(scene_of(name), solver="static")
    monkeypatch.setattr(pardiso, "available", lambda: False)
    with_superlu = run(scene_of(name), solver="static")
    x_p, x_s = with_pardiso.steps["positions"], with_superlu.steps["positions"]
    assert x_p.shape == x_s.shape
    bound = with_pardiso.steps["error_estimate"] + with_superlu.steps["error_estimate"]
    assert np.all(np.isfinite(bound))
    for k in range(x_p.shape[0]):
        difference = np.abs(x_p[k] - x_s[k]).max()
        assert difference <= bound[k], (k, difference, bound[k])
    assert np.array_equal(with_pardiso.steps["negative_eigenvalues"],
                          with_superlu.steps["negative_eigenvalues"])
    moved = np.abs(x_s[-1] - x_s[0]).max()
    assert moved > 100 * bound[-1]  # the bounds are small against the motion
