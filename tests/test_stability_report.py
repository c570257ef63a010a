"""`dynfab stability --quick`: every case gets a verdict, nothing ends in NaN, the buckling
limit is refused by name, and the stable time step the solver predicts is what the
bisection measures, within a factor derived here.

The factor. Symplectic Euler is stable while dt omega_max < 2. The solver predicts
dt_p = 2 min_i sqrt(m_i / r_i), r_i the largest Gershgorin row sum sum_j |K_ij| of node
i's two dofs, K the stiffest tangent the load step can meet (every contact at its bound
k_we, every crossing sticking with k_t). Gershgorin bounds lambda_max(M^-1 K) from above,
and the stiffest tangent bounds the actual one, so dt_p is at most the true limit:
measured >= dt_p, up to the bisection's bracket (2 %). How far above: on a crimped
chain dominated by its axial springs (k = EA/l0), the x-row of a node sums
2 k t_x^2 + 2 k |t_x t_z| per side, while the highest mode (neighbours in opposition
along x) has lambda ~ 4 k t_x^2 / m; the excess is the crimp slope |t_z / t_x| <=
pi A_wa N_we / L = 0.25 on this yarn (the quick yarn has the same spacing), i.e. 1.25 in
lambda, 1.12 in dt; with the bracket, measured <= 1.15 dt_p (measured: 1.01-1.06).

With friction the prediction takes every crossing as sticking, adding k_t to the x-row
of a crossing node: where crossings slide (or stick only until their force reaches F_T,
which caps a growing stick oscillation), the measured step is up to
sqrt(1 + k_t / (4 k)) times larger (16 at 1000 x the default k_t). And stick/slip
switching makes the undamped motion a switched system, which can grow below the linear
limit of each of its pieces (the full report measures 0.94 dt_p at alpha = 2): there
the lower bound is the solver's default safety factor, 0.9, the fraction of dt_p it
uses with physical masses. (The quick friction case is measured with kinetic damping,
the variant the dynamic tests compile, which sees the linear instability only: within
the same bounds. A stick oscillation that grows until sliding caps it still counts as
unstable: the kernel's energy test sees kinetic energy the forces never supplied, so the
measured step no longer reaches the sliding limit near the top.)
"""

from __future__ import annotations

import contextlib
import csv
import io
import json
import math
import re

import numpy as np
import pytest
from matplotlib.image import imread

from dynfab.cli import main
from dynfab.errors import UserError
from dynfab.kernels import structure_variants
from dynfab.reports.stability import (BISECTION_RATIO, CSV_COLUMNS, EXPLICIT_MAX_STEPS,
                                      case_scene, extrapolate_mesh, fit_power_law, paper_yarns,
                                      run_stability)
from dynfab.reports.stability_cases import METHODS, QUICK
from dynfab.reports.stability_plots import plot_map
from dynfab.scene import Dynamic

GERSHGORIN_SLACK = 1.15
"""Largest measured / predicted stable dt without friction (module docstring)."""
SAFETY = Dynamic().safety
"""The solver's default fraction of the predicted dt (physical masses): 0.9."""

TESTED_VARIANTS = {
    # the float64 grouped kernels (`structure_variants.Variant.name`; the damping and the load
    # control are data) that test_dynamic_relaxation.py and test_dynamic_semi_implicit.py
    # compile, and the one-pass kernels of their steps' ends
    "explicit/grouped/scatter/float64/no friction/planar", "explicit/grouped/scatter/float64/friction/planar",
    "semi_implicit/grouped/scatter/float64/no friction/planar",
    "semi_implicit/grouped/scatter/float64/friction/planar",
    "passes/-/-/float64/no friction/planar", "passes/-/-/float64/friction/planar",
}


@pytest.fixture(scope="module")
def report(tmp_path_factory):
    """The quick report through the command line: (folder, summary, stdout, progress lines,
    kernel variants built during the run)."""
    out = tmp_path_factory.mktemp("stability")
    stdout, stderr = io.StringIO(), io.StringIO()
    before = set(structure_variants.built_variants())
    with contextlib.redirect_stdout(stdout), contextlib.redirect_stderr(stderr):
        main(["stability", "--out", str(out), "--quick"])
    built = set(structure_variants.built_variants()) - before
    summary = json.loads((out / "summary.json").read_text())
    return out, summary, stdout.getvalue(), stderr.getvalue().splitlines(), built


def cases(summary, refused=False):
    return [c for c in summary["cases"] if (c["refused"] is not None) == refused]


