"""A folded yarn is outside the model (docs/model.md, what the model is not): `dynfab run`
stops the step with exit status 3 instead of writing a mirrored yarn as a result."""

from pathlib import Path

import h5py
import numpy as np
import pytest

from dynfab.cli import main
from dynfab.model.domain import first_fold

RUNS = Path(__file__).resolve().parents[1] / "runs"


def chains(x_of_yarn):
    """(yarns, nodes, 2) chains with the given in-plane coordinates and z = 0."""
    x = np.asarray(x_of_yarn, float)
    return np.stack([x, np.zeros_like(x)], axis=-1)


def test_first_fold_names_the_first_segment_that_points_back():
    assert first_fold(chains([[0.0, 1.0, 2.0], [0.0, 0.5, 1.0]])) is None
    assert first_fold(chains([[0.0, 1.0, 2.0], [0.0, 0.5, 0.4]])) == (1, 1, pytest.approx(-0.1))
    assert first_fold(chains([[0.0, 0.0, 1.0]])) == (0, 0, 0.0)  # a vertical segment: 90 deg
    assert first_fold(chains([[0.0, np.nan, 1.0]]))[:2] == (0, 0)  # never a silent NaN


def compressed_yarn(tmp_path) -> Path:
    """The paper yarn, as woven, under force control -0.01 N then -0.1 N (section 7)."""
    text = (RUNS / "relax.toml").read_text()
    text = text[:text.index("[dynamic]")]
    text = text.replace('reference = "prestressed"', 'reference = "as_woven"')
    text = text.replace("values = [0.0]", "values = [-0.01, -0.1]")
    path = tmp_path / "compressed.toml"
    path.write_text(text)
    return path


def test_a_yarn_compressed_until_it_folds_stops_the_run_with_status_3(tmp_path, capsys):
    """At -0.1 N the static solver converges to the yarn mirrored through its first node
    (stable: the springs are blind to the mirror); the run keeps step 1 and stops."""
    out = tmp_path / "out.h5"
    with pytest.raises(SystemExit) as stop:
        main(["run", str(compressed_yarn(tmp_path)), "--out", str(out), "--quiet"])
    assert stop.value.code == 3
    error = capsys.readouterr().err
    assert "load step 2/2" in error and "yarn 1 (s=+1) folded back at segment" in error
    with h5py.File(out, "r") as h5:
        assert int(h5["steps_done"][0]) == 1
        assert first_fold(h5["steps/positions"][0]) is None


def test_a_fabric_cell_compressed_both_ways_stops_naming_a_warp(tmp_path, capsys):
    text = (RUNS / "fabric_biaxial.toml").read_text()
    lines = [("values = [-0.5]" if line.startswith("values =") else
              "weft_values = [-0.5]" if line.startswith("weft_values =") else line)
             for line in text.splitlines()]
    scene = tmp_path / "cell.toml"
    scene.write_text("\n".join(lines) + "\n")
    with pytest.raises(SystemExit) as stop:
        main(["run", str(scene), "--out", str(tmp_path / "cell.h5"), "--quiet"])
    assert stop.value.code == 3
    assert "warp 1 folded back at segment" in capsys.readouterr().err


def test_a_fit_path_that_folds_the_yarn_is_refused(tmp_path):
    """The fit's path solve (`dynfab.fitting.sensitivity.solve_path`) applies the same check: the
    compressed yarn's second step raises SolverError naming the fold, so a fit rejects such
    a trial point (and refuses such a start) instead of fitting a mirrored yarn."""
    from dynfab.errors import SolverError
    from dynfab.scene import load_scene
    from dynfab.fitting.sensitivity import solve_path

    with pytest.raises(SolverError, match="the yarn folded back at segment"):
        solve_path(load_scene(compressed_yarn(tmp_path)))


def test_a_slip_ratio_above_one_half_means_another_node_is_nearer_the_crossing():
    """`slip_ratios` (docs/model.md section 10, crossings at fixed nodes) against its meaning:
    on random increasing chains and planes, a crossing node's ratio is at most 1/2 exactly
    when no other node of its yarn is nearer the crossing yarn's plane."""
    from dynfab.model.domain import slip_ratios

    rng = np.random.default_rng(7)
    x = np.cumsum(rng.uniform(0.5, 1.5, size=(200, 12)), axis=1)
    nodes = np.array([3, 8])
    planes = x[:, nodes] + rng.uniform(-1.6, 1.6, size=(200, 2))
    ratios = slip_ratios(chains(x), nodes, planes)
    nearest = np.stack([np.argmin(np.abs(x - planes[:, [c]]), axis=1) for c in range(2)], axis=1)
    assert np.array_equal(ratios <= 0.5, nearest == nodes)
    assert np.all(slip_ratios(chains(x), nodes, x[:, nodes]) == 0.0)  # on its plane: 0


def test_the_one_yarn_model_records_its_slip_ratio_and_runs_on():
    """The one-yarn model's crossing nodes slide against a weft fixed at their as-woven x
    (docs/model.md section 4): `steps/slip_ratio` (steps, yarns) records the largest ratio,
    and the paper's scenes, whose crossings ride on their nodes past half a segment (Fig.
    5's at 0.5 mm of its 10 mm pull), run on (docs/model.md section 10)."""
    from dynfab.model.domain import slip_ratios
    from dynfab.run import run
    from dynfab.scene import parse_scene_text

    text = (RUNS / "paper_fig5.toml").read_text().replace("max = 0.01\nsteps = 40",
                                                          "values = [0.00025, 0.0005]")
    results = run(parse_scene_text(text))
    steps, nodes = results.steps, results.reference["crossing_nodes"]
    assert steps["slip_ratio"].shape == (2, 2) and steps["slip_ratio"][-1].min() > 0.5
    for i in range(2):
        expected = slip_ratios(steps["positions"][i], nodes,
                               results.reference["positions"][:, nodes, 0]).max(axis=1)
        np.testing.assert_array_equal(steps["slip_ratio"][i], expected)
    np.testing.assert_array_equal(steps["stress"],
                                  steps["end_force"] / results.attrs["width_per_yarn"])


def test_a_stopped_run_keeps_its_stop_in_the_file_and_resume_says_so(tmp_path, capsys):
    """The stop the file remembers (exit 3): its message, step and status in the file's root
    attributes; the summary of the finished steps printed before the error line; --resume
    names the recorded stop and does not run into it again."""
    from dynfab.results.file import read_results

    scene, out = compressed_yarn(tmp_path), tmp_path / "out.h5"
    with pytest.raises(SystemExit) as stop:
        main(["run", str(scene), "--out", str(out)])
    assert stop.value.code == 3
    captured = capsys.readouterr()
    error_line = captured.err.strip().splitlines()[-1]
    assert error_line.startswith("dynfab: error: load step 2/2") and "folded back" in error_line
    assert "step" in captured.out and "1 load step" in captured.out  # the table, the summary
    attrs = read_results(out).attrs
    assert attrs["stop_step"] == 2 and attrs["stop_exit_status"] == 3
    assert attrs["stop_message"].startswith("load step 2/2") and "folded back" in attrs[
        "stop_message"]
    with pytest.raises(SystemExit) as resumed:
        main(["run", str(scene), "--out", str(out), "--resume", "--quiet"])
    assert resumed.value.code == 3
    line = capsys.readouterr().err.strip()
    assert "\n" not in line and f"'{out}' stopped at entry 2 when it was run" in line
    assert "would stop there again" in line
    with h5py.File(out, "r") as h5:
        assert int(h5["steps_done"][0]) == 1  # nothing run, nothing written
