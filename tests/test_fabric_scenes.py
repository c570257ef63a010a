"""The fabric scenes of runs/ run with `dynfab.run` and show their physics
(docs/model.md section 10).

Each scene runs through the run driver (the scene file, `FabricModel`, the Solver
adapter, the result file), the strip as a smaller copy (4 x 4 yarns, 3 steps), and each
test checks what the scene is for: the balanced cell's symmetry, the strip's crimp
interchange, the pull-out's friction plateau, and a resumed file equal to an
uninterrupted one.
"""

import re
from pathlib import Path

import h5py
import meshio
import numpy as np
import pytest

from dynfab.model.fabric.model import FabricModel
from dynfab.results.file import MACHINE_TIMES
from dynfab.run import run, run_to_file
from dynfab.scene import load_scene, parse_scene_text
from dynfab.model.structure import uniform
from independent import pullout_scene, pullout_text, record_inverse_norm

RUNS = Path(__file__).resolve().parent.parent / "runs"


def core_stiffness(model: FabricModel) -> float:
    """k_c [N/m], one for every crossing: dR/dg <= k_c (docs/model.md section 10)."""
    return float(uniform(model.structure.tie_contact_law)[0])


def solved(name: str):
    """(model, results) of runs/<name>.toml solved in memory."""
    scene = load_scene(RUNS / f"{name}.toml")
    return FabricModel.from_scene(scene), run(scene)


def position_bound(model: FabricModel, results, step: int = -1) -> float:
    """4 ||H^-1||_inf max(r, tolerance) [m]: how far a state with residual r may lie from the
    exact one, ||H^-1||_inf the step's record's (`record_inverse_norm`: its error_estimate,
    residual x est ||H^-1||_inf, over its residual; the F_T-frozen Hessian of its
    certificate). Factor 4 for the friction limit's coupling, as in
    tests/test_fabric_symmetry.py. Two states compared: twice this."""
    last = {name: values[step] for name, values in results.steps.items()}
    residual = float(last["residual"])
    return 4 * record_inverse_norm(last) * max(residual, model.scene.static.tolerance)


def test_balanced_cell_under_equal_loads_responds_alike_in_both_families():
    """(x, y, z) -> (y, x, -z) maps the balanced cell onto itself (docs/model.md section 10): at 1:1
    each weft is its warp mirrored in z, the strains and crimps equal, R symmetric."""
    model, results = solved("fabric_biaxial")
    steps = results.steps
    for i in range(results.step_count):
        tol = 2 * position_bound(model, results, i)
        np.testing.assert_allclose(steps["weft_positions"][i] * [1, -1], steps["positions"][i],
                                   rtol=0, atol=tol)
        assert abs(steps["strain"][i, 0] - steps["strain"][i, 1]) <= 2 * tol / model.warp.length
        np.testing.assert_allclose(steps["contact_force"][i], steps["contact_force"][i].T,
                                   rtol=0, atol=core_stiffness(model) * 2 * tol)
    assert np.all(np.diff(steps["strain"][:, 0]) > 0)  # it stretches as the load grows
    assert np.all(steps["stable"])


def test_swapping_the_load_ratio_swaps_the_families():
    """2:1 and 1:2 are each other's mirror image: strains swap, R transposes
    (docs/model.md section 10)."""
    model, two = solved("fabric_biaxial_2to1")
    _, half = solved("fabric_biaxial_1to2")
    np.testing.assert_array_equal(two.steps["load"], half.steps["load"][:, ::-1])
    for i in range(two.step_count):
        tol = position_bound(model, two, i) + position_bound(model, half, i)
        np.testing.assert_allclose(two.steps["strain"][i], half.steps["strain"][i, ::-1], rtol=0,
                                   atol=tol / model.warp.length)
        np.testing.assert_allclose(two.steps["contact_force"][i], half.steps["contact_force"][i].T,
                                   rtol=0, atol=core_stiffness(model) * tol)
    # the more loaded family stretches more, and its crimp falls below the other's
    assert np.all(two.steps["strain"][:, 0] > two.steps["strain"][:, 1])
    assert np.all(two.steps["crimp"][:, 0] < two.steps["crimp"][:, 1])


