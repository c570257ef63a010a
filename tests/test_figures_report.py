"""`dynfab figures --quick`: what its data and figures show, not only that files exist.

The quick report solves the paper yarns cut to 4 crossings (L = 25 mm, N = 56, the same
weft and crossing spacing, prestressed) to 2.5 mm (10 % strain, as the paper's 10 mm on
100 mm) in 20 steps, statically and dynamically. Every check below reads the figure data
back from the four HDF5 result files and recomputes the quantity here, independently of
the report's code; the report's JSON must agree with it.

Thresholds (the same as the report's, dynfab/reports/figures.py `check_trends`):

* orderings (K, friction) must hold at every load step by more than the largest
  static-vs-dynamic end-force difference, so that they are not solver noise;
* saturation of the contact force: at most 10 % of its growth in the last quarter of
  the displacement (a growth linear in the displacement puts 25 % there; the quick report's
  trends.json: 2.4 to 3.1 %);
* the friction gap: up by >= 10 % from the first step to 5 % strain (the paper's 5 mm),
  then within 10 % of its 5 % value to the end ("nearly parallel"); at the end within 5 %
  of half the summed friction limits, its value for fully sliding crossings symmetric
  about the middle under displacement control (the data: 0.1 %).

Static against dynamic: |x_dyn - x_static|_inf <= ||J^-1||_inf (r_dyn + r_static) at
every step and yarn, with ||J^-1||_inf computed here exactly from the dense matrix
(numpy inverse) of the step's Jacobian on the free dofs (the Hessian; with friction the
coupled friction Jacobian at the anchors the step started from). The quick friction yarn
slides at every crossing from the first step on, so the anchor term of the report's
bound (k_t |delta xi| at sticking crossings) is zero here; the test checks that too.
"""

from __future__ import annotations

import contextlib
import io
import json
import shutil
import time
from pathlib import Path

import numpy as np
import pytest
from matplotlib.image import imread
from matplotlib.text import Text

from dynfab.model import assembly
from dynfab.linalg.banded import to_dense
from dynfab.cli import main
from dynfab.errors import UserError
from dynfab.kernels.structure_variants import built_variants
from dynfab.model.builders import build_model
from dynfab.reports import figures as report
from dynfab.reports import figures_plots
from dynfab.results.file import read_results
from dynfab.scene import expand_sweep, load_scene, parse_scene_text
from dynfab.model.terms.friction import INDEX as FRICTION

RUNS = Path(__file__).resolve().parent.parent / "runs"
NAMES = ("fig3", "fig5")
SOLVERS = ("static", "dynamic")
PNGS = ("fig3a_traction.png", "fig3b_contact_force.png", "fig5_friction.png", "shapes.png",
        "friction_states.png")
ALLOWED_VARIANTS = {f"{kind}/{layout}/{order}/float64/{couplings}/planar"
                    for kind, layout, order in (("explicit", "grouped", "scatter"),
                                                ("passes", "-", "-"))
                    for couplings in ("no friction", "friction")}
"""What the dynamic tests already compile (`structure_variants.Variant.name`): the explicit
kernel (kinetic damping and displacement control are data), +-friction, and the one-pass
kernels of a step's end."""


@pytest.fixture(scope="module")
def quick(tmp_path_factory):
    """The quick report through the command line: (folder, summary, stdout, seconds, variants)."""
    out = tmp_path_factory.mktemp("figures")
    before = set(built_variants())
    stdout = io.StringIO()
    started = time.perf_counter()
    with contextlib.redirect_stdout(stdout):
        main(["figures", "--out", str(out), "--quick", "--quiet"])
    seconds = time.perf_counter() - started
    variants = {variant.name for variant in set(built_variants()) - before}
    return out, json.loads((out / "trends.json").read_text()), stdout.getvalue(), seconds, variants


@pytest.fixture(scope="module")
def files(quick):
    """The four result files read back: {(figure, solver): Results}."""
    out = quick[0]
    return {(name, solver): read_results(out / f"{name}_{solver}.h5")
            for name in NAMES for solver in SOLVERS}


def per_width(results):
    return results.steps["end_force"] / results.attrs["width_per_yarn"]


def k_order(results):
    scene = parse_scene_text(results.attrs["scene"])
    K = np.array([s.warp.kawabata_K for s in expand_sweep(scene)])
    return K, np.argsort(K)


def friction_yarns(results):
    """(index with friction, index without)."""
    scene = parse_scene_text(results.attrs["scene"])
    alpha = np.array([s.friction.alpha for s in expand_sweep(scene)])
    return int(np.argmax(alpha)), int(np.argmin(alpha))


def solver_noise(files, name):
    return np.abs(files[(name, "static")].steps["end_force"]
                  - files[(name, "dynamic")].steps["end_force"]).max()


# --------------------------------------------------------------------------
# Files, scenes and settings.


def test_the_command_writes_every_file_it_names(quick):
    out, summary, stdout, _, _ = quick
    names = {f"{n}_{s}.h5" for n in NAMES for s in SOLVERS} | set(PNGS) | {"trends.json"}
    names |= {f"{n}_{s}.xdmf" for n in NAMES for s in SOLVERS}  # each run's ParaView view
    assert {p.name for p in out.iterdir()} == names
    assert sorted(line.split()[-1] for line in stdout.splitlines()) == sorted(summary["files"])
    assert summary["quick"] and summary["plan"] == "quick"
    assert summary["reference_state"] == ["prestressed"]
    assert all(s["solved"] and s["reason"] == "missing" for s in summary["solves"])
    assert summary["all_trends_hold"]


def test_quick_scenes_are_the_paper_yarns_cut_to_four_crossings(files):
    for name, file in (("fig3", "paper_fig3.toml"), ("fig5", "paper_fig5.toml")):
        paper = load_scene(RUNS / file)
        for solver in SOLVERS:
            scene = parse_scene_text(files[(name, solver)].attrs["scene"])
            assert scene.geometry.crossings == 4 and scene.geometry.segments == 56
            assert scene.geometry.length / 4 == pytest.approx(paper.geometry.length / 16)
            assert scene.geometry.reference == paper.geometry.reference == "prestressed"
            assert scene.geometry.amplitude == paper.geometry.amplitude
            assert (scene.warp, scene.weft, scene.friction) == (paper.warp, paper.weft,
                                                                paper.friction)
            assert scene.sweep == paper.sweep
            assert scene.load.control == "displacement"
            assert np.allclose(scene.load.values, 2.5e-3 * np.arange(1, 21) / 20, rtol=1e-12)


def test_dynamic_files_use_the_default_quasi_static_settings_and_known_kernels(quick, files):
    *_, variants = quick
    for name in NAMES:
        attrs = files[(name, "dynamic")].attrs
        assert attrs["solver"] == "dynamic"
        assert (attrs["dynamic_mode"], attrs["dynamic_method"], attrs["dynamic_damping"],
                attrs["dynamic_masses"], attrs["dynamic_precision"]) == (
            "quasi_static", "explicit", "kinetic", "fictitious", "float64")
        assert attrs["dynamic_tolerance"] == 1e-8
        assert files[(name, "dynamic")].steps["residual"].max() <= 1e-8
        assert files[(name, "static")].steps["residual"].max() <= 1e-11
    # compile budget: nothing beyond what the dynamic tests compile
    assert variants <= ALLOWED_VARIANTS


# --------------------------------------------------------------------------
# The paper's trends, recomputed from the HDF5 files.


def test_fig3a_smaller_K_gives_a_stiffer_traction_curve(quick, files):
    _, summary, *_ = quick
    noise = solver_noise(files, "fig3")
    for solver in SOLVERS:
        results = files[("fig3", solver)]
        K, order = k_order(results)
        assert K[order].tolist() == [0.02, 0.2, 1.0]
        q = per_width(results)[:, order]
        gaps = q[:, :-1] - q[:, 1:]  # K = 0.02 above 0.2 above 1.0, at every step
        assert gaps.min() > noise / results.attrs["width_per_yarn"]
        # the K effect shrinks as the undulation is lost (paper, on Fig. 3a)
        spread = q[:, 0] - q[:, -1]
        assert spread[-1] <= 0.25 * spread.max()
        check = summary["trends"]["fig3a_smaller_K_stiffer"][solver]
        assert check["smallest_gap_N_per_m"] == pytest.approx(gaps.min(), rel=1e-12)
    assert summary["trends"]["fig3a_smaller_K_stiffer"]["passed"]
    assert summary["trends"]["fig3a_K_effect_shrinks"]["passed"]


def test_fig3b_contact_force_grows_and_saturates(quick, files):
    _, summary, *_ = quick
    for solver in SOLVERS:
        results = files[("fig3", solver)]
        _, order = k_order(results)
        R = results.steps["contact_force"].mean(axis=-1)[:, order]
        u = results.steps["end_displacement"][:, 0]
        assert (np.diff(R, axis=0) > 0).all()  # grows at every step
        for k in range(3):
            late = R[-1, k] - np.interp(0.75 * u[-1], u, R[:, k])
            assert late <= 0.10 * (R[-1, k] - R[0, k])  # saturates
        assert (R[:, :-1] > R[:, 1:]).all()  # the smaller K, the larger the contact force
        # the report's shares are the ones recomputed here (the same interpolation)
        shares = [(R[-1, k] - np.interp(0.75 * u[-1], u, R[:, k])) / (R[-1, k] - R[0, k])
                  for k in range(3)]
        assert summary["trends"]["fig3b_contact_force_grows_and_saturates"][solver][
            "last_quarter_share_of_growth"] == pytest.approx(shares, rel=1e-12)
    assert summary["trends"]["fig3b_contact_force_grows_and_saturates"]["passed"]


def test_fig5_friction_stiffens_and_the_gap_grows_then_stays_nearly_constant(quick, files):
    _, summary, *_ = quick
    noise = solver_noise(files, "fig5")
    for solver in SOLVERS:
        results = files[("fig5", solver)]
        on, off = friction_yarns(results)
        q = per_width(results)
        gap = q[:, on] - q[:, off]
        assert gap.min() > noise / results.attrs["width_per_yarn"]
        strain = results.steps["end_displacement"][:, on] / results.attrs["projected_length"]
        at_5 = np.interp(0.05, strain, gap)
        assert at_5 >= 1.10 * gap[0]
        assert abs(gap[-1] - at_5) <= 0.10 * at_5
        half_sum = 0.5 * results.steps["friction_limit"][-1, on].sum()
        assert gap[-1] == pytest.approx(half_sum / results.attrs["width_per_yarn"], rel=0.05)
        check = summary["trends"]["fig5_gap_grows_then_nearly_constant"][solver]
        assert check["gap_at_5_percent_N_per_m"] == pytest.approx(at_5, rel=1e-12)
    for name in ("fig5_friction_stiffens", "fig5_gap_grows_then_nearly_constant",
                 "fig5_gap_is_half_the_friction_limits"):
        assert summary["trends"][name]["passed"], name


# --------------------------------------------------------------------------
# Static against dynamic.


def dense_inverse_norm(yarn, positions, anchors, fixed):
    """||J^-1||_inf on the free dofs, from numpy's dense inverse."""
    band = assembly.tangent(positions, yarn, anchors, bool(yarn.active[FRICTION]))
    free = ~fixed
    return np.abs(np.linalg.inv(to_dense(band)[np.ix_(free, free)])).sum(axis=1).max()


@pytest.mark.parametrize("name", NAMES)
def test_static_and_dynamic_agree_within_residual_times_inverse_stiffness(quick, files, name):
    _, summary, *_ = quick
    static, dynamic = files[(name, "static")], files[(name, "dynamic")]
    model = build_model(parse_scene_text(static.attrs["scene"]))
    fixed = model.fixed_dofs()
    nodes = static.reference["crossing_nodes"]
    s, d = static.steps, dynamic.steps
    worst, norms = 0.0, []
    for i in range(s["load"].shape[0]):
        anchors = static.reference["positions"][:, nodes, 0] if i == 0 else s["anchors"][i - 1]
        if "friction" in model.terms and i > 0:
            # every crossing slides from the first step on: the anchors do not enter
            assert s["sliding"][i].all() and d["sliding"][i].all()
        for k, yarn in enumerate(model.yarns):
            norm = dense_inverse_norm(yarn, s["positions"][i, k],
                                      np.ascontiguousarray(anchors[k]), fixed)
            norms.append(norm)
            bound = norm * (s["residual"][i, k] + d["residual"][i, k])
            error = np.abs(s["positions"][i, k] - d["positions"][i, k]).max()
            assert error <= bound, (i, k, error, bound)
            worst = max(worst, error / bound)
    c = summary["static_vs_dynamic"][name]
    assert c["max_position_over_bound"] == pytest.approx(worst, rel=1e-6)
    assert c["inverse_stiffness_norm_m_per_N"]["max"] == pytest.approx(max(norms), rel=1e-9)
    assert c["within_bound"] and c["max_anchor_term_N"] == 0.0
    assert c["friction_state_mismatches"] == 0
    # The report's bound is the one the residual tolerances give (dynamic 1e-8 N, static
    # 1e-11 N, both checked above) with the norms computed here (to the 1e-9 agreement of
    # the LU and numpy inverses): nothing looser slips in. The end-force difference is
    # within its own bound, and the orderings of Fig. 3a and 5 are judged against it above.
    assert c["max_position_bound_m"] <= max(norms) * (1e-8 + 1e-11) * (1 + 1e-9)
    assert c["max_end_force_over_bound"] <= 1.0


# --------------------------------------------------------------------------
# Figures: from the files alone, readable, and showing the data.


def test_dynfab_plot_draws_the_standard_figures_of_every_report_file(quick, tmp_path):
    out = quick[0]
    for name in NAMES:
        for solver in SOLVERS:
            folder = tmp_path / f"{name}_{solver}"
            with contextlib.redirect_stdout(io.StringIO()):
                main(["plot", str(out / f"{name}_{solver}.h5"), "--out", str(folder)])
            written = {p.name for p in folder.iterdir()}
            assert {"traction.png", "contact_force.png", "shape.png"} <= written
            assert ("friction.png" in written) == (name == "fig5")


def test_the_figures_are_redrawn_from_the_files_and_a_current_file_is_not_solved_again(
        quick, tmp_path):
    out = quick[0]
    for path in out.glob("*.h5"):
        shutil.copy(path, tmp_path / path.name)
    written = figures_plots.draw_figures(tmp_path)
    assert sorted(p.name for p in written) == sorted(PNGS)
    (tmp_path / "fig5_dynamic.h5").write_bytes(b"not an HDF5 file")
    summary = report.run_figures(tmp_path, quick=True)
    reasons = {s["file"]: (s["solved"], s["reason"]) for s in summary["solves"]}
    assert reasons.pop("fig5_dynamic.h5")[0] is True
    assert all(solved is False and reason == "current" for solved, reason in reasons.values())
    assert read_results(tmp_path / "fig5_dynamic.h5").step_count == 20


def test_fig3a_draws_the_file_data_static_as_lines_and_dynamic_as_markers(files):
    fig = figures_plots.plot_fig3a(files)
    left = fig.axes[0]
    static, dynamic = files[("fig3", "static")], files[("fig3", "dynamic")]
    _, order = k_order(static)
    lines = [line for line in left.get_lines()]
    assert len(lines) == 6  # a line and a marker series per K
    strain = 100 * static.steps["end_displacement"] / static.attrs["projected_length"]
    for n, k in enumerate(order):
        line, markers = lines[2 * n], lines[2 * n + 1]
        assert line.get_linestyle() == "-" and markers.get_linestyle() == "None"
        assert np.array_equal(line.get_xdata(), strain[:, k])
        assert np.array_equal(line.get_ydata(), per_width(static)[:, k])
        assert np.array_equal(markers.get_ydata(), per_width(dynamic)[:, k])
    assert "prestressed" in fig.get_suptitle()


def test_fig3b_draws_the_mean_contact_force_of_each_K_from_the_files(files):
    ax = figures_plots.plot_fig3b(files).axes[0]
    static, dynamic = files[("fig3", "static")], files[("fig3", "dynamic")]
    _, order = k_order(static)
    lines = ax.get_lines()
    assert len(lines) == 6  # a line (static) and a marker series (dynamic) per K
    for n, k in enumerate(order):
        for line, results in ((lines[2 * n], static), (lines[2 * n + 1], dynamic)):
            assert np.array_equal(line.get_xdata(), 1e3 * results.steps["end_displacement"][:, k])
            assert np.array_equal(line.get_ydata(),
                                  1e3 * results.steps["contact_force"][:, k].mean(axis=-1))


def test_fig5_draws_both_curves_the_friction_gap_and_half_the_friction_limits(files):
    left, right = figures_plots.plot_fig5(files).axes
    static, dynamic = files[("fig5", "static")], files[("fig5", "dynamic")]
    on, off = friction_yarns(static)
    width = static.attrs["width_per_yarn"]
    left_lines = left.get_lines()
    for n, k in enumerate((on, off)):  # static line, dynamic markers: with, then without
        assert np.array_equal(left_lines[2 * n].get_ydata(), per_width(static)[:, k])
        assert np.array_equal(left_lines[2 * n + 1].get_ydata(), per_width(dynamic)[:, k])
    gap_static, gap_dynamic, half = right.get_lines()[:3]
    for line, results in ((gap_static, static), (gap_dynamic, dynamic)):
        q = per_width(results)
        assert np.array_equal(line.get_ydata(), q[:, on] - q[:, off])
    assert np.allclose(half.get_ydata(),
                       0.5 * static.steps["friction_limit"][:, on].sum(axis=1) / width,
                       rtol=1e-15, atol=0)


def test_every_figure_names_its_reference_state_and_uses_readable_fonts(files):
    for draw in (figures_plots.plot_fig3a, figures_plots.plot_fig3b, figures_plots.plot_fig5,
                 figures_plots.plot_shapes, figures_plots.plot_friction_states):
        fig = draw(files)
        assert "reference state: prestressed" in fig.get_suptitle()
        width, height = fig.get_size_inches()
        assert width in (3.5, 7.0) and height <= 7.0
        sizes = [t.get_fontsize() for t in fig.findobj(Text) if t.get_text().strip()]
        assert min(sizes) >= 8.0
        for ax in fig.axes:
            assert ax.get_xlabel()  # every axis says what it shows
            if ax.get_ylabel():
                assert "(" in ax.get_ylabel() or "crossing" in ax.get_ylabel()


def test_the_pngs_are_real_images(quick):
    out = quick[0]
    for name in PNGS:
        image = imread(out / name)
        height, width = image.shape[:2]
        assert width >= 650 and height >= 400, name  # >= 3.25 x 2 in at 200 dpi
        rgb = image[..., :3]
        assert rgb.std() > 0.05, name  # not blank
        coloured = (rgb.max(axis=-1) - rgb.min(axis=-1)) > 0.3
        assert coloured.mean() > 1e-3, name  # the coloured data are drawn
        packed = (np.round(255 * rgb).astype(np.int64) * [65536, 256, 1]).sum(axis=-1)
        assert np.unique(packed).size > 50, name  # anti-aliased lines, not flat blocks


def test_bad_output_folder_is_a_scene_error_and_exit_status_2(tmp_path, capsys):
    not_a_folder = tmp_path / "file.txt"
    not_a_folder.write_text("x")
    with pytest.raises(UserError, match="is a file, not a folder"):
        report.run_figures(not_a_folder, quick=True)
    with pytest.raises(SystemExit) as exit_info:
        main(["figures", "--out", str(not_a_folder), "--quick"])
    assert exit_info.value.code == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("dynfab: error:") and "\n" not in err