def test_the_command_writes_every_file_it_names(report):
    out, summary, stdout, progress, _ = report
    assert {p.name for p in out.iterdir()} == {"stability.md", "stability.csv", "summary.json",
                                               "map.png"}
    assert sorted(line.split()[-1] for line in stdout.splitlines()) == sorted(summary["files"])
    assert summary["quick"] and summary["machine"]["cpus"] >= 1 and summary["wall_time_s"] > 0
    assert [c["case"] for c in summary["cases"]] == [c.name for c in QUICK.cases]
    # one case per family, as the plan says
    assert {c["family"] for c in summary["cases"]} == {"kawabata", "stretch", "weft", "load",
                                                       "friction"}
    assert progress[-1].startswith("stability report:")


def test_only_the_kernel_variants_the_dynamic_tests_compile(report):
    _, summary, _, _, built = report
    # new in this process (the rest were compiled before), and the report's own record
    assert {variant.name for variant in built} <= TESTED_VARIANTS
    used = set(summary["kernel_variants"])
    assert used and used <= TESTED_VARIANTS


def test_every_case_has_a_verdict(report):
    _, summary, _, _, _ = report
    for case in summary["cases"]:
        if case["refused"] is not None:
            assert case["refused"] and not case["methods"], case["case"]
            continue
        assert case["static"]["residual_N"] <= 1e-10, case["case"]
        assert set(case["methods"]) == set(METHODS)
        for name, method in case["methods"].items():
            verdict = method["verdict"]
            assert verdict in ("converged", "failed", "skipped"), (case["case"], name)
            if verdict == "converged":
                assert method["residual_N"] <= 1e-8 and method["time_steps"] > 0
                assert math.isfinite(method["error_over_A_wa"])
                assert method["wall_time_s"] >= 0
            else:
                assert method["message"], (case["case"], name)
            if verdict == "failed":
                assert method["time_steps"] > 0 and method["last_good_state"]["finite"]
        # the quick plan runs the friction case with the two variants the tests compile
        skipped = {n for n, m in case["methods"].items() if m["verdict"] == "skipped"}
        assert skipped == ({"viscous", "fire"} if case["friction"] else set()), case["case"]
    assert len(cases(summary, refused=True)) == 1


def test_every_failure_names_its_case_and_time_step(report):
    # A failure (here: the friction case relaxed with the physical masses at the measured
    # energy-stable dt, where a sticking crossing chatters) is one progress line naming
    # the case, the time step it stopped at and the solver's own message; the run goes on.
    _, summary, _, progress, _ = report
    failures = [line for line in progress if "FAILED" in line]
    friction = next(c for c in summary["cases"] if c["friction"])
    relaxation = friction["stability"]["relaxation_at_measured_dt"]
    assert relaxation["verdict"] == "failed" and "no convergence" in relaxation["message"]
    assert any(line.startswith(f"[ 5/5] {friction['case']}: ") and
               f"FAILED after {relaxation['time_steps']} time steps" in line and
               relaxation["message"] in line for line in failures)
    assert relaxation["time_steps"] == EXPLICIT_MAX_STEPS


def test_nothing_is_nan_in_any_output(report):
    out, summary, _, _, _ = report

    def walk(value):
        if isinstance(value, dict):
            for v in value.values():
                walk(v)
        elif isinstance(value, list):
            for v in value:
                walk(v)
        elif isinstance(value, float):
            assert math.isfinite(value)

    walk(json.loads((out / "summary.json").read_text()))  # json reads NaN/Infinity as floats
    for name in ("summary.json", "stability.csv", "stability.md"):
        text = (out / name).read_text()
        assert not re.search(r"\b(nan|inf|infinity)\b", text, re.IGNORECASE), name
    with (out / "stability.csv").open() as handle:
        reader = csv.DictReader(handle)
        assert tuple(reader.fieldnames) == CSV_COLUMNS
        rows = list(reader)
    assert len(rows) == len(summary["cases"]) * len(METHODS)
    numeric = ("load", "predicted_dt_s", "measured_dt_s", "measured_over_predicted",
               "gershgorin_actual_dt_s", "linear_dt_s", "time_steps", "wall_time_s", "residual_N",
               "error_over_A_wa", "bound_over_A_wa")
    for row in rows:
        assert row["verdict"], row
        for column in numeric:
            if row[column]:
                assert math.isfinite(float(row[column])), (column, row)


def test_beyond_buckling_is_refused_naming_the_limit(report):
    _, summary, _, _, _ = report
    (case,) = cases(summary, refused=True)
    assert case["case"] == "alpha_we=-1.01"
    ei, length = 1.47e-7, 0.1  # the paper's weft (the quick yarn keeps the weft whole)
    limit = -math.pi ** 2 * ei / length ** 2
    message = case["refused"]
    assert message.startswith(f"weft.tension = {-1.01 * math.pi ** 2 * ei / length ** 2!r}:")
    assert f"must be > {limit:.6g} N = -pi^2 weft.EI / weft.length^2, where the weft buckles" \
        in message
    # the verdict is validate_scene's own message for that scene, verbatim
    plan_case = next(c for c in QUICK.cases if c.name == case["case"])
    with pytest.raises(UserError) as raised:
        case_scene(plan_case, paper_yarns(QUICK)[False], 0.01 * 0.025)
    assert str(raised.value) == message
    out = report[0]
    assert message in (out / "stability.md").read_text()
    with (out / "stability.csv").open() as handle:
        refused = [r for r in csv.DictReader(handle) if r["case"] == case["case"]]
    assert {r["verdict"] for r in refused} == {"refused"}
    assert {r["message"] for r in refused} == {message}


