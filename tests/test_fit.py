"""`dynfab.fitting.fit`: recovery of known parameters, identifiability, statistics, bad data.

Curves are made by dynfab itself with known parameters plus seeded Gaussian
noise; the scenes are the quarter paper yarn of tests/test_fit_sensitivity.py
(N = 32, 4 crossings), 10 data points, so one fit costs well under 0.1 s.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from dynfab.errors import UserError
from dynfab.fitting.fit import default_substeps, fit, refined_path
from dynfab.results.measured_curve import curve_from_columns
from dynfab.scene import with_key
from dynfab.fitting.sensitivity import _get_key, solve_path
from independent import PAPER_FRICTION, PAPER_WARP, PAPER_WEFT, make_scene
from test_fit_sensitivity import quarter_yarn

FORCES = np.linspace(0.05, 0.5, 10)
DISPLACEMENTS = np.linspace(2.5e-4, 2.5e-3, 10)
SEEDS = 100


def measured_name(scene):
    return ("end_force", "N") if scene.load.control == "displacement" else ("end_displacement", "m")


def synthetic(scene, rel_noise, seed, sigma_column=False):
    """The scene's own curve + Gaussian noise of rel_noise x max |curve| (seeded)."""
    name, unit = measured_name(scene)
    curve = solve_path(scene).observables[name]
    sigma = rel_noise * np.abs(curve).max()
    noisy = curve + np.random.default_rng(seed).normal(0.0, sigma, curve.size)
    first = "load [N]" if scene.load.control == "force" else "end_displacement [m]"
    header, columns = [first, f"{name} [{unit}]"], [np.asarray(scene.load.values), noisy]
    if sigma_column:
        header.append(f"{name} sigma [{unit}]")
        columns.append(np.full(curve.size, sigma))
    return curve_from_columns(header, np.c_[tuple(columns)], scene.load.control)


RECOVERY = {
    # frictionless, force control: the warp's EA and the weft's Kawabata C
    "frictionless": (quarter_yarn("force", FORCES), ["warp.EA", "weft.kawabata_C"]),
    # friction (every crossing sliding), displacement control: Gralen's alpha and EA
    "friction": (quarter_yarn("displacement", DISPLACEMENTS, dict(PAPER_FRICTION, beta=1e4)),
                 ["friction.alpha", "warp.EA"]),
}


@pytest.mark.parametrize("case, sigma_column", [("frictionless", False), ("friction", False),
                                                ("frictionless", True)])
def test_95_percent_intervals_contain_the_truth_about_95_times_in_100(case, sigma_column):
    """Coverage of the intervals over 100 seeds (noise 0.2 % of the curve's range, where the
    linearisation holds): Binomial(100, 0.95) lies in [90, 99] with probability 0.99, so a
    count outside means miscalibrated intervals (e.g. a covariance not scaled by s^2, a
    given sigma rescaled, a wrong chain rule for log coordinates), not bad luck. (Normal
    quantiles with 8 dof would cover 91 %: inside the band, so this test cannot see that
    mistake; test_sigma_column_... pins the scaling.) Estimated noise: t intervals; sigma
    column: normal ones on the unscaled covariance. Measured: 96/94, 94/95, 95/95. Each fit
    starts 10 % off the truth."""
    scene, keys = RECOVERY[case]
    truth = {k: _get_key(scene, k) for k in keys}
    start = {k: 1.1 * v for k, v in truth.items()}
    hits = dict.fromkeys(keys, 0)
    for seed in range(SEEDS):
        result = fit(scene, synthetic(scene, 2e-3, seed, sigma_column), keys, start=start)
        assert result.converged and result.identifiable, result.warnings
        for key in keys:
            lo, hi = result.parameters[key]["ci95"]
            hits[key] += lo <= truth[key] <= hi
    for key, count in hits.items():
        assert 90 <= count <= 99, (key, count)


def test_sigma_column_fixes_the_covariance_and_estimated_noise_rescales_it():
    """With sigma given, the covariance is (J^T W J)^-1 unscaled: doubling sigma doubles the
    standard errors; without sigma, s^2 from the residuals makes them independent of it."""
    scene, keys = RECOVERY["frictionless"]
    data = synthetic(scene, 2e-3, 0, sigma_column=True)
    name = next(iter(data.measured))
    doubled = replace(data, sigma={name: 2 * data.sigma[name]})
    plain = replace(data, sigma={})
    once, twice, estimated = (fit(scene, d, keys) for d in (data, doubled, plain))
    for key in keys:
        ratio = twice.parameters[key]["standard_error"] / once.parameters[key]["standard_error"]
        assert ratio == pytest.approx(2.0, rel=1e-6)
    assert once.noise["estimated"] is False and estimated.noise["estimated"] is True
    # the same minimum, the same J: the estimated-noise errors are the sigma ones x sqrt(chi2/dof)
    chi2 = sum(((estimated.fitted[name] - data.measured[name]) / data.sigma[name]) ** 2)
    scale = np.sqrt(chi2 / estimated.dof)
    for key in keys:
        assert estimated.parameters[key]["standard_error"] == pytest.approx(
            scale * once.parameters[key]["standard_error"], rel=1e-4)