def small_strip() -> str:
    """runs/fabric_strip.toml as a 4 x 4 patch of the same yarns (segment length kept), 3 steps."""
    text = (RUNS / "fabric_strip.toml").read_text()
    for old, new in (("length = 0.1", "length = 0.025"), ("segments = 224", "segments = 56"),
                     ("crossings = 16", "crossings = 4"), ("count = 16", "count = 4"),
                     ("steps = 10", "steps = 3")):
        assert old in text, old
        text = text.replace(old, new)
    return text


def test_strip_shows_crimp_interchange():
    """Warps pulled, weft ends free: the warps decrimp, which pushes the wefts into more crimp,
    and the free wefts shorten (docs/model.md section 10, the fabric's crimp interchange)."""
    scene = parse_scene_text(small_strip())
    results = run(scene)
    steps = results.steps
    as_woven = FabricModel.from_scene(scene).initial_state()
    crimp0 = FabricModel.from_scene(scene).crimps(as_woven.positions)
    crimp = np.vstack([crimp0, steps["crimp"]])
    assert np.all(np.diff(crimp[:, 0]) < 0) and np.all(np.diff(crimp[:, 1]) > 0)
    assert np.all(steps["strain"][:, 0] > 0) and np.all(np.diff(steps["strain"][:, 1]) < 0)
    assert np.all(steps["end_force"][:, :4] == steps["load"][:, :1])  # force control: P
    assert np.all(steps["end_force"][:, 4:] == 0.0)  # the weft ends free
    assert np.all(steps["stable"])
    # loads per unit width (docs/model.md section 10): P over the wefts' pitch, 0 on the wefts
    np.testing.assert_array_equal(steps["stress"][:, 0],
                                  steps["load"][:, 0] / results.attrs["width_per_yarn"])
    assert np.all(steps["stress"][:, 1] == 0.0)


def test_friction_does_nothing_in_the_uniformly_strained_strip():
    """runs/fabric_strip.toml's friction is inert, as its comments and the README say
    (docs/model.md section 10, what friction does in a patch): with affine planes and every
    warp under the same load the clamped patch is the periodic cell repeated (its ends at
    inflection points, as the cell's pinned node 0), so each crossing lies on its yarns'
    mirror planes and its exact slip is zero, loading and unloading. The computed slips
    are then the solver's position error: each node within b = position_bound of the
    exact state, each plane X_j = (j - 1/2)(L + u)/n_we within b too, so |s| <= 2 b per
    direction and |F| <= 2 sqrt(2) k_t b, far below every friction limit: nothing slides and
    nothing is dissipated. No edge effect either: the strains are the periodic cell's (the
    same yarns, no friction) within both states' bounds over the length."""
    text = re.sub(r"^max = 1\.0\nsteps = 3$", "values = [0.3, 0.6, 0.2]", small_strip(),
                  flags=re.M)
    scene = parse_scene_text(text)
    # what the scene (its title, on every figure) and the README's scene list say is what
    # this test checks
    readme = (RUNS.parent / "README.md").read_text()
    row = next(line for line in readme.splitlines() if line.startswith("| `runs/fabric_strip"))
    assert "friction inert (no crossing slips)" in scene.title
    assert "friction is inert: no crossing slips" in row and "friction on" not in row
    model, results = FabricModel.from_scene(scene), run(scene)
    steps, k_t = results.steps, model.structure.tie_friction_law[0, 3]
    assert not steps["sliding"].any() and np.all(steps["dissipated"] == 0.0)
    for i in range(results.step_count):
        bound = 2 * np.sqrt(2) * k_t * position_bound(model, results, i)
        closed = steps["friction_limit"][i] > 0
        assert closed.all() and bound < 0.01 * steps["friction_limit"][i].min()  # a real test
        assert np.linalg.norm(steps["friction_force"][i], axis=-1).max() <= bound
    cell_text = (RUNS / "fabric_biaxial.toml").read_text()
    cell_text = re.sub(r"^weft_values = .*$", "weft_values = [0, 0, 0]", cell_text, flags=re.M)
    cell_text = re.sub(r"^values = .*$", "values = [0.3, 0.6, 0.2]", cell_text, flags=re.M)
    cell_model, cell = FabricModel.from_scene(parse_scene_text(cell_text)), run(
        parse_scene_text(cell_text))
    for i in range(results.step_count):
        # a strain is an end displacement (each within its state's b) over the length
        tol = (position_bound(model, results, i) / model.warp.length
               + position_bound(cell_model, cell, i) / cell_model.warp.length)
        np.testing.assert_allclose(steps["strain"][i], cell.steps["strain"][i], rtol=0, atol=tol)


