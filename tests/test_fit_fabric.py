"""`dynfab.fitting.fit` on fabric scenes: recovery of known parameters, the forward-difference
Jacobian, fittable keys, malformed fabric curves.

The scene is the fabric example's (runs/fit_example/fabric_scene.toml: a periodic 2 x 2 cell of
8 segments per yarn, pulled 2:1 under force control); a path of it solves in ~25 ms, a fit of
two or three keys in about a second. Curves are made by dynfab itself at known parameters.
"""

from __future__ import annotations

import math
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from dynfab.errors import UserError
from dynfab.fitting.fit import FD_STEP, fit, fittable_keys, make_parameters, refined_path, with_path
from dynfab.results.measured_curve import FABRIC_MEASURABLE, curve_from_columns, read_curve
from dynfab.fitting.models import FabricFit
from dynfab.scene import Contact, Friction, load_scene, validate_scene, with_key
from test_fit_sensitivity import quarter_yarn

EXAMPLE = Path(__file__).resolve().parent.parent / "runs" / "fit_example"
TRUTH = {"warp.EA": 13.72, "weft.EA": 10.0, "contact.core_stiffness": 1e5}
"""The parameters the curves are made with (warp.EA, weft.EA as runs/fit_example/make_curve.py)."""
START = {"warp.EA": 10.0, "weft.EA": 14.0, "contact.core_stiffness": 2e5}
WARP = np.linspace(0.05, 0.5, 8)
COLUMNS = ("warp_strain", "weft_strain", "warp_crimp", "weft_crimp")


def cell():
    """The example's cell at TRUTH, with a [contact] table (k_c given, so that it can be
    fitted)."""
    scene = load_scene(EXAMPLE / "fabric_scene.toml")
    scene = validate_scene(replace(scene, contact=Contact(core_stiffness=TRUTH[
        "contact.core_stiffness"])))
    for key in ("warp.EA", "weft.EA"):
        scene = with_key(scene, key, TRUTH[key])
    return scene


def synthetic(scene, warp, weft, names=COLUMNS, noise=0.0, seed=0):
    """The scene's own curve along (warp, weft) loads (weft None: no weft column), plus
    Gaussian noise of `noise` x each column's largest |value|."""
    path = np.column_stack([warp, np.zeros_like(warp) if weft is None else weft])
    curves = FabricFit.solve(with_path(scene, path, weft is not None), names).observables
    rng = np.random.default_rng(seed)
    measured = [curves[n] + noise * np.abs(curves[n]).max() * rng.normal(size=warp.size)
                for n in names]
    header = ["load [N]"] + ([] if weft is None else ["weft_load [N]"])
    header += [f"{n} [{FABRIC_MEASURABLE[n].unit}]" for n in names]
    loads = [warp] + ([] if weft is None else [weft])
    return curve_from_columns(header, np.c_[tuple(loads + measured)], "force", model="fabric")


def test_noise_free_curve_gives_back_its_parameters_from_a_wrong_start():
    """Three keys (both yarns' EA and the core stiffness, whose effect on the curve is ~1e-3 of
    the EAs') from a start 30 to 100 % off. The truth is the zero-residual minimum. The
    optimiser (scipy's least_squares, default xtol = 1e-8) stops once a step in theta = log p
    is below xtol (xtol + |theta|), |theta| ~ 12 here: the error left is of the order of
    the last steps, so 10 x that bound. (The curve's solver noise, residual rms ~1e-12, moves
    the weakest key, k_c, by ~1e-12 / (its sensitivity ~3e-6 per unit log p) ~ 3e-7 of that, below it.)
    A wrong Jacobian that still descends would stop elsewhere or not converge."""
    scene = cell()
    data = synthetic(scene, WARP, 0.5 * WARP)
    result = fit(scene, data, list(TRUTH), start=START)
    assert result.converged and result.identifiable, result.warnings
    theta = np.log(list(TRUTH.values()))
    tolerance = 10 * 1e-8 * (1e-8 + np.linalg.norm(theta))
    for key, truth in TRUTH.items():
        assert abs(math.log(result.parameters[key]["value"] / truth)) <= tolerance, key
    assert result.jacobian == "finite-difference"
    assert result.warnings[0].startswith("finite-difference Jacobian")