def test_kawabata_K_and_C_from_a_linear_curve_are_reported_unidentifiable():
    """As-woven yarn, K = 0.002 m/N: a_wa R ~ 1e-2 along the whole curve, so the Kawabata law is
    linear, delta ~ C a R, and the curve only sees the product K C. The fit must say so,
    naming both, and give neither an interval."""
    scene = make_scene(
        geometry={"length": 0.025, "segments": 32, "crossings": 4, "amplitude": 0.5e-3},
        warp=dict(PAPER_WARP, kawabata_K=0.002), weft=PAPER_WEFT,
        load={"control": "force", "values": list(FORCES)})
    result = fit(scene, synthetic(scene, 2e-3, 1), ["warp.kawabata_K", "warp.kawabata_C"],
                 start={"warp.kawabata_K": 0.0025})
    assert not result.identifiable
    message = " ".join(result.warnings)
    assert "warp.kawabata_K" in message and "warp.kawabata_C" in message
    for entry in result.parameters.values():
        assert entry["ci95"] is None and entry["identified"] is False


def test_a_parameter_at_an_active_bound_gets_no_interval():
    scene, keys = RECOVERY["frictionless"]
    data = synthetic(scene, 2e-3, 2)
    truth = _get_key(scene, "warp.EA")
    result = fit(scene, data, keys, bounds={"warp.EA": (0.5 * truth, 0.9 * truth)},
                 start={"warp.EA": 0.8 * truth})
    entry = result.parameters["warp.EA"]
    assert entry["at_bound"] and entry["ci95"] is None
    assert entry["value"] == pytest.approx(0.9 * truth, rel=1e-6)
    assert any("warp.EA" in w and "bound" in w for w in result.warnings)


def test_friction_curve_does_not_depend_on_the_sampling_density():
    """Stick then slip under force control: the same loads sampled at 4 and at 16 points (the
    4 among them) give the same curve at the 4 common points, with the default substeps and
    with 16 substeps. The 1D return map is exact along a monotone slip, so only the solver's
    tolerance (1e-11 N on compliances ~ 1e-3 m/N: ~1e-14 m) should separate them; 1e-9 of the
    curve's range is a margin above that, while an O(increment) path error would be ~1e-2."""
    friction = dict(PAPER_FRICTION, beta=3e4)
    top = 0.5
    curves = []
    for points, substeps in ((4, None), (16, None), (4, 16)):
        load = top * np.arange(1, points + 1) / points
        steps = default_substeps(points) if substeps is None else substeps
        path, index = refined_path(load, steps)
        solution = solve_path(quarter_yarn("force", path, friction))
        assert any(s.any() for s in solution.sliding) and not all(s.all() for s in solution.sliding)
        curve = solution.observables["end_displacement"][index]
        curves.append(curve if points == 4 else curve[3::4])
    span = np.abs(curves[0]).max()
    for other in curves[1:]:
        assert np.abs(other - curves[0]).max() <= 1e-9 * span


def test_refined_path_holds_the_data_points():
    path, index = refined_path(np.array([1.0, 2.0, 4.0]), 2)
    assert np.allclose(path, [0.5, 1.0, 1.5, 2.0, 3.0, 4.0])
    assert (path[index] == [1.0, 2.0, 4.0]).all()
    path, index = refined_path(np.array([0.0, 1.0]), 2)  # a first row at the unloaded state
    assert np.allclose(path, [0.0, 0.5, 1.0]) and (index == [0, 2]).all()


def test_a_curve_may_start_at_the_unloaded_state():
    """A first row at load 0 (the prestressed yarn relaxed at P = 0, a real step) is fitted
    like any other point; the truth fits it to the solver's precision."""
    scene = quarter_yarn("force", np.r_[0.0, FORCES])
    curve = solve_path(scene).observables["end_displacement"]
    assert curve[0] != 0.0  # the prestress relaxes at zero load
    data = curve_from_columns(["load [N]", "end_displacement [m]"],
                              np.c_[np.r_[0.0, FORCES], curve * (1 + 1e-3 * np.cos(np.arange(11)))],
                              "force")
    result = fit(scene, data, ["warp.EA"], start={"warp.EA": 12.0})
    assert result.converged and result.parameters["warp.EA"]["ci95"] is not None
    for bad in ([0.0, 0.0, 0.1], [0.1, 0.0, 0.2]):
        with pytest.raises(UserError):
            curve_from_columns(["load [N]", "end_displacement [m]"],
                               np.c_[bad, [1.0, 2.0, 3.0]], "force")