def test_pullout_is_resisted_by_the_friction_of_the_pressed_crossings():
    """Stage 1 (weft ends pulled) presses the crossings, which carry no force as woven; in
    stage 2 the pulled warp's end force is the friction on its crossings (its x-equilibrium:
    internal forces cancel, contact acts in z), at most their sum of limits; it rises while
    the slip front runs along the warp, and once all slide it stays at that sum: the peak is
    a plateau (tests/test_fabric_pullout.py's argument)."""
    scene = pullout_scene()  # its crossings fixed pairs of nodes, to the peak
    model, results = FabricModel.from_scene(scene), run(scene)
    steps, k = results.steps, scene.pullout.warp - 1
    nodes = model.warp.segments + 1
    stage1 = steps["load"][:, 0] == 0.0
    assert np.all(np.diff(steps["contact_force"][stage1, k].min(axis=1)) > 0)
    assert steps["contact_force"][stage1][-1, k].min() > 0
    for i in np.flatnonzero(~stage1):
        pull = steps["end_force"][i, k]
        tolerance = nodes * max(float(steps["residual"][i]), model.scene.static.tolerance)
        assert abs(pull + steps["friction_force"][i, k, :, 0].sum()) <= tolerance
        assert 0 < pull <= steps["friction_limit"][i, k].sum() + tolerance
    # the warp strain is the pulled warp's (the held warps are not loaded, docs/model.md section 10)
    np.testing.assert_allclose(steps["strain"][~stage1, 0],
                               steps["load"][~stage1, 0] / model.warp.length, rtol=1e-12)
    last = steps["sliding"][~stage1][-5:, k]
    assert last.all()
    # the load per unit width of the warps is the pulled warp's (docs/model.md section 10)
    np.testing.assert_array_equal(steps["stress"][:, 0],
                                  steps["end_force"][:, k] / results.attrs["width_per_yarn"])
    # the scene stays where the model holds: no crossing node past half its segment
    assert np.all(steps["slip_ratio"] <= 0.5) and steps["slip_ratio"][-1] > 0.1
    # the plateau is the friction of the pressed crossings, not zero
    assert steps["end_force"][-1, k] > 0.5 * steps["friction_limit"][-1, k].sum()
    # Through the slip front to the peak: every crossing slides along the warp at the last
    # step, so the pull is sum_j F_T,j, short of it by the slip's leftover y-part: the slip
    # after a radial return has length F_T/k_t, and the last step moved it dU along x, so
    # 1 - cos(angle to x) <= 1/2 (c / (dU - c))^2 with c = max F_T / k_t.
    c = steps["friction_limit"][-1, k].max() / uniform(model.structure.tie_friction_law)[3]
    dU = steps["load"][-1, 0] - steps["load"][-2, 0]
    last = steps["friction_limit"][-1, k].sum()
    tolerance = nodes * max(float(steps["residual"][-1]), model.scene.static.tolerance)
    assert abs(steps["end_force"][-1, k] - last) <= tolerance + 0.5 * last * (c / (dU - c)) ** 2
    # before it, the force rises through the steps of the front (stick to slip)
    rising = steps["end_force"][~stage1, k]
    assert np.all(np.diff(rising[:10]) > 0) and rising[0] < 0.9 * last


def run_interrupted(scene, solver: str, out, steps: int = 4) -> None:
    """`run_to_file` into `out`, interrupted (KeyboardInterrupt, as a Ctrl-C) once its
    progress line reports load step `steps`."""
    def stop_after(line: str) -> None:
        if line.lstrip("[ ").startswith(f"{steps}/"):
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        run_to_file(scene, solver, out, progress=stop_after)