def test_noisy_example_curve_holds_the_truth_in_its_intervals():
    """The example's curve (make_curve.py: warp.EA = 13.72 N, weft.EA = 10 N, noise 0.2 % of
    each column's range, seed 2026) fitted from EA 10 and 14: both 95 % intervals hold the
    truth (each with probability 0.95 for a random seed; this seed is the example's)."""
    scene = load_scene(EXAMPLE / "fabric_scene.toml")
    result = fit(scene, EXAMPLE / "fabric_curve.csv", ["warp.EA", "weft.EA"])
    assert result.converged and result.identifiable, result.warnings
    for key in ("warp.EA", "weft.EA"):
        lo, hi = result.parameters[key]["ci95"]
        assert lo <= TRUTH[key] <= hi, (key, lo, hi)
    assert result.dof == 4 * 10 - 2


def test_example_fabric_curve_is_the_documented_one():
    """fabric_curve.csv comes from make_curve.py: the noise-free curve at the truth lies
    within 5 sigma (0.2 % of each column's range) of every point."""
    data = read_curve(EXAMPLE / "fabric_curve.csv", "force", "fabric")
    scene = load_scene(EXAMPLE / "fabric_scene.toml")
    scene = with_key(with_key(scene, "warp.EA", 13.72), "weft.EA", 10.0)
    curves = FabricFit.solve(with_path(scene, data.path), list(data.measured)).observables
    for name, measured in data.measured.items():
        sigma = 2e-3 * np.abs(curves[name]).max()
        assert np.abs(curves[name] - measured).max() < 5 * sigma, name


def test_forward_difference_jacobian_matches_central_differences():
    """The fit's Jacobian (forward differences, FD_STEP in the fitted coordinates) against a
    central difference of the same residual function at steps 1e-4 and 5e-5 (Richardson: the
    error of the finer is below |c(h) - c(h/2)|). The forward difference's own error is its
    truncation FD_STEP/2 |r''| (r'' from the second difference at step 1e-4) plus the
    solves' noise over its step (Newton stops at a residual of 1e-11 N, not at the exact
    equilibrium): the second difference at FD_STEP itself, whose truncation FD_STEP^2 |r''|
    is nil, measures it. Keys: both EAs, k_c (the smallest column, where the noise shows)
    and Kawabata's K of the warps (through the nonlinear contact law)."""
    from dynfab.fitting.fit import _Problem

    scene = cell()
    data = synthetic(scene, WARP, 0.5 * WARP)
    data = replace(data, measured={n: 1.01 * v for n, v in data.measured.items()})
    keys = [*TRUTH, "warp.kawabata_K"]
    parameters = make_parameters(scene, keys)
    path, index = refined_path(data.path, 1)
    problem = _Problem(with_path(scene, path), data, parameters, index, None)
    theta = np.array([p.to_theta(p.start) for p in parameters])
    jac = problem.jacobian(theta)
    r0 = problem.residuals(theta)
    for k in range(theta.size):
        def at(h):
            step = np.zeros_like(theta)
            step[k] = h
            return problem.evaluate(theta + step)[1]
        plus, minus, plus2, minus2 = at(1e-4), at(-1e-4), at(5e-5), at(-5e-5)
        coarse, fine = (plus - minus) / 2e-4, (plus2 - minus2) / 1e-4
        second = np.abs(plus - 2 * r0 + minus).max() / 1e-8
        noise = np.abs(at(FD_STEP) - 2 * r0 + at(-FD_STEP)).max() / FD_STEP
        bound = np.abs(coarse - fine).max() + FD_STEP / 2 * second + noise
        assert np.abs(jac[:, k] - fine).max() <= 2 * bound, keys[k]
        assert np.abs(fine).max() > 10 * bound, keys[k]  # the check sees the column


def test_a_curve_without_weft_column_loads_the_wefts_with_zero():
    """Uniaxial: no weft column, the wefts' load 0 at every step (the scene's default without
    load.weft_values); the free wefts contract (weft_strain < 0) and the fit recovers the warps'
    EA from it. The fitted scene has no weft_values."""
    scene = cell()
    data = synthetic(scene, WARP, None, ("warp_strain", "weft_strain"))
    assert data.weft_load is None and (data.path[:, 1] == 0).all()
    assert (data.measured["weft_strain"] < 0).all()
    result = fit(scene, data, ["warp.EA"], start={"warp.EA": 12.0})
    assert result.scene.load.weft_values is None
    assert abs(math.log(result.parameters["warp.EA"]["value"] / TRUTH["warp.EA"])) <= 1e-7


def test_a_weft_only_path_is_a_path():
    """A warp column at 0 throughout with the weft moving is a load path (a weft test)."""
    data = curve_from_columns(["load [N]", "weft_load [N]", "weft_strain [-]"],
                              [[0.0, 0.1, 1e-3], [0.0, 0.2, 2e-3]], "force", model="fabric")
    assert data.path.tolist() == [[0.0, 0.1], [0.0, 0.2]]


def test_refined_path_cuts_both_columns_in_proportion():
    path, index = refined_path(np.array([[1.0, 0.5], [2.0, 0.5], [4.0, 1.5]]), 2)
    assert np.allclose(path, [[0.5, 0.25], [1.0, 0.5], [1.5, 0.5], [2.0, 0.5], [3.0, 1.0],
                              [4.0, 1.5]])
    assert (index == [1, 3, 5]).all()


# --------------------------------------------------------------------------
# Keys.


def test_fabric_keys_are_fittable():
    """The real keys of [warp], [weft], [friction], [contact] (and [gravity]) a fabric takes,
    fabric-only ones included; integers, geometry, load and one-yarn keys not."""
    scene = validate_scene(replace(cell(), friction=Friction(
        alpha=0.2, beta=1e3, contact_length=2e-3, fiber_radius=1e-3)))
    keys = fittable_keys(scene)
    for key in ("warp.EA", "weft.EA", "weft.kawabata_K", "contact.core_stiffness",
                "friction.alpha", "friction.stick_stiffness"):
        assert key in keys
    for key in ("weft.tension", "weft.count", "weft.segments", "geometry.amplitude",
                "load.values", "gravity.g"):
        assert key not in keys
    for key in ("weft.segments", "weft.tension", "geometry.length"):
        with pytest.raises(UserError, match="cannot be fitted"):
            make_parameters(scene, [key])
    with pytest.raises(UserError, match="gravity"):
        make_parameters(scene, ["weft.linear_density"])


def test_keys_left_to_their_defaults_start_from_what_the_fabric_runs():
    """k_c and k_t left out: the fit starts from the structure's values (1e5 N/m; the smaller
    family's EA / segment length)."""
    scene = validate_scene(replace(load_scene(EXAMPLE / "fabric_scene.toml"),
                                   contact=Contact(), friction=Friction(
                                       alpha=0.2, beta=1e3, contact_length=2e-3,
                                       fiber_radius=1e-3)))
    core, stick = make_parameters(scene, ["contact.core_stiffness", "friction.stick_stiffness"])
    assert core.start == 1e5
    warp, weft = scene.warp.EA * 8 / scene.geometry.length, scene.weft.EA * 8 / scene.weft.length
    assert stick.start == pytest.approx(min(warp, weft), rel=1e-15)


def test_exact_jacobian_is_refused_for_a_fabric():
    scene = load_scene(EXAMPLE / "fabric_scene.toml")
    with pytest.raises(UserError) as error:
        fit(scene, EXAMPLE / "fabric_curve.csv", ["warp.EA"], jacobian="exact")
    assert "one-yarn model only" in str(error.value) and "\n" not in str(error.value)


# --------------------------------------------------------------------------
# Malformed fabric curves: one UserError of one line each, naming the column.

ROWS = [[0.1, 0.05, 1e-3, 2e-3], [0.2, 0.1, 2e-3, 3e-3], [0.3, 0.15, 3e-3, 4e-3]]
BAD = {
    # case: (control, header, rows, words the message must hold)
    "weft load of the other control": (
        "force", ["load [N]", "weft_end_displacement [m]", "warp_strain [-]", "weft_strain [-]"],
        ROWS, ["'weft_end_displacement [m]'", "'weft_load [N]'"]),
    "weft load not second": (
        "force", ["load [N]", "warp_strain [-]", "weft_load [N]", "weft_strain [-]"], ROWS,
        ["'weft_load [N]'", "second column"]),
    "weft load in kN": (
        "force", ["load [N]", "weft_load [kN]", "warp_strain [-]", "weft_strain [-]"], ROWS,
        ["'weft_load [kN]'", "[N]"]),
    "strain under displacement control": (
        "displacement", ["end_displacement [m]", "weft_end_displacement [m]", "warp_strain [-]",
                         "warp_crimp [-]"], [[r[0] * 1e-3, r[1] * 1e-3, *r[2:]] for r in ROWS],
        ["'warp_strain [-]'", "prescribed"]),
    "stress under force control": (
        "force", ["load [N]", "weft_load [N]", "warp_stress [N/m]", "warp_crimp [-]"], ROWS,
        ["'warp_stress [N/m]'", "prescribed"]),
    "stress in N": (
        "displacement", ["end_displacement [m]", "warp_stress [N]"], [[1e-4, 1.0], [2e-4, 2.0]],
        ["'warp_stress [N]'", "[N/m]"]),
    "weft column turns back": (
        "force", ["load [N]", "weft_load [N]", "warp_strain [-]", "weft_strain [-]"],
        [ROWS[0], ROWS[1], [0.3, 0.04, 3e-3, 4e-3]], ["'weft_load [N]'", "row 4"]),
    "row repeats the load": (
        "force", ["load [N]", "weft_load [N]", "warp_strain [-]", "weft_strain [-]"],
        [ROWS[0], ROWS[1], ROWS[1]], ["row 4", "repeats"]),
    "a one-yarn column": (
        "force", ["load [N]", "weft_load [N]", "end_displacement [m]", "warp_crimp [-]"], ROWS,
        ["'end_displacement [m]'", "one-yarn model", "woven fabric"]),
    "the one-yarn crimp": (
        "force", ["load [N]", "weft_load [N]", "crimp [-]", "warp_crimp [-]"], ROWS,
        ["'crimp [-]'", "one-yarn model"]),
    "unknown column": (
        "force", ["load [N]", "weft_load [N]", "shear_angle [-]", "warp_crimp [-]"], ROWS,
        ["'shear_angle [-]'", "warp_strain"]),
    "sigma in the wrong unit": (
        "force", ["load [N]", "weft_load [N]", "warp_strain [-]", "warp_strain sigma [m]"], ROWS,
        ["'warp_strain sigma [m]'"]),
    "weft load first": (
        "force", ["weft_load [N]", "load [N]", "warp_strain [-]", "weft_strain [-]"], ROWS,
        ["'load [N]'", "first column"]),
}


@pytest.mark.parametrize("case", BAD)
def test_bad_fabric_curve_is_one_line_naming_the_column(case):
    control, header, rows, words = BAD[case]
    with pytest.raises(UserError) as error:
        curve_from_columns(header, rows, control, "curve.csv", model="fabric")
    message = str(error.value)
    assert "\n" not in message
    for word in words:
        assert word in message, (word, message)


@pytest.mark.parametrize("header, words", [
    (["load [N]", "warp_strain [-]"], ["'warp_strain [-]'", "woven fabric", "one-yarn model"]),
    (["load [N]", "weft_load [N]", "end_displacement [m]"], ["'weft_load [N]'", "woven fabric",
                                                              "one-yarn model"]),
])
def test_fabric_columns_for_a_one_yarn_scene_are_refused(header, words):
    rows = [[0.1] * len(header), [0.2] * len(header)]
    with pytest.raises(UserError) as error:
        curve_from_columns(header, rows, "force", "curve.csv", model="yarn")
    message = str(error.value)
    assert "\n" not in message and all(word in message for word in words), message


def test_a_curve_of_one_model_for_a_scene_of_the_other_is_refused():
    fabric_data = read_curve(EXAMPLE / "fabric_curve.csv", "force", "fabric")
    yarn = quarter_yarn("force", WARP)
    with pytest.raises(UserError, match="woven fabric.*one-yarn model"):
        fit(yarn, fabric_data, ["warp.EA"])
    with pytest.raises(UserError, match="weft_load"):  # the file read for the yarn's columns
        fit(yarn, EXAMPLE / "fabric_curve.csv", ["warp.EA"])
    yarn_data = curve_from_columns(["load [N]", "end_displacement [m]"],
                                   [[0.1, 1e-4], [0.2, 2e-4], [0.3, 3e-4]], "force")
    with pytest.raises(UserError, match="one-yarn model.*woven fabric"):
        fit(load_scene(EXAMPLE / "fabric_scene.toml"), yarn_data, ["warp.EA"])


def test_a_clamped_patch_curve_gives_back_its_warp_ea():
    """A clamped 2 x 2 patch of the paper's yarns ("affine" planes, 8 segments per half-wave)
    fitted the same way: its own noise-free curve (warp strain and crimp, warps pulled 2:1
    against the wefts) at warp.EA = 13.72 N gives back warp.EA from 10 N, to 10 x the
    optimiser's step tolerance as in `test_noise_free_curve_gives_back_its_parameters_from_a_wrong_start`."""
    from dynfab.reports.fabric_data import paper_patch_scene

    scene = paper_patch_scene(2, 2, planes="affine",
                              load={"control": "force", "values": [0.1], "weft_values": [0.05]})
    assert scene.geometry.boundary == "clamped"
    warp = np.linspace(0.05, 0.3, 6)
    data = synthetic(scene, warp, 0.5 * warp, names=("warp_strain", "warp_crimp"))
    result = fit(scene, data, ["warp.EA"], start={"warp.EA": 10.0})
    assert result.converged and result.jacobian == "finite-difference"
    truth = scene.warp.EA
    tolerance = 10 * 1e-8 * (1e-8 + abs(math.log(truth)))
    assert abs(math.log(result.parameters["warp.EA"]["value"] / truth)) <= tolerance
