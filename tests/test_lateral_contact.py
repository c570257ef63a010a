"""The lateral contacts' active set in the static solver (docs/model.md 11.5).

A small picture frame whose yarns are nearly as wide as their spacing (w = 4.9 mm at
p = 5.18 mm: they lock at acos(w / p) = 18.9 degrees) is sheared past the lock (Cao et al.
eq. 2: 26.6 degrees at d = 6 mm), so neighbouring yarns come into lateral contact during the
path. Each Newton solve holds every lateral contact open or closed and updates the set where
the converged state contradicts it (`SparseNewton.on_lateral_set`); what it returns must be
an equilibrium of the unilateral law itself, and the same one (within the steps' error
bounds) as the solve that takes the contacts' kink in its line search.
"""

from __future__ import annotations

import numpy as np
import pytest

from dynfab import run

from dynfab.solvers import newton_sparse
from dynfab.model.builders import build_model
from dynfab.scene import parse_scene_text
from dynfab.solvers.static import StaticSolver

YARN = """spacing = 5.18e-3
amplitude = 0.3e-3
width = 4.9e-3
EA = 2.0e4
EI = 1e-5
EI_lateral = 1e-5
kawabata_C = 0.2e-3
kawabata_K = 0.2
"""
SCENE = f"""
[geometry]
model = "fabric"
kinematics = "spatial"

[specimen]
test = "picture_frame"
side = 0.0207
segments_per_spacing = 2

[crossing]
preload = 0.1
shear_stiffness = 5e-3
torsion_radius = 2e-5

[warp]
{YARN}
[weft]
{YARN}
[static]
tolerance = 1e-9

[load]
control = "displacement"
values = [0.001, 0.002, 0.003, 0.004, 0.005, 0.006]
"""


def frame_path(status=None):
    return run(parse_scene_text(SCENE), solver="static", status=status)


@pytest.fixture(scope="module")
def held_path():
    """The path with the active set, and the solver's progress lines."""
    lines = []
    return frame_path(lines.append), lines


def test_the_frame_locks_during_the_path(held_path):
    """The scene does what the tests below need: no lateral contact presses at the first
    step, several at the last (w - d > 0)."""
    results, _ = held_path
    gaps = results.steps["lateral_gap"]
    assert not np.any(gaps[1] > 0.0)
    assert np.count_nonzero(gaps[-1] > 0.0) >= 4


def test_the_active_set_switches_contacts_and_ends_on_the_unilateral_law(held_path):
    """The sets were updated during the path (the solver's progress line says so), and every
    step's state balances the forces of the unilateral law to the tolerance, computed by a
    fresh solver that holds no set: the held sets leave no trace in the answer."""
    results, lines = held_path
    assert any("lateral contacts:" in line and "switched" in line for line in lines)
    scene = parse_scene_text(SCENE)
    backend = StaticSolver(build_model(scene)).backend
    tolerance = scene.static.tolerance
    for k in range(results.step_count):
        pos = np.ascontiguousarray(results.steps["positions"][k])
        anchors = np.ascontiguousarray(results.steps["anchors"][k])
        residual = backend.law_residual(pos, np.zeros(1), anchors)
        assert residual <= tolerance or results.steps["rounding_floor"][k], (k, residual)


def test_the_active_set_and_the_line_search_find_the_same_equilibria(held_path,
                                                                      monkeypatch):
    """With no set updates allowed the lateral contacts go to the unilateral law at once
    (its kink left to the line search): the same equilibria within the two error bounds
    (docs/model.md, "Stability and accuracy of a converged step")."""
    held, _ = held_path
    monkeypatch.setattr(newton_sparse, "LATERAL_UPDATES", 0)
    natural = frame_path()
    bound = held.steps["error_estimate"] + natural.steps["error_estimate"]
    difference = np.abs(held.steps["positions"] - natural.steps["positions"]).max(axis=(1, 2))
    assert np.all(difference <= bound), (difference, bound)