def assert_same_steps(whole, part) -> None:
    """Every steps/ dataset of two result files equal, entry for entry (but the machine's times,
    `MACHINE_TIMES`)."""
    with h5py.File(whole, "r") as a, h5py.File(part, "r") as b:
        for name in a["steps"]:
            if isinstance(a["steps"][name], h5py.Dataset) and name not in MACHINE_TIMES:
                np.testing.assert_array_equal(a["steps"][name][:], b["steps"][name][:],
                                              err_msg=name)


def test_fabric_file_resumes_to_the_uninterrupted_run(tmp_path):
    """A run stopped after 4 steps and resumed equals the run done in one go, entry for
    entry; its XDMF view holds both families' grids for every step."""
    scene = load_scene(RUNS / "fabric_biaxial_2to1.toml")
    whole, part = tmp_path / "whole.h5", tmp_path / "part.h5"
    run_to_file(scene, "static", whole)
    run_interrupted(scene, "static", part)
    with h5py.File(part, "r") as h5:
        assert int(h5["steps_done"][0]) == 4
    assert run_to_file(scene, "static", part, resume=True) == 6
    assert_same_steps(whole, part)
    from dynfab.plots.figures import plot_results
    assert [p.name for p in plot_results(part, tmp_path / "plots")] == ["fabric.png", "shape.png"]
    with meshio.xdmf.TimeSeriesReader(part.with_suffix(".xdmf")) as view, \
            h5py.File(part, "r") as h5:  # plain meshio: both families' nodes, every step
        points, _ = view.read_points_cells()
        assert view.num_steps == 10
        warp_nodes, weft_nodes = h5["reference/positions"].size // 2, \
            h5["reference/weft_positions"].size // 2
        assert points.shape == (warp_nodes + weft_nodes, 3)
        position = view.read_data(9)[1]["position"]
        np.testing.assert_array_equal(position[warp_nodes:, 1:],
                                      h5["steps/weft_positions"][9].reshape(-1, 2))


def test_pullout_figure_draws_the_file(tmp_path):
    """`dynfab plot` on a pull-out draws the pull force, the sum of the limits and each
    crossing's |F_x| / F_T from the file's datasets, recomputed here."""
    from dynfab.plots.figures import plot_pullout, plot_results
    from dynfab.results.file import read_results

    scene = parse_scene_text(small_pullout())
    path = tmp_path / "pullout.h5"
    run_to_file(scene, "static", path)
    assert [p.name for p in plot_results(path, tmp_path)] == ["fabric.png", "shape.png",
                                                              "pullout.png"]
    results, k = read_results(path), scene.pullout.warp - 1
    steps = results.steps
    force_ax, front_ax = plot_pullout(results).axes[:2]
    force, bound = force_ax.get_lines()[:2]
    assert force.get_label().startswith(f"pull force on warp {k + 1}")
    np.testing.assert_array_equal(force.get_ydata(), 1e3 * np.append(0, steps["end_force"][:, k]))
    np.testing.assert_array_equal(force.get_xdata(),
                                  1e3 * np.append(0, steps["end_displacement"][:, k]))
    np.testing.assert_array_equal(bound.get_ydata(),
                                  1e3 * steps["friction_limit"][:, k].sum(axis=1))
    limit = steps["friction_limit"][:, k]
    share = np.abs(steps["friction_force"][:, k, :, 0]) / np.where(limit > 0, limit, np.inf)
    np.testing.assert_allclose(front_ax.get_images()[0].get_array(), share.T, rtol=1e-15)


def small_pullout(values: str = "0, 0, 5e-5, 1e-4, 1.5e-4") -> str:
    """runs/fabric_pullout.toml as a 4 x 4 patch (half the length, the same segment length
    of 0.446 mm), warp 2 pulled to 0.15 mm (`values`) after two steps of weft stretching
    to 0.1 mm (0.4 %, the scene's strain), within half a segment (docs/model.md section 10,
    crossings at fixed nodes)."""
    text = pullout_text()  # the crossings fixed pairs of nodes
    for old, new in (("segments = 112", "segments = 56"), ("crossings = 8", "crossings = 4"),
                     ("count = 8", "count = 4"), ("warp = 4", "warp = 2"),
                     ("length = 0.05", "length = 0.025")):
        text = text.replace(old, new)
    count = len(values.split(","))
    text = re.sub(r"^values = .*$", f"values = [{values}]", text, flags=re.M)
    wefts = ", ".join(["5e-5"] + ["1e-4"] * (count - 1))
    return re.sub(r"^weft_values = .*$", f"weft_values = [{wefts}]", text, flags=re.M)