# --------------------------------------------------------------------------
# Bad data and keys: one UserError each.


def _scene():
    return quarter_yarn("force", FORCES)


BAD = {
    "unknown column": (["load [N]", "strain [-]"], [[0.1, 1.0], [0.2, 2.0], [0.3, 3.0]]),
    "wrong unit": (["load [N]", "end_displacement [mm]"], [[0.1, 1.0], [0.2, 2.0], [0.3, 3.0]]),
    "wrong load column": (["end_displacement [m]", "end_force [N]"], [[0.1, 1.0], [0.2, 2.0]]),
    "load in kN": (["load [kN]", "end_displacement [m]"], [[0.1, 1.0], [0.2, 2.0]]),
    "NaN": (["load [N]", "end_displacement [m]"], [[0.1, 1.0], [0.2, "nan"], [0.3, 3.0]]),
    "text": (["load [N]", "end_displacement [m]"], [[0.1, 1.0], [0.2, "x"], [0.3, 3.0]]),
    "not monotonic": (["load [N]", "end_displacement [m]"], [[0.1, 1.0], [0.3, 2.0], [0.2, 3.0]]),
    "no unit": (["load [N]", "end_displacement"], [[0.1, 1.0], [0.2, 2.0]]),
    "sigma of nothing": (["load [N]", "end_displacement [m]", "crimp sigma [-]"],
                         [[0.1, 1.0, 1.0], [0.2, 2.0, 1.0]]),
    "sigma unit": (["load [N]", "end_displacement [m]", "end_displacement sigma [N]"],
                   [[0.1, 1.0, 1.0], [0.2, 2.0, 1.0]]),
    "load measured": (["load [N]", "end_force [N]"], [[0.1, 1.0], [0.2, 2.0]]),
    "no measured column": (["load [N]"], [[0.1], [0.2]]),
}


@pytest.mark.parametrize("case", BAD)
def test_bad_curve_is_one_scene_error(case):
    header, rows = BAD[case]
    with pytest.raises(UserError) as error:
        data = curve_from_columns(header, rows, "force")
        fit(_scene(), data, ["warp.EA"])
    assert "\n" not in str(error.value)


def test_too_few_points_and_bad_keys_are_scene_errors():
    scene = _scene()
    two = curve_from_columns(["load [N]", "end_displacement [m]"], [[0.1, 1e-4], [0.2, 2e-4]],
                             "force")
    for keys in (["warp.EA", "weft.kawabata_C"],  # 2 values, 2 parameters, noise estimated
                 ["geometry.segments"], ["load.values"], ["friction.alpha"], ["warp.EA", "warp.EA"],
                 ["warp.nothing"], ["warp.linear_density"]):
        with pytest.raises(UserError):
            fit(scene, two, keys)
    with pytest.raises(UserError):
        fit(scene, two, ["warp.EA"], bounds={"warp.EA": (1.0, 2.0)})  # start outside


def test_fit_jacobian_is_the_derivative_of_its_residuals():
    """The optimiser's Jacobian (sensitivities x dp/dtheta / weights, log coordinates for
    positive keys) against a central difference of its own residual function in theta, on a
    curve with two measured columns. Tolerance: the whole-curve FD error, estimated by
    Richardson as in tests/test_fit_sensitivity.py."""
    from dynfab.fitting.fit import _Problem, make_parameters, with_path

    scene = quarter_yarn("force", FORCES, dict(PAPER_FRICTION, beta=3e4))
    solution = solve_path(scene)
    data = curve_from_columns(
        ["load [N]", "end_displacement [m]", "crimp [-]"],
        np.c_[FORCES, 1.01 * solution.observables["end_displacement"],
              0.99 * solution.observables["crimp"]], "force")
    parameters = make_parameters(scene, ["warp.EA", "friction.alpha"])
    path, index = refined_path(data.load, 1)
    problem = _Problem(with_path(scene, path), data, parameters, index, None)
    theta = np.array([p.to_theta(p.start) for p in parameters])
    jac = problem.jacobian(theta)
    for k in range(theta.size):
        def difference(h):
            step = np.zeros_like(theta)
            step[k] = h
            return (problem.residuals(theta + step) - problem.residuals(theta - step)) / (2 * h)
        coarse, fine = difference(1e-4), difference(5e-5)
        error = np.abs(jac[:, k] - fine).max()
        assert error <= 3 * np.abs(coarse - fine).max() + 1e-12 * np.abs(fine).max(), k


