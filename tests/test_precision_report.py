"""`dynfab precision --quick`: what its numbers and figures show, not only that files exist.

The quick report relaxes single load steps of the paper yarn cut to 4 crossings (N = 56,
the same spacing, weft and contact law; end displacements / 4) from a converged static
state, with each dynamic method at 2-3 tolerances, and compares every result with the
static reference converged to float64's rounding floor.

The bound used throughout is the one of test_dynamic_relaxation.py. A solve stops at a
residual r (the largest free force component) and the reference at r_ref; linearising the
residual map g at the reference, x - x_ref = K^-1 (g(x) - g(x_ref)), so

    |x - x_ref|_inf <= ||K^-1||_inf (r + r_ref) =: B(r),

with ||K^-1||_inf from the dense Hessian over the free dofs at the reference (the coupled
friction Jacobian where there is friction), computed by the report for each case.
"""

from __future__ import annotations

import contextlib
import csv
import io
import json
import math
from collections import defaultdict

import numpy as np
import pytest
from matplotlib.image import imread

from dynfab.cli import main
from dynfab.errors import UserError
from dynfab.kernels.structure_variants import built_variants
from dynfab.reports.precision import CSV_COLUMNS, QUICK, TARGETS, Plan, run_precision
from dynfab.reports.precision_plots import plot_error_vs_residual, plot_work_precision

FILES = {"points.csv", "summary.json", "cheapest.json", "precision.md",
         "work_precision_time.png", "work_precision_evaluations.png", "error_vs_residual.png"}
PNGS = sorted(name for name in FILES if name.endswith(".png"))

TEST_VARIANTS = {
    # the variants tests/test_dynamic_*.py build (`structure_variants.Variant.name`; the
    # damping and the load control are data, not variants)
    "explicit/grouped/scatter/float64/no friction/planar",
    "semi_implicit/grouped/scatter/float64/no friction/planar",
    "explicit/grouped/scatter/float32/no friction/planar",
    "explicit/grouped/scatter/float64/friction/planar",
    "semi_implicit/grouped/scatter/float64/friction/planar",
}
PASSES = {"passes/-/-/float64/no friction/planar", "passes/-/-/float64/friction/planar",
          "passes/-/-/float32/no friction/planar"}
"""The one-pass kernels (tie forces at a step's end) of the same tests."""

ROUNDING_SLACK = 1e-12
"""float64 rounding of a recomputed residual [N]: a node's diagonal stiffness k ~ 6e4 N/m
at x <= 0.025 m gives k eps |x| ~ 3e-13 N of rounding, summed over a few terms."""


NEW_VARIANTS = set()
"""Kernel variants the quick run built that this process had not built before it."""


@pytest.fixture(scope="module")
def report(tmp_path_factory):
    """The quick report, through the command line; (folder, summary, stdout)."""
    out = tmp_path_factory.mktemp("precision")
    stdout = io.StringIO()
    before = set(built_variants())
    with contextlib.redirect_stdout(stdout):
        main(["precision", "--out", str(out), "--quick", "--quiet"])
    NEW_VARIANTS.update(set(built_variants()) - before)
    return out, json.loads((out / "summary.json").read_text()), stdout.getvalue()


def usable(summary, solver=None):
    return [p for p in summary["points"] if p["status"] != "failed"
            and (solver is None or p["solver"] == solver)]


def curves(summary):
    """Dynamic points by (case, method), loosest tolerance first."""
    groups = defaultdict(list)
    for p in usable(summary, "dynamic"):
        groups[(p["case"], p["method"])].append(p)
    return {key: sorted(group, key=lambda p: -p["tolerance"]) for key, group in groups.items()}


def cases(summary):
    return {c["case"]: c for c in summary["cases"]}


def bound(case, point):
    """B(r) = ||K^-1||_inf (r + r_ref) [m], from the point's float64 residual."""
    return case["inverse_stiffness_norm_m_per_N"] * (point["residual_N"]
                                                     + case["reference_residual_N"])


def read_csv(out):
    with (out / "points.csv").open() as handle:
        reader = csv.DictReader(handle)
        return tuple(reader.fieldnames), list(reader)


def test_the_command_writes_every_file_it_names(report):
    out, summary, stdout = report
    assert {p.name for p in out.iterdir()} == FILES
    assert sorted(line.split()[-1] for line in stdout.splitlines()) == sorted(summary["files"])
    assert summary["quick"] and summary["plan"]["name"] == "quick"
    assert summary["machine"]["cpus"] >= 1 and summary["wall_time_s"] > 0
    # two scenes (frictionless, friction) x three steps of the 40-step path
    assert len(summary["cases"]) == 6
    assert {c["segments"] for c in summary["cases"]} == {56}
    assert not summary["failures"]