def test_measured_stable_dt_is_within_the_derived_factor_of_the_predicted_one(report):
    _, summary, _, _, _ = report
    measured = [c for c in cases(summary) if c["stability"]["measured_dt_s"] is not None]
    assert len(measured) == 4
    for case in measured:
        stability = case["stability"]
        ratio = stability["measured_over_predicted"]
        assert stability["unstable_dt_s"] / stability["measured_dt_s"] <= BISECTION_RATIO
        if not case["friction"]:
            assert 1 / BISECTION_RATIO <= ratio <= GERSHGORIN_SLACK, case["case"]
            # the exact linear limit lies inside the bracket: the bisection finds it
            assert stability["measured_dt_s"] <= stability["linear_dt_s"] * BISECTION_RATIO
            assert stability["linear_dt_s"] <= stability["unstable_dt_s"] * BISECTION_RATIO
            assert stability["measured_with"].startswith("undamped")
        else:
            sticking = math.sqrt(1 + case["stick_stiffness"] / (4 * case["stretch_stiffness_max"]))
            assert SAFETY <= ratio <= GERSHGORIN_SLACK * sticking, case["case"]
            assert stability["measured_with"] == "kinetic damping"
        # Gershgorin on the actual tangent is a bound too, and the solver's (stiffest tangent)
        # is below it; 1e-6: the solver's is taken at the perturbed state (1e-9 m moves)
        assert stability["predicted_dt_s"] <= stability["gershgorin_actual_dt_s"] * (1 + 1e-6)
        assert stability["gershgorin_actual_dt_s"] <= stability["linear_dt_s"] * (1 + 1e-9)


def test_converged_errors_are_within_the_residual_bound(report):
    # |x_dyn - x_static|_inf <= ||K^-1||_inf (r + r_s) (tests/test_dynamic_relaxation.py),
    # K the Hessian (with friction: the coupled Jacobian) at the static solution; it holds
    # while both solvers end with the same crossings sliding, checked here too.
    _, summary, _, _, _ = report
    checked = 0
    for case in cases(summary):
        for name, method in case["methods"].items():
            if method["verdict"] != "converged":
                continue
            assert method["same_sliding"], (case["case"], name)
            assert method["bound_over_A_wa"] is not None
            assert method["error_over_A_wa"] <= method["bound_over_A_wa"], (case["case"], name)
            checked += 1
    assert checked == 3 * 4 + 2


def test_the_table_has_a_row_per_case_and_its_notes(report):
    out, summary, _, _, _ = report
    text = (out / "stability.md").read_text()
    cases_table, paths_table = text.split("Friction load paths")  # the cases' table comes first
    rows = [line for line in cases_table.splitlines() if line.startswith("| ")]
    header, body = rows[0], rows[1:]
    assert [cell.strip() for cell in header.strip("|").split("|")][-4:] == list(METHODS)
    assert len(body) == len(summary["cases"])
    path_rows = [line for line in paths_table.splitlines() if line.startswith("| friction path")]
    assert len(path_rows) == len(summary["paths"]) == 1
    width = header.count("|")
    assert all(line.count("|") == width for line in body)
    for case, line in zip(summary["cases"], body):
        assert line.startswith(f"| {case['case']} |")
    notes = re.findall(r"\[(\d+)\]", text)
    assert notes and all(f"\n{n}. " in text for n in set(notes))
    assert "**refused**" in text and "skipped" in text


def test_the_map_is_a_real_image(report):
    out, _, _, _, _ = report
    image = imread(out / "map.png")
    height, width = image.shape[:2]
    assert height >= 800 and width >= 1000
    rgb = image[..., :3]
    assert rgb.std() > 0.05
    coloured = (rgb.max(axis=-1) - rgb.min(axis=-1)) > 0.3
    assert coloured.mean() > 1e-4  # the family markers
    assert len(np.unique(rgb.reshape(-1, 3), axis=0)) > 50


