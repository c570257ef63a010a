"""The dynamic solver's transient mode on the woven fabric (docs/model.md sections 4, 5, 10):
dynamic.mode = "transient" runs a fabric as it runs the one-yarn model (the same solver and
kernels, `dynfab.solvers.dynamic.DynamicSolver.transient`), its frames in the fabric's record layout
(`FabricModel.frame`).

A 2 x 2 clamped patch of the paper's yarns with friction, its ends pulled by a prescribed
displacement ramped over the run (physical masses, undamped): the frames hold the contract's
names and the wefts' arrays beside them; each end sits on the ramp at every frame time; the
anchors are return-mapped at every time step, so no frame carries a friction force above
Gralen's limit, and friction slips; a run interrupted after a frame and resumed from its file
writes the very frames of the uninterrupted run, whose XDMF view shows both families at every
frame, and the file's size is within the budget's estimate.

Kernel variants: the float64 grouped transient kernel with friction (the one-yarn transient
tests build it without friction and with it, tests/test_dynamic_transient.py).
"""

import h5py
import meshio
import numpy as np
import pytest

from dynfab import budget
from dynfab.solvers.dynamic import DynamicTransient
from dynfab.model.fabric import assembly
from dynfab.model.fabric.model import FabricModel
from dynfab.reports.fabric_data import paper_patch_scene
from dynfab.results.file import read_results
from dynfab.run import run_to_file
from dynfab.solvers.contract import FRAME_KEYS, Transient
from dynfab.solvers.by_name import make_solver
from independent import PAPER_FRICTION

EPS = np.finfo(float).eps
DURATION, FRAMES = 4e-4, 4
"""Simulated time [s] (about 600 time steps at the patch's stable dt of 6.7e-7 s) and frame
intervals."""
VALUES = ((1e-4, 2e-5), (2e-4, 4e-5))
"""The (warp, weft) end displacements [m] the ramp passes through."""
LAYOUT = ("weft_positions", "weft_velocities", "weft_force", "warp_planes", "weft_planes")
"""The fabric's frame names beside the contract's (its record's layout)."""


def transient_scene():
    """The patch's scene: displacement control, friction, the transient over DURATION."""
    return paper_patch_scene(
        2, 2, friction=PAPER_FRICTION,
        load={"control": "displacement", "values": [v[0] for v in VALUES],
              "weft_values": [v[1] for v in VALUES]},
        dynamic={"mode": "transient", "duration": DURATION,
                 "output_interval": DURATION / FRAMES})


@pytest.fixture(scope="module")
def run_frames():
    """(model, frames) of the transient through the `Transient` contract."""
    model = FabricModel.from_scene(transient_scene())
    solver = make_solver(model, "dynamic")
    assert isinstance(solver, Transient) and isinstance(solver, DynamicTransient)
    return model, list(solver.advance(model.initial_state()))


def test_frames_hold_the_contract_names_and_follow_the_ramp(run_frames):
    model, frames = run_frames
    times = [float(frame["time"]) for frame in frames]
    assert np.allclose(times, np.linspace(0.0, DURATION, FRAMES + 1), rtol=0, atol=1e-18)
    f = model.structure
    for frame in frames:
        assert set(FRAME_KEYS) | set(LAYOUT) <= set(frame)
        assert frame["positions"].shape == (model.warps, model.warp.segments + 1, 2)
        assert frame["weft_positions"].shape == (model.wefts, model.weft.segments + 1, 2)
        assert frame["contact_force"].shape == (model.warps, model.wefts)
        # each end at x0 + u(t) of the ramp through (0, 0) and (k T / 2, value_k), up to the
        # rounding of x0 + u (|x| <= 0.0125 m)
        u = np.interp(float(frame["time"]), [0.0, DURATION / 2, DURATION],
                      [0.0, VALUES[0][0], VALUES[1][0]]), \
            np.interp(float(frame["time"]), [0.0, DURATION / 2, DURATION],
                      [0.0, VALUES[0][1], VALUES[1][1]])
        nodes = np.concatenate([frame["positions"].reshape(-1, 2),
                                frame["weft_positions"].reshape(-1, 2)])
        expected = f.rest_position[f.load_node, 0] + model.yarn_loads(*u)
        assert np.abs(nodes[f.load_node, 0] - expected).max() <= 4 * EPS * 0.0125
    assert frames[-1]["energy/kinetic"] > 0.0 and frames[0]["energy/kinetic"] == 0.0


def test_anchors_are_return_mapped_every_step(run_frames):
    """In every frame k_t |s| <= F_T at every crossing (s the slip from the planes and the
    anchor, F_T Gralen's limit of its contact force), up to the rounding of the slip
    (coordinates ~0.0125 m); the anchors moved: friction slipped."""
    model, frames = run_frames
    f = model.structure
    stick = f.tie_friction_law[:, 3]
    for frame in frames:
        pos = np.concatenate([frame["positions"].reshape(-1, 2),
                              frame["weft_positions"].reshape(-1, 2)])
        anchors = frame["anchors"].reshape(-1, 2)
        px, py = assembly.planes(pos, f)
        slip = np.stack([pos[f.tie_a, 0] - px, pos[f.tie_b, 0] - py], axis=1) - anchors
        force = stick * np.hypot(*slip.T)
        assert (force <= model.friction_limits(pos) + 8 * EPS * stick * 0.0125).all()
    assert np.abs(frames[-1]["anchors"] - frames[0]["anchors"]).max() > 1e-7


def resumed_equals_whole(scene, tmp_path, frames: int):
    """Run `scene`'s transient to a file in one go and, into another, stopped (as a Ctrl-C)
    after its second frame and resumed: every frame dataset of the two files bit for bit.
    Returns (the whole file's path, its frame dataset names)."""
    whole, part = tmp_path / "whole.h5", tmp_path / "part.h5"
    assert run_to_file(scene, "dynamic", whole) == frames

    def stop_after(line: str) -> None:
        if line.startswith("frame 2:"):
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        run_to_file(scene, "dynamic", part, progress=stop_after)
    assert read_results(part).frames["time"].shape == (2,)
    assert run_to_file(scene, "dynamic", part, resume=True) == frames - 2
    with h5py.File(whole, "r") as a, h5py.File(part, "r") as b:
        names = []
        a["frames"].visit(lambda name: names.append(name)
                          if isinstance(a["frames"][name], h5py.Dataset) else None)
        for name in names:
            np.testing.assert_array_equal(a["frames"][name][:], b["frames"][name][:], err_msg=name)
    return whole, names


def test_a_resumed_transient_writes_the_uninterrupted_frames(tmp_path):
    """`run_to_file` stopped (as a Ctrl-C) after its second frame and resumed from the file
    writes the very bits of the run done in one go (every frame dataset), its view has a grid
    of both families' nodes per frame, and the file lies within a factor 2 of the budget's
    estimate (`dynfab.budget.result_file_bytes`)."""
    scene = transient_scene()
    whole, names = resumed_equals_whole(scene, tmp_path, FRAMES + 1)
    assert set(FRAME_KEYS) | set(LAYOUT) <= set(names)
    assert "xdmf/weft_contact_force" in names  # the view's point data of both families
    assert 0.5 < whole.stat().st_size / budget.result_file_bytes(scene) < 2.0
    with meshio.xdmf.TimeSeriesReader(whole.with_suffix(".xdmf")) as view:  # both families
        points, _ = view.read_points_cells()
        assert view.num_steps == FRAMES + 1
        assert points.shape[0] == FabricModel.from_scene(scene).structure.rest_position.shape[0]


def test_a_transient_of_the_periodic_cell_follows_its_prescribed_cell_lengths():
    """The periodic 2 x 2 cell with friction (tied cell lengths, moving planes, wrap springs)
    in the transient mode, its cell lengths prescribed on the ramp of VALUES over DURATION:
    the frames at their times, each family's last node on the ramp at every frame (to the
    rounding of x0 + u), both families' arrays in every frame, and the cell in motion."""
    scene = paper_patch_scene(
        2, 2, friction=PAPER_FRICTION, boundary="periodic",
        load={"control": "displacement", "values": [v[0] for v in VALUES],
              "weft_values": [v[1] for v in VALUES]},
        dynamic={"mode": "transient", "duration": DURATION,
                 "output_interval": DURATION / FRAMES})
    model = FabricModel.from_scene(scene)
    solver = make_solver(model, "dynamic")
    assert isinstance(solver, DynamicTransient)
    frames = list(solver.advance(model.initial_state()))
    times = [float(frame["time"]) for frame in frames]
    assert np.allclose(times, np.linspace(0.0, DURATION, FRAMES + 1), rtol=0, atol=1e-18)
    f = model.structure
    for frame in frames:
        assert set(FRAME_KEYS) | set(LAYOUT) <= set(frame)
        u = [np.interp(float(frame["time"]), [0.0, DURATION / 2, DURATION],
                       [0.0, VALUES[0][k], VALUES[1][k]]) for k in (0, 1)]
        nodes = np.concatenate([frame["positions"].reshape(-1, 2),
                                frame["weft_positions"].reshape(-1, 2)])
        expected = f.rest_position[f.load_node, 0] + model.yarn_loads(*u)
        assert np.abs(nodes[f.load_node, 0] - expected).max() <= 4 * EPS * 0.0125
    assert frames[-1]["energy/kinetic"] > 0.0 and frames[0]["energy/kinetic"] == 0.0