@pytest.mark.parametrize("solver", ["static", "dynamic"])
def test_a_pull_past_half_a_segment_stops_naming_the_crossing(tmp_path, solver):
    """A crossing is a fixed pair of nodes: once the pulled warp's node has slid past half
    a segment from a weft's plane another node is nearer that crossing, so the step stops
    (SolverError, exit status 3) naming the crossing, with either solver; the finished
    steps are kept, each within the limit (docs/model.md section 10)."""
    from dynfab.errors import SolverError
    from dynfab.results.file import read_results

    scene = parse_scene_text(small_pullout("0, 0, 1e-4, 3e-4"))
    out = tmp_path / "past.h5"
    with pytest.raises(SolverError, match=r"^load step 4/4 \(load 0\.0003 0\.0001 m\): "
                                          r"crossing \(warp 2, weft \d\): warp 2's node there "
                                          r"has slid 0\.\d+ of its segment"):
        run_to_file(scene, solver, out)
    kept = read_results(out).steps
    assert kept["load"].shape[0] == 3 and np.all(kept["slip_ratio"] <= 0.5)


def test_the_pullout_reports_the_pulled_warp(tmp_path):
    """What a pull-out prints says whose each number is, and shows the pulled warp: its end
    displacement and pull force in the progress line and the table, the peak pull force in
    the summary, not a mean over the warps or the largest end displacement of all yarns
    (a weft's); fabric.png's warp curve is the pulled warp's, labelled so."""
    import io

    from dynfab.plots.figures import plot_fabric
    from dynfab.results.summary import print_summary

    scene, lines = parse_scene_text(small_pullout()), []
    results = run(scene, progress=lines.append)
    steps, k = results.steps, scene.pullout.warp - 1
    for line, u, force in zip(lines, steps["end_displacement"][:, k], steps["end_force"][:, k]):
        shown = re.search(r"warp 2 \(pulled\): end displacement (\S+) mm, pull force (\S+) N",
                          line)
        assert shown is not None, line
        assert float(shown[1]) == pytest.approx(1e3 * u, abs=5e-5)
        assert float(shown[2]) == pytest.approx(force, rel=5e-4)
    # a weft's end displacement is the largest in stage 1: the line is not the largest
    assert np.any(steps["end_displacement"].max(axis=1) > steps["end_displacement"][:, k])
    table = io.StringIO()
    print_summary(results, table)
    text = table.getvalue()
    assert "P w2 [N]" in text.splitlines()[0] and "P_wa" not in text
    for row, force in zip(text.splitlines()[1:], steps["end_force"][:, k]):
        assert f"{force:.4g}" in row.split()
    peak = int(np.argmax(steps["end_force"][:, k]))
    assert (f"pull-out of warp 2: peak pull force {steps['end_force'][peak, k]:.6g} N at step "
            f"{peak + 1}") in text
    warp_line = plot_fabric(results).axes[0].get_lines()[0]
    assert warp_line.get_label() == "warp 2 (pulled)"
    width = results.attrs["width_per_yarn"]
    np.testing.assert_array_equal(warp_line.get_ydata(),
                                  np.append(0, steps["end_force"][:, k]) / width)


def test_dynamic_fabric_run_equals_the_static_one_within_their_residual_bounds():
    """`--solver dynamic` on a fabric relaxes each step with the Warp kernels: its positions
    lie within its position_bound of the exact equilibrium, as the static solver's within
    theirs (each run's residual), so the two differ by at most the sum; both see the same
    crossings slide (docs/model.md sections 6, 10)."""
    scene = parse_scene_text(small_pullout())
    model = FabricModel.from_scene(scene)
    static, dynamic = run(scene, "static"), run(scene, "dynamic")
    assert dynamic.attrs["solver"] == "dynamic"
    for i in range(static.step_count):
        tol = position_bound(model, static, i) + position_bound(model, dynamic, i)
        for name in ("positions", "weft_positions"):
            np.testing.assert_allclose(dynamic.steps[name][i], static.steps[name][i],
                                       rtol=0, atol=tol)
        np.testing.assert_array_equal(dynamic.steps["sliding"][i], static.steps["sliding"][i])
    assert static.steps["sliding"][-1].any()  # friction is really at work


