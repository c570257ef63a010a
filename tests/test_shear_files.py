"""A shear specimen's result file (docs/model.md section 11): resumed after an interrupt it
equals the uninterrupted run entry for entry (step 0's reference angles included), its XDMF
view shows every node of both families with the shear angle, `dynfab plot` draws it, and
the dynamic solver refuses it in one line.
"""

from __future__ import annotations

import h5py
import meshio
import numpy as np
import pytest

from dynfab import run
from dynfab.plots.figures import plot_results
from dynfab.run import run_to_file
from dynfab.scene import parse_scene_text
from test_fabric_scenes import assert_same_steps, run_interrupted
from test_shear_specimens import BIAS, FRAME, HOLDING_FRICTION, scene_text

D = [1e-3, 2e-3, 3e-3, 4e-3]


def small_frame():
    return parse_scene_text(scene_text(FRAME.replace("side = 0.06", "side = 0.022"), D))


def resumed_run(scene, tmp_path):
    """The file of `scene` run to step 3, interrupted and resumed, checked equal to the
    uninterrupted run's entry for entry."""
    whole, part = tmp_path / "whole.h5", tmp_path / "part.h5"
    run_to_file(scene, "static", whole)
    run_interrupted(scene, "static", part, steps=3)
    assert run_to_file(scene, "static", part, resume=True) == 2
    assert_same_steps(whole, part)
    return part


def test_a_resumed_bias_file_has_the_uninterrupted_normalised_force(tmp_path):
    """Harrison's normalisation reads the whole curve so far (dynfab.model.shear_force), and a step
    starts along the last step's path tangent: a resumed run gives the model the finished
    steps' forces and positions, so every step is the uninterrupted run's."""
    bias = BIAS.replace("width = 0.06", "width = 0.025").replace("height = 0.12", "height = 0.05")
    part = resumed_run(parse_scene_text(scene_text(bias, D, HOLDING_FRICTION)), tmp_path)
    with h5py.File(part, "r") as b:
        assert np.all(np.isfinite(b["steps/normalised_shear_force"][:]))


def test_a_resumed_specimen_file_is_the_uninterrupted_one_and_its_view_and_figures(tmp_path):
    part = resumed_run(small_frame(), tmp_path)
    with h5py.File(part, "r") as b:
        nodes = b["reference/positions"].shape[0]
        gamma = b["steps/shear_angle"][4]
        crossing_nodes = b["reference/crossing_nodes"][()]
        positions = b["steps/positions"][4]
    with meshio.xdmf.TimeSeriesReader(part.with_suffix(".xdmf")) as view:
        points, cells = view.read_points_cells()
        assert view.num_steps == 5 and points.shape == (nodes, 3)
        _, data, _ = view.read_data(4)
    np.testing.assert_array_equal(data["position"], positions)
    np.testing.assert_array_equal(data["shear_angle"][crossing_nodes[:, 0]], gamma)
    np.testing.assert_array_equal(data["shear_angle"][crossing_nodes[:, 1]], gamma)
    assert [p.name for p in plot_results(part, tmp_path / "plots")] == \
        ["shear_force.png", "shear_field.png", "contact_field.png"]


def test_a_study_of_a_specimen_gathers_the_serial_runs(tmp_path):
    """A small picture frame as a study's base scene, its crossings' shear stiffness varied:
    each case's clamp force at the last step is exactly the serial run's, and the stiffer
    crossings carry the larger force."""
    import xarray as xr

    from dynfab.scene import scene_to_toml
    from dynfab.studies.study import study
    from dynfab.studies.file import load_study
    from test_study import serial

    (tmp_path / "base.toml").write_text(scene_to_toml(small_frame()))
    path = tmp_path / "study.toml"
    path.write_text('title = "frame"\nscene = "base.toml"\n'
                    '[vary]\n"crossing.shear_stiffness" = [2e-3, 5e-3]\n'
                    '[observe]\nforce = { dataset = "clamp_force", at = "last" }\n')
    plan = load_study(path)
    reference = serial(plan)
    result = study(plan, tmp_path / "out", workers=1, sync="end")
    assert (result.cases, result.finished, result.failed) == (2, 2, 0)
    force = xr.open_dataset(result.table)["force"].values
    assert np.array_equal(force, [run.steps["clamp_force"][-1] for run in reference])
    assert force[1] > force[0] > 0.0