def test_banded_solve_falls_back_to_pivoting_on_a_negative_pivot():
    """J is not positive definite under compression: the solve must still be J^-1 rhs (dense
    numpy reference), fixed dofs held at 0."""
    from dynfab.linalg.banded import BANDWIDTH, band_add, to_dense, zeros_band
    from dynfab.fitting.sensitivity import _solve

    rng = np.random.default_rng(0)
    n = 24
    band = zeros_band(n)
    for i in range(n):
        for j in range(max(0, i - BANDWIDTH), min(n, i + BANDWIDTH + 1)):
            value = rng.normal() + (8.0 if i == j else 0.0)
            if i == j == 3:
                value = -8.0  # an indefinite matrix: LU without pivoting stops here
            band_add(band, i, j, value)
    dense_matrix = to_dense(band)
    fixed = np.zeros(n, bool)
    fixed[[0, 1, n - 1]] = True
    rhs = rng.normal(size=(2, n))
    got = _solve(band, rhs, fixed)
    free = ~fixed
    expected = np.linalg.solve(dense_matrix[np.ix_(free, free)], rhs[:, free].T).T
    assert np.allclose(got[:, free], expected, rtol=1e-12, atol=1e-14 * np.abs(expected).max())
    assert (got[:, fixed] == 0).all()


def test_statistics_of_a_straight_line_match_the_textbook_formulas():
    """y = b0 + b1 x by least squares: se(b1) = s / sqrt(sum (x - xbar)^2),
    se(b0) = s sqrt(1/n + xbar^2 / sum (x - xbar)^2), corr(b0, b1) = -xbar / sqrt(mean(x^2)),
    s^2 = |r|^2 / (n - 2), 95 % interval b +- t_{0.975, n-2} se (independent of dynfab)."""
    from scipy import stats as scipy_stats

    from dynfab.fitting.fit import Parameter, statistics

    rng = np.random.default_rng(3)
    x = np.linspace(0.0, 1.0, 9)
    y = 0.3 + 2.0 * x + rng.normal(0.0, 0.05, x.size)
    b1, b0 = np.polyfit(x, y, 1)
    residual = b0 + b1 * x - y
    jac = np.c_[np.ones_like(x), x]
    parameters = [Parameter("a.b0", b0, False, -np.inf, np.inf),
                  Parameter("a.b1", b1, False, -np.inf, np.inf)]
    report = statistics(jac, residual, np.array([b0, b1]), parameters, False, [0, 0])
    n, sxx = x.size, ((x - x.mean()) ** 2).sum()
    s = np.sqrt((residual ** 2).sum() / (n - 2))
    expected = {"a.b0": s * np.sqrt(1 / n + x.mean() ** 2 / sxx), "a.b1": s / np.sqrt(sxx)}
    q = scipy_stats.t.ppf(0.975, n - 2)
    for key, value in (("a.b0", b0), ("a.b1", b1)):
        entry = report["parameters"][key]
        assert entry["standard_error"] == pytest.approx(expected[key], rel=1e-10)
        assert entry["ci95"] == pytest.approx([value - q * expected[key], value + q * expected[key]],
                                              rel=1e-10)
    assert report["correlation"][0][1] == pytest.approx(-x.mean() / np.sqrt((x ** 2).mean()),
                                                        rel=1e-10)
    assert report["dof"] == n - 2 and report["identifiable"]


def test_statistics_name_a_key_the_curve_does_not_see():
    from dynfab.fitting.fit import Parameter, statistics

    x = np.linspace(0.0, 1.0, 9)
    jac = np.c_[x, np.zeros_like(x)]
    parameters = [Parameter(k, 1.0, True, 0.0, np.inf) for k in ("a.E", "a.m")]
    report = statistics(jac, 0.01 * np.sin(7 * x), np.zeros(2), parameters, False, [0, 0])
    assert report["parameters"]["a.E"]["ci95"] is not None
    assert report["parameters"]["a.m"]["ci95"] is None and not report["identifiable"]
    assert report["warnings"] == ["not identifiable: a.m; the curve does not depend on it"]


def test_statistics_name_an_exactly_dependent_pair():
    """Two columns proportional (the curve sees only their combination): rank deficient."""
    from dynfab.fitting.fit import Parameter, statistics

    x = np.linspace(0.0, 1.0, 9)
    jac = np.c_[x, 2 * x, np.ones_like(x)]
    parameters = [Parameter(k, 1.0, True, 0.0, np.inf) for k in ("a.K", "a.C", "a.E")]
    report = statistics(jac, 0.01 * np.sin(7 * x), np.zeros(3), parameters, False, [0, 0, 0])
    assert not report["identifiable"]
    assert report["parameters"]["a.E"]["ci95"] is not None
    for key in ("a.K", "a.C"):
        assert report["parameters"][key]["ci95"] is None
    assert any("a.K" in w and "a.C" in w and "a.E" not in w for w in report["warnings"])