def test_the_dynamic_fabric_solver_runs_the_periodic_cell():
    """`--solver dynamic` on the periodic cell (its planes and cell lengths moving with the
    load, docs/model.md section 10): every step within both runs' residual bounds of the static
    one, the planes where the static run puts them."""
    scene = load_scene(RUNS / "fabric_biaxial_2to1.toml")
    model, static = solved("fabric_biaxial_2to1")
    dynamic = run(scene, "dynamic")
    assert dynamic.attrs["solver"] == "dynamic" and dynamic.step_count == static.step_count
    for i in range(static.step_count):
        tol = position_bound(model, static, i) + position_bound(model, dynamic, i)
        for name in ("positions", "weft_positions", "warp_planes", "weft_planes"):
            np.testing.assert_allclose(dynamic.steps[name][i], static.steps[name][i],
                                       rtol=0, atol=tol)


def test_a_fabric_step_whose_bound_exceeds_its_accuracy_stops_with_exit_3(tmp_path):
    """The honest stop (docs/model.md, "Stability and accuracy of a converged step"): a
    fabric step is held to error_estimate <= accuracy x its largest displacement, as a
    yarn's. At --accuracy 1e-12 no step of the small strip can pass (its bound,
    residual x ||H^-1||_inf, is far above 1e-12 of its displacements): exit status 3, one
    line naming the yarn and node where the bound is largest and what to change; no step
    finished. At the default the same scene runs (test_strip_shows_crimp_interchange)."""
    import subprocess
    import sys

    path, out = tmp_path / "strip.toml", tmp_path / "strip.h5"
    path.write_text(small_strip())
    done = subprocess.run([sys.executable, "-m", "dynfab.cli", "run", str(path), "--out",
                           str(out), "--accuracy", "1e-12", "--quiet"],
                          capture_output=True, text=True)
    assert done.returncode == 3, done.stderr
    lines = done.stderr.strip().splitlines()
    assert len(lines) == 1, lines
    assert re.match(r"dynfab: error: load step 1/3 \(load 0\.333\d* 0 N\): fabric \((warp|weft) "
                    r"\d, node \d+: where the bound is largest\): the residual .* N \(tolerance "
                    r"1e-11 N\) leaves a position error up to .* m \(residual x \|\|H\^-1\|\|_inf "
                    r"= .* m/N\), above static\.accuracy = 1e-12 of the step's largest "
                    r"displacement .* m: tighten the tolerance to below .* N, or loosen "
                    r"static\.accuracy; the 0 finished steps are kept$", lines[0]), lines[0]


def test_dynfab_run_on_a_fabric_scene_from_the_command_line(tmp_path):
    """The command a user types: exit 0, the fabric's summary table, the file and its view;
    the wefts of the view lie in the planes x = X_j = (j - 1/2) L / n_we
    (docs/model.md section 10)."""
    import subprocess
    import sys

    out = tmp_path / "cell.h5"
    done = subprocess.run([sys.executable, "-m", "dynfab.cli", "run",
                           str(RUNS / "fabric_biaxial.toml"), "--out", str(out)],
                          capture_output=True, text=True)
    assert done.returncode == 0, done.stderr
    assert_fabric_summary(done.stdout, out)
    scene = load_scene(RUNS / "fabric_biaxial.toml")
    n_wa, n_we = scene.weft.count, scene.geometry.crossings
    N, M = scene.geometry.segments, scene.weft.segments
    with meshio.xdmf.TimeSeriesReader(out.with_suffix(".xdmf")) as view:  # plain meshio
        points, _ = view.read_points_cells()
    x = points[n_wa * (N + 1):, 0]  # the wefts follow the warps
    expected = np.repeat((np.arange(n_we) + 0.5) * scene.geometry.length / n_we, M + 1)
    np.testing.assert_allclose(x, expected, rtol=1e-15)
    relaxed = subprocess.run([sys.executable, "-m", "dynfab.cli", "run",
                              str(RUNS / "fabric_biaxial.toml"), "--out", str(out),
                              "--overwrite", "--solver", "dynamic"], capture_output=True, text=True)
    assert relaxed.returncode == 0, relaxed.stderr
    assert_fabric_summary(relaxed.stdout, out)