def test_quick_mode_builds_only_the_kernel_variants_the_dynamic_tests_build(report):
    # Each Warp variant costs about 2 s to compile cold: the quick report must not add any.
    # Its own record of the variants it used (every solver and the mass probe):
    _, summary, _ = report
    assert set(summary["kernel_variants"]) == TEST_VARIANTS
    assert {p["kernel"] for p in usable(summary, "dynamic")} <= TEST_VARIANTS
    # and Warp's bookkeeping (empty when earlier tests built them all in this process):
    assert {variant.name for variant in NEW_VARIANTS} <= TEST_VARIANTS | PASSES


def test_the_references_sit_at_the_rounding_floor(report):
    # The reference is Newton to 1e-13 N, below float64's floor: it stops where the residual
    # stops falling, a few 1e-13 N here (docs/model.md sections 5-6).
    _, summary, _ = report
    for case in summary["cases"]:
        assert case["reference_residual_N"] <= 1e-12, case
        assert case["end_quantity"] == "end_force"  # displacement control: P is the unknown
        assert case["inverse_stiffness_norm_m_per_N"] > 0
        assert case["critical_damping_per_s"] > 0


def test_the_cheapest_table_is_consistent_with_the_csv_data(report):
    # Rebuilt from the CSV rows alone: the named cheapest point reaches the target and no
    # dynamic point reaching it is cheaper (by wall time, and by force evaluations).
    out, summary, _ = report
    _, rows = read_csv(out)
    data = defaultdict(dict)
    for row in rows:
        if row["solver"] == "dynamic" and row["status"] != "failed":
            key = (row["case"], row["method"], float(row["tolerance"]))
            data[key][row["quantity"]] = float(row["value"])
    table = json.loads((out / "cheapest.json").read_text())
    assert table["cheapest"] == summary["cheapest"]
    assert len(table["cheapest"]) == len(summary["cases"]) * len(TARGETS)
    for row in table["cheapest"]:
        reaching = {key: value for key, value in data.items()
                    if key[0] == row["case"] and value["relative_error"] <= row["target"]}
        for column, quantity in (("by_wall_time", "wall_time"),
                                 ("by_force_evaluations", "force_evaluations")):
            named = row[column]
            assert (named is None) == (not reaching), row
            if named is None:
                continue
            mine = data[(row["case"], named["method"], named["tolerance"])]
            assert mine["relative_error"] <= row["target"]
            assert mine[quantity] == min(v[quantity] for v in reaching.values()), row
        if row["by_wall_time"] is not None:
            assert row["static_speedup"] == pytest.approx(
                row["by_wall_time"]["wall_time_s"] / row["static_newton"]["wall_time_s"])


def test_the_pareto_fronts_are_the_undominated_dynamic_points(report):
    # Brute force: a point is on the front of a cost when no other dynamic point is at most
    # as costly and as wrong, and strictly better in one (errors floored at the case's
    # position rounding floor, as plotted).
    _, summary, _ = report
    for case in summary["cases"]:
        points = [p for p in usable(summary, "dynamic") if p["case"] == case["case"]]
        floor = case["rounding_floor_relative"]
        for cost, flag in (("wall_time_s", "pareto_time"),
                           ("force_evaluations", "pareto_evaluations")):
            def key(p):
                return p[cost], max(p["relative_error"], floor)
            for p in points:
                beaten = any(key(q)[0] <= key(p)[0] and key(q)[1] <= key(p)[1]
                             and key(q) != key(p) for q in points)
                assert p[flag] == (not beaten), (case["case"], cost, p["method"], p["tolerance"])
            assert any(p[flag] for p in points)
    assert not any(p["pareto_time"] for p in summary["points"] if p["solver"] != "dynamic")


def test_every_point_is_within_its_bound(report):
    # The linearised bound B(r) holds for every solve, dynamic, static and L-BFGS-B, with the
    # residual recomputed in float64 at the returned positions (for float32 solves too).
    _, summary, _ = report
    by_case = cases(summary)
    for p in usable(summary):
        assert p["position_error_m"] <= bound(by_case[p["case"]], p), p
        assert p["within_bound"] is True


def test_every_method_error_falls_as_its_tolerance_tightens(report):
    # Within a method, a tighter tolerance need not give a smaller error point by point: a
    # solve stopping at residual r leaves an error anywhere in [0, B(r)], and a looser
    # solve may stop luckily close. What must hold is
    #   (a) monotone within the bound: e_k <= min_{j<k} e_j + B(r_k) for each tighter
    #       tolerance k, i.e. a tighter solve is never worse than any looser one by more
    #       than its own bound (this follows from e_k <= B(r_k), checked above, and is
    #       restated here on the curves);
    #   (b) float64 solves meet their tolerance (r_k <= tol_k, up to float64 rounding of the
    #       recomputed residual), so B(r_k) shrinks with the tolerance;
    #   (c) the errors do fall: over the 6 decades 1e-4 -> 1e-10 N the error drops at least
    #       100-fold (measured: 840- to 5e7-fold; the tightest errors are within
    #       B(1e-10 N) <= 1e-10 m, 2e-7 A_wa, while the loosest are >= 3e-8 m).
    _, summary, _ = report
    by_case = cases(summary)
    for (case_key, method), curve in curves(summary).items():
        case = by_case[case_key]
        for k, point in enumerate(curve[1:], start=1):
            best_looser = min(p["position_error_m"] for p in curve[:k])
            assert point["position_error_m"] <= best_looser + bound(case, point), (method, point)
        if curve[0]["precision"] == "float32":
            continue
        assert [p["tolerance"] for p in curve] == list(QUICK.tolerances)
        for point in curve:
            assert point["status"] == "converged"
            assert point["residual_N"] <= point["tolerance"] + ROUNDING_SLACK, point
        assert curve[-1]["relative_error"] <= curve[0]["relative_error"] / 100, (case_key, method)


def test_float32_does_not_beat_its_rounding_floor(report):
    # float32 stores positions x <= 0.025 m to a spacing of about 2e-9 m; the equilibrium
    # lies between grid points, so each node is off by up to 1e-9 m, and the 3e4 N/m
    # stretch springs (6e4 N/m on a node's diagonal) turn that into force imbalances of up
    # to ~1e-4 N. The residual
    # (recomputed in float64 at the float32 positions) therefore stays near 1e-4 N: asking
    # 1e-6 N ends at the rounding floor, and no float32 solve gets below 2e-5 N, while the
    # float64 solves of the same cases reach 1e-10 N.
    _, summary, _ = report
    float32 = [p for p in usable(summary, "dynamic") if p["precision"] == "float32"]
    assert float32
    for p in float32:
        assert p["residual_N"] >= 2e-5, p
        if p["tolerance"] < 1e-5:
            assert p["status"] == "rounding_floor", p
            assert p["residual_N"] > p["tolerance"]
    float64 = [p for p in usable(summary, "dynamic") if p["precision"] == "float64"
               and p["tolerance"] == min(QUICK.tolerances)]
    assert max(p["residual_N"] for p in float64) <= 1e-10 + ROUNDING_SLACK


def test_the_static_point_has_the_smallest_error(report):
    # The static point is the reference solve timed again: Newton is deterministic, so it
    # reproduces the reference bit for bit (error exactly 0, the floor); every other solve
    # is at least as far off, and the figures draw the static point at the rounding floor.
    # The second static point, Newton at the scene's 1e-11 N (what `dynfab run` does), stops
    # at most one iteration earlier: quadratic convergence leaves it within its bound
    # B(1e-11 N) ~ 1e-11 m (checked for every point above), here 2e-8 A_wa.
    _, summary, _ = report
    for case in summary["cases"]:
        points = [p for p in usable(summary) if p["case"] == case["case"]]
        static = [p for p in points if p["method"] == "static_reference"]
        assert len(static) == 1 and static[0]["solver"] == "static"
        assert static[0]["relative_error"] == 0.0
        assert static[0]["residual_N"] == pytest.approx(case["reference_residual_N"])
        assert all(p["relative_error"] >= static[0]["relative_error"] for p in points)
        assert min(p["relative_error"] for p in points if p["solver"] == "dynamic") > 0
        default = [p for p in points if p["method"] == "static_newton"]
        assert len(default) == 1 and default[0]["tolerance"] == 1e-11
        assert default[0]["residual_N"] <= 1e-11 and default[0]["relative_error"] <= 2e-8


def test_end_force_errors_follow_the_position_errors(report):
    # Under displacement control the reported end error is the end force's. The force is
    # dV/dx_N, so to first order |dP| <= sum_j |K_Nj| |dx|_inf: it cannot be wrong by more
    # than a row sum of |K| (the largest is 1.3e5 N/m here) times the position error, and it
    # is 0 for the static reference.
    _, summary, _ = report
    for p in usable(summary):
        assert p["end_quantity"] == "end_force"
        assert p["end_error_absolute"] <= 2e5 * p["position_error_m"] + ROUNDING_SLACK, p


def test_every_csv_row_is_tidy_with_units(report):
    out, summary, _ = report
    columns, rows = read_csv(out)
    assert columns == CSV_COLUMNS
    units = {"wall_time": "s", "force_evaluations": "-", "iterations": "-",
             "position_error": "m", "relative_error": "-", "end_force_error": "-",
             "end_force_error_absolute": "N", "residual": "N", "solver_residual": "N",
             "error_bound": "m"}
    per_point = defaultdict(set)
    for row in rows:
        assert row["units"] == units[row["quantity"]], row
        assert math.isfinite(float(row["value"]))
        assert row["tolerance_units"] == "N" and row["load_units"] == "m"
        assert float(row["load"]) > float(row["start_load"]) >= 0
        if row["damping_coefficient"] not in ("", "adaptive"):
            assert row["damping_coefficient_units"] == "1/s"
            assert float(row["damping_coefficient"]) > 0
        per_point[(row["case"], row["method"], row["tolerance"])].add(row["quantity"])
    assert len(per_point) == len(usable(summary))
    assert all(quantities == set(units) for quantities in per_point.values())


def test_the_pngs_are_real_images(report):
    out, _, _ = report
    for name in PNGS:
        image = imread(out / name)
        height, width = image.shape[:2]
        assert height >= 800 and width >= 1500
        rgb = image[..., :3]
        assert rgb.std() > 0.05  # not blank
        coloured = (rgb.max(axis=-1) - rgb.min(axis=-1)) > 0.3
        assert coloured.mean() > 1e-3  # the coloured curves are drawn
        levels = np.round(rgb * 255).astype(np.uint32)
        colours = levels[..., 0] << 16 | levels[..., 1] << 8 | levels[..., 2]
        assert np.unique(colours).size > 50  # anti-aliased curves and markers, not flat fills


def test_each_work_precision_panel_plots_the_usable_points_of_its_case(report):
    # What the figure shows: in the panel titled as a case, the (force evaluations, relative
    # error floored at the case's rounding floor) of every usable point of that case, and
    # nothing else (the Pareto front redraws some of them; the targets are horizontal lines).
    _, summary, _ = report
    figure = plot_work_precision(summary, "force_evaluations")
    panels = {ax.get_title(): ax for ax in figure.axes if ax.axison}
    assert len(panels) == len(summary["cases"])
    for case in summary["cases"]:
        ax, floor = panels[case["title"]], case["rounding_floor_relative"]
        drawn = {(float(x), float(y)) for line in ax.get_lines()
                 if list(line.get_xdata()) != [0, 1]  # not an axhline (axes coordinates)
                 for x, y in zip(line.get_xdata(), line.get_ydata())}
        expected = {(float(p["force_evaluations"]), max(p["relative_error"], floor))
                    for p in usable(summary) if p["case"] == case["case"]}
        assert drawn == expected, case["case"]


def test_each_error_vs_residual_panel_plots_its_points_and_their_bound(report):
    # What error_vs_residual.png shows: (float64 residual, floored relative error) of every
    # usable point of the case, and the dashed bound ||K^-1||_inf (r + r_ref) / scale.
    _, summary, _ = report
    figure = plot_error_vs_residual(summary)
    panels = {ax.get_title(): ax for ax in figure.axes if ax.axison}
    for case in summary["cases"]:
        ax, floor = panels[case["title"]], case["rounding_floor_relative"]
        lines = [line for line in ax.get_lines() if list(line.get_xdata()) != [0, 1]]
        bounds = [line for line in lines if line.get_linestyle() == "--"]
        drawn = {(float(x), float(y)) for line in lines if line not in bounds
                 for x, y in zip(line.get_xdata(), line.get_ydata())}
        assert drawn == {(p["residual_N"], max(p["relative_error"], floor))
                         for p in usable(summary) if p["case"] == case["case"]}, case["case"]
        if case["inverse_stiffness_norm_m_per_N"] is not None:
            (bound,) = bounds
            r = np.asarray(bound.get_xdata())
            assert np.allclose(bound.get_ydata(), case["inverse_stiffness_norm_m_per_N"]
                               * (r + case["reference_residual_N"]) / case["scale_m"],
                               rtol=1e-15, atol=0)


def test_lbfgs_points_are_there_with_scipy(report):
    out, summary, _ = report
    lbfgs = [p for p in summary["points"] if p["solver"] == "lbfgs"]
    assert {p["case"] for p in lbfgs} == set(cases(summary))
    assert all(p["blas_single_thread"] for p in lbfgs)




def test_bad_output_folder_is_a_scene_error_and_exit_status_2(tmp_path, capsys):
    not_a_folder = tmp_path / "file.txt"
    not_a_folder.write_text("x")
    with pytest.raises(UserError, match="is a file, not a folder"):
        run_precision(not_a_folder, quick=True)
    with pytest.raises(SystemExit) as exit_info:
        main(["precision", "--out", str(not_a_folder), "--quick"])
    assert exit_info.value.code == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("dynfab: error:") and "\n" not in err