def test_the_map_plots_each_measured_case_at_its_predicted_and_measured_dt(report):
    # What map.png shows: left, one marker at (predicted, measured) per case with a measured
    # dt (a cross over it where the relaxation fails there); right, measured / predicted
    # on the case's row, the rows labelled with the case names.
    _, summary, _, _, _ = report
    measured = [c for c in summary["cases"]
                if c.get("stability") and c["stability"].get("measured_dt_s") is not None]
    assert measured
    left, right = plot_map(summary["cases"], QUICK).axes
    markers = [line for line in left.get_lines() if line.get_linestyle() == "None"
               and line.get_marker() != "x"]
    assert [(line.get_xdata()[0], line.get_ydata()[0]) for line in markers] == [
        (c["stability"]["predicted_dt_s"], c["stability"]["measured_dt_s"]) for c in measured]
    ratios = [line for line in right.get_lines() if line.get_marker() not in ("x", "None", "")]
    assert [(line.get_xdata()[0], line.get_ydata()[0]) for line in ratios] == [
        (c["stability"]["measured_over_predicted"], -k) for k, c in enumerate(measured)]
    assert [t.get_text() for t in right.get_yticklabels()] == [c["case"] for c in measured]


def test_fine_meshes_are_judged_by_their_extrapolated_step_count():
    # steps = 2 N^1.5 measured at 224, 448, 896: 1792 and 3584 are predicted by the fit,
    # and judged against max_steps (1792: 1.5e5 <= 2e5; 3584: 4.3e5 > 2e5).
    assert fit_power_law([224, 448, 896], [2 * n ** 1.5 for n in (224, 448, 896)]) == \
        pytest.approx((1.5, 2.0))

    def case(n, family="mesh"):
        methods = {name: ({"verdict": "converged", "time_steps": round(2 * n ** 1.5),
                           "wall_time_s": 1e-8 * n * 2 * n ** 1.5} if n <= 896
                          else {"verdict": "extrapolated"}) for name in ("kinetic", "viscous", "fire")}
        return {"case": f"N={n}", "family": family, "segments": n, "refused": None,
                "methods": methods}

    measured = [case(224, "baseline"), case(448), case(896), case(1792), case(3584)]
    fits = extrapolate_mesh(measured)
    assert fits["kinetic"]["exponent"] == pytest.approx(1.5, abs=1e-3)
    fine, finest = measured[3]["methods"]["kinetic"], measured[4]["methods"]["kinetic"]
    assert fine["verdict"] == "extrapolated: converges"
    assert fine["predicted_time_steps"] == pytest.approx(2 * 1792 ** 1.5, rel=1e-3)
    assert finest["verdict"] == "extrapolated: max_steps"
    assert f"> max_steps = {EXPLICIT_MAX_STEPS}" in finest["message"]


def test_bad_output_folder_is_a_scene_error_and_exit_status_2(tmp_path, capsys):
    not_a_folder = tmp_path / "file.txt"
    not_a_folder.write_text("x")
    with pytest.raises(UserError, match="is a file, not a folder"):
        run_stability(not_a_folder, quick=True)
    with pytest.raises(SystemExit) as exit_info:
        main(["stability", "--out", str(not_a_folder), "--quick"])
    assert exit_info.value.code == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("dynfab: error:") and "\n" not in err


def test_the_friction_path_is_followed_by_the_compiled_methods(report):
    """The quick path case: the static reference along the force path (loading, unloading to
    zero, reloading), then kinetic and semi_implicit along its end displacements under
    displacement control, each from its own last state: both finish every load step (the
    stick/slip reversals of unloading included); the other methods are skipped, their
    variants not being among those the tests compile."""
    _, summary, _, _, _ = report
    path = summary["paths"][0]
    assert path["control"] == "displacement" and "failed" not in path["static"]
    assert len(path["static"]["end_displacement_m"]) == len(path["values"])
    for name, method in path["methods"].items():
        if name in ("kinetic", "semi_implicit"):
            assert method["verdict"] == "converged", method.get("message")
            assert len(method["time_steps"]) == len(path["values"])
        else:
            assert method["verdict"] == "skipped" and method["message"]


def test_the_map_marks_a_case_whose_relaxation_fails_at_the_measured_dt():
    """A friction case can be energy-stable at a dt where its relaxation still fails: the map
    must say so on the figure (a cross and a label), not only in a footnote."""
    def case(name, verdict):
        return {"case": name, "family": "friction",
                "stability": {"predicted_dt_s": 1e-6, "measured_dt_s": 1.5e-5,
                              "measured_over_predicted": 15.0, "measured_with": "viscous damping",
                              "relaxation_at_measured_dt": {"verdict": verdict}}}

    def crosses(figure):
        return [line for ax in figure.axes for line in ax.lines if line.get_marker() == "x"]

    failing = plot_map([case("stick", "failed")], QUICK)
    texts = [t.get_text() for ax in failing.axes for t in ax.texts]
    assert len(crosses(failing)) == 2 and "relaxation fails at this dt" in texts
    assert not crosses(plot_map([case("stick", "converged")], QUICK))