def assert_fabric_summary(stdout: str, out) -> None:
    """A fabric run's stdout: the table (a row per step, the columns saying they are the
    families' means) and the run's summary: its steps, the solver time and the last step's
    strains and loads per unit width, as the file holds them (docs/model.md section 10)."""
    from dynfab.results.file import read_results

    steps = read_results(out).steps
    count = steps["load"].shape[0]
    lines = stdout.strip().splitlines()
    assert "strain wa" in lines[0] and "N_wa [N/m]" in lines[0]
    assert [line.split()[0] for line in lines[1:count + 1]] == [str(i + 1) for i in range(count)]
    assert "mean strain and load per unit width over its loaded yarns" in lines[count + 1]
    assert lines[count + 2] == (f"{count} load steps, {steps['wall_time'].sum():.3f} s in the "
                                f"solver")
    strain, stress = 100 * steps["strain"][-1], steps["stress"][-1]
    assert lines[count + 3].startswith(
        f"last step: mean strain {strain[0]:.5g} %, {strain[1]:.5g} % and load per unit width "
        f"{stress[0]:.6g}, {stress[1]:.6g} N/m (warp, weft: means over each family's loaded")


@pytest.mark.parametrize("table", ['damping = "viscous"\ndamping_coefficient = 0.01',
                                   'damping = "viscous"', 'masses = "physical"'],
                         ids=["viscous-given", "viscous-adaptive", "physical-masses"])
def test_a_dynamic_setting_of_the_scene_relaxes_to_the_static_solution(table):
    """Explicit with viscous damping (c given, or Underwood's adaptive c) or physical masses
    (settings the fabric's dynamic runs once refused, now the one dynamic solver's): the first
    two steps of the small pull-out agree with the static solver within twice
    position_bound, as the kinetic relaxation does
    (test_dynamic_fabric_run_equals_the_static_one...)."""
    text = small_pullout("0, 1e-4")
    scene = parse_scene_text(text + f"\n[dynamic]\n{table}\n")
    model = FabricModel.from_scene(parse_scene_text(text))
    static, dynamic = run(parse_scene_text(text), "static"), run(scene, "dynamic")
    assert dynamic.attrs["dynamic_damping"] == scene.dynamic.damping_used()
    assert dynamic.attrs["dynamic_masses"] == scene.dynamic.masses_used()
    for i in range(static.step_count):
        tol = position_bound(model, static, i) + position_bound(model, dynamic, i)
        np.testing.assert_allclose(dynamic.steps["positions"][i], static.steps["positions"][i],
                                   rtol=0, atol=tol)


@pytest.mark.parametrize("key", ["static.accuracy", "dynamic.accuracy"])
def test_a_fabric_holds_its_steps_to_the_accuracy_key(key):
    """[static] and [dynamic] accuracy are a fabric's keys too (its steps carry an error
    bound, steps/error_estimate): written in the scene text a result file stores, and the
    solver that reads it stops a step whose bound exceeds it (SolverError, exit 3 at the
    command line), naming the key."""
    from dynfab.errors import SolverError
    from dynfab.scene import scene_to_toml

    table, name = key.split(".")
    scene = parse_scene_text(small_strip() + f"\n[{table}]\n{name} = 1e-12\n")
    assert getattr(getattr(scene, table), name) == 1e-12
    assert f"{name} = 1e-12" in scene_to_toml(scene)
    with pytest.raises(SolverError, match=rf"^load step 1/3 .*: fabric \((warp|weft) \d, node "
                                          rf"\d+: where the bound is largest\): .* above {key} "
                                          rf"= 1e-12 of"):
        run(scene, table)