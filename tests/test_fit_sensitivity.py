"""Sensitivities of a load path (dynfab.fitting.sensitivity) against finite differences of whole
curves.

Each check re-solves the whole load path at p + h and p - h (static solver, as
a user's run) and compares the central difference with the exact sensitivity
(one banded solve per parameter and step, history carried by the anchors). It
only holds where the stick/slip and open/closed sets are the same at p and
p +- h (the curve is smooth there); every test checks that first. The
tolerance is the finite difference's own error, estimated by Richardson:
fd(h/2) has a truncation error ~ |fd(h) - fd(h/2)| / 3, and the solver's
residual (1e-11 N) enters both as noise / h, so 3 |fd(h) - fd(h/2)| bounds
the error of fd(h/2) with margin.

Scenes: the paper's yarn over a quarter of its length (L = 25 mm, 4
crossings, N = 32, prestressed; docs/model.md section 7), as in tests/test_friction.py.
"""

from __future__ import annotations

import numpy as np
import pytest

from dynfab.scene import with_key
from dynfab.fitting.sensitivity import (RELATIVE_STEP, _get_key, parameter_scale,
                                        path_sensitivities, solve_path)
from independent import PAPER_FRICTION, PAPER_WARP, PAPER_WEFT, make_scene

STEP = 1e-4
"""Whole-curve FD step, relative: truncation ~ 1e-8, solver noise 1e-11 N / (0.25 N/m x h) below."""


def quarter_yarn(control, values, friction=None):
    tables = dict(geometry={"length": 0.025, "segments": 32, "crossings": 4, "amplitude": 0.5e-3,
                            "reference": "prestressed"},
                  warp=PAPER_WARP, weft=PAPER_WEFT,
                  load={"control": control, "values": list(values)})
    if friction:
        tables["friction"] = friction
    return make_scene(**tables)


DISPLACEMENTS = np.linspace(2.5e-4, 2.5e-3, 8)
FORCES = np.linspace(0.05, 0.5, 8)
STICK_SLIP = dict(PAPER_FRICTION, beta=3e4)
"""Gralen's constant 6e-2 N: under FORCES the crossings stick first and start sliding one by one."""
ELASTIC_KEYS = ["warp.EA", "warp.kawabata_K", "weft.kawabata_C", "warp.EI"]
GEOMETRY_KEYS = ["geometry.amplitude", "weft.amplitude", "weft.EI", "weft.tension",
                 "weft.kawabata_K", "warp.kawabata_C"]
FRICTION_KEYS = ["friction.alpha", "friction.beta"]

CASES = {
    "displacement, frictionless": (quarter_yarn("displacement", DISPLACEMENTS), ELASTIC_KEYS),
    "force, frictionless": (quarter_yarn("force", FORCES), ELASTIC_KEYS + GEOMETRY_KEYS),
    "force, stick then slip": (quarter_yarn("force", FORCES, STICK_SLIP),
                               ELASTIC_KEYS + FRICTION_KEYS),
    # Unloading after sliding: crossings stick again on anchors the loading moved, so the
    # curve depends on the anchors' history (dxi/dp carried from the sliding steps).
    "force, slip then stick on unloading": (
        quarter_yarn("force", np.concatenate([FORCES, FORCES[::-1][1:5]]), STICK_SLIP),
        ELASTIC_KEYS + FRICTION_KEYS + ["friction.contact_length", "geometry.amplitude"]),
    "displacement, friction": (quarter_yarn("displacement", DISPLACEMENTS,
                                            dict(PAPER_FRICTION, beta=1e4)),
                               ELASTIC_KEYS + FRICTION_KEYS + ["friction.stick_stiffness"]),
}


def same_sets(a, b):
    """The stick/slip and open/closed sets of two solved paths agree at every step."""
    return all((x == y).all() for x, y in zip(a.sliding, b.sliding)) and \
        all((x == y).all() for x, y in zip(a.closed, b.closed))


def central_difference(scene, key, h):
    value = _get_key(scene, key)
    return (solve_path(with_key(scene, key, value + h)),
            solve_path(with_key(scene, key, value - h)))


@pytest.mark.parametrize("case", CASES)
def test_sensitivities_match_finite_differences_of_whole_curves(case):
    scene, keys = CASES[case]
    if "friction.stick_stiffness" in keys:
        scene = with_key(scene, "friction.stick_stiffness", 4000.0)
    base = solve_path(scene)
    if "stick" in case:  # the path has both: some crossings stick while others slide
        counts = [int(s.sum()) for s in base.sliding]
        assert min(counts) < 4 and max(counts) == 4, counts
    if "unloading" in case:  # a crossing that slid sticks later
        slid = np.zeros(4, bool)
        resticks = False
        for sliding in base.sliding:
            resticks |= (slid & ~sliding).any()
            slid |= sliding
        assert resticks
    exact = path_sensitivities(base, keys)
    observed = ["crimp",
                "end_force" if scene.load.control == "displacement" else "end_displacement"]
    for k, key in enumerate(keys):
        h = STEP * parameter_scale(scene, key, _get_key(scene, key))
        coarse, fine = central_difference(scene, key, h), central_difference(scene, key, h / 2)
        for solved in (*coarse, *fine):
            assert same_sets(base, solved), f"{key}: a set switches within +-h; choose other loads"
        for name in observed:
            fd_h = (coarse[0].observables[name] - coarse[1].observables[name]) / (2 * h)
            fd_half = (fine[0].observables[name] - fine[1].observables[name]) / h
            fd_error = 3 * np.abs(fd_h - fd_half).max() + 1e-12 * np.abs(fd_half).max()
            error = np.abs(exact[name][:, k] - fd_half).max()
            assert error <= fd_error, (key, name, error, fd_error, np.abs(fd_half).max())


def test_residual_difference_at_fixed_state_is_at_rounding_level():
    """The only non-analytic piece, dr/dp at fixed state by a central difference with step
    RELATIVE_STEP x |p|: its error against a step 4x smaller (Richardson) is O(h^2) + O(EPS/h),
    about 1e-10 relative -- far below the FD of whole curves above."""
    scene = quarter_yarn("force", FORCES, STICK_SLIP)
    base = solve_path(scene)
    keys = ["warp.kawabata_K", "weft.kawabata_C", "friction.alpha"]
    exact = path_sensitivities(base, keys)["end_displacement"]
    import dynfab.fitting.sensitivity as sensitivity
    original = sensitivity.RELATIVE_STEP
    try:
        sensitivity.RELATIVE_STEP = original / 4
        smaller = path_sensitivities(base, keys)["end_displacement"]
    finally:
        sensitivity.RELATIVE_STEP = original
    assert RELATIVE_STEP == original
    relative = np.abs(exact - smaller).max(axis=0) / np.abs(exact).max(axis=0)
    assert (relative < 1e-8).all(), relative
