"""The transient mode on the in-plane shear specimens (docs/model.md sections 5, 11.12):
dynamic.mode = "transient" drives a specimen's held nodes along the load path in physical time
with the kernels and solver of every other model (`SpecimenModel.transient_drive`,
`kernels/structure_transient.py`), its frames in the specimen's record layout
(`SpecimenModel.frame`).

The 60 mm picture frame of tests/test_shear_specimens.py, step 0's d = 0 held for a third of
the run (the woven preload's relaxation) and then ramped to 3 mm and held:
- with the scene's friction law, undamped: every held node lies on its prescribed path at
  every frame, to the drive's interpolation bound between its knots (the frame's turn is
  sampled finely and taken linear between samples); the anchors are return-mapped at every
  time step, so no frame holds a friction force above Gralen's limit; a run interrupted after
  a frame and resumed from its file writes the uninterrupted frames bit for bit, and its view
  and figures draw every frame;
- held together by a friction limit no crossing reaches (nothing slides, so the equilibrium
  does not depend on the path) and damped: the last frame lies where the static solver's
  equilibrium is, to first order in the frame's residual (a Newton step from the frame, whose
  length is the first-order distance to the nearest equilibrium).

Kernel variants: the spatial float64 transient kernels with friction, grouped (scatter and
gather order) and node-parallel.
"""

from __future__ import annotations

import io

import meshio
import numpy as np
import pytest
import scipy.sparse.linalg

from dynfab import plot_results, run
from dynfab.model import build_model
from dynfab.model import specimen_layout
from dynfab.model.fabric import spatial
from dynfab.model.fabric.specimen_model import TRANSIENT_KNOTS
from dynfab.results.file import read_results
from dynfab.results.summary import print_summary
from dynfab.scene import parse_scene_text
from dynfab.solvers.by_name import make_solver
from dynfab.solvers.contract import FRAME_KEYS
from dynfab.solvers.dynamic import DynamicSolver
from test_fabric_transient import resumed_equals_whole
from test_shear_specimens import FRAME, scene_text

pytest.importorskip("warp")

EPS = np.finfo(float).eps
VALUES = [3e-3]
"""The corner displacement d [m] the ramp reaches (after step 0's d = 0)."""
DURATION, INTERVAL = 2e-3, 2e-4
"""Simulated time [s] (a millisecond at d = 0, a millisecond's ramp to 3 mm) and the time
between frames [s], off the drive's knots (every DURATION / (2 TRANSIENT_KNOTS))."""
SPECIMEN_NAMES = ("load", "end_displacement", "clamp_force", "shear_angle", "crossing_slip_ratio",
                  "slip_ratio", "dissipated")
"""A specimen frame's names beside the contract's (its record's layout)."""
STICKING = "\n[friction]\nalpha = 0.2\nbeta = 1e8\ncontact_length = 2e-3\nfiber_radius = 1e-3\n"
"""A friction limit of about 200 N per crossing: no crossing of the frame slides to d = 3 mm
(checked below), so its equilibrium at d is one whatever path led there."""


def transient_text(values, duration, interval, friction="", damping=0.0) -> str:
    return (scene_text(FRAME, values, friction)
            + f'\n[dynamic]\nmode = "transient"\nduration = {duration!r}\n'
              f"output_interval = {interval!r}\ndamping_coefficient = {damping!r}\n")


@pytest.fixture(scope="module")
def frame_run():
    """(model, frames) of the undamped frame with the scene's friction law."""
    model = build_model(parse_scene_text(transient_text(VALUES, DURATION, INTERVAL)))
    frames = list(make_solver(model, "dynamic").advance(model.initial_state()))
    return model, frames


def test_held_nodes_follow_the_drive_and_frames_hold_the_record_names(frame_run):
    """Each frame at its time with the contract's names and the specimen's; d on the ramp
    through (0, 0), (T/2, 0), (T, 3 mm); every held node within the drive's interpolation
    bound h^2 / 8 max |x''(t)| of its exact position at d (h the knots' spacing in time, x''
    from central differences of the exact path on a grid 16 times finer than the knots, which
    estimate it to O(h^2/256)), plus the rounding of x0 + u."""
    model, frames = frame_run
    layout, rest = model.layout, model.structure.rest_position
    times = [float(frame["time"]) for frame in frames]
    assert np.allclose(times, np.arange(11) * INTERVAL, rtol=0, atol=1e-18)

    def ramp(t):
        return np.interp(t, [0.0, DURATION / 2, DURATION], [0.0, 0.0, VALUES[0]])

    def exact(t):
        return specimen_layout.held_positions(layout, rest, float(ramp(t)))

    h = DURATION / (2 * TRANSIENT_KNOTS)
    fine = np.linspace(DURATION / 2, DURATION, 16 * TRANSIENT_KNOTS + 1)
    path = np.array([exact(t) for t in fine])
    step = fine[1] - fine[0]
    curvature = np.abs(path[2:] - 2 * path[1:-1] + path[:-2]).max() / step ** 2
    bound = h ** 2 / 8 * curvature + 4 * EPS * 0.1
    assert bound < 1e-8  # the drive's error is far below the 3 mm of motion
    held = np.flatnonzero(layout.held)
    for frame in frames:
        assert set(FRAME_KEYS) | set(SPECIMEN_NAMES) <= set(frame)
        assert float(frame["load"][0]) == pytest.approx(ramp(float(frame["time"])), abs=1e-18)
        error = np.abs(frame["positions"][held] - exact(float(frame["time"]))).max()
        assert error <= bound, (float(frame["time"]), error, bound)
    assert np.abs(frames[-1]["positions"][held] - rest[held]).max() > 1e-3  # the bars turned
    assert frames[0]["energy/kinetic"] == 0.0 < frames[-1]["energy/kinetic"]


def test_anchors_are_return_mapped_every_step(frame_run):
    """No frame's anchors lie outside Gralen's limit: the radial return map of a frame's
    anchors at its positions moves none of them by more than the rounding of the slip
    (x ~ 0.1 m), so it dissipates at most F_T times that; the dissipation never falls, and
    friction slips (the paper's law lets the frame's free-end crossings slide)."""
    model, frames = frame_run
    f = model.structure
    for frame in frames:
        pos, anchors = frame["positions"], np.array(frame["anchors"], float)
        limit = model.friction_limits(pos)
        sliding = np.zeros(f.tie_a.size, np.bool_)
        lost = spatial.return_map(pos, anchors, f, limit, sliding, np.zeros((f.tie_a.size, 3)))
        assert lost <= np.sum(limit) * 8 * EPS * 0.1
    dissipated = np.array([float(frame["dissipated"]) for frame in frames])
    assert np.all(np.diff(dissipated) >= 0.0) and dissipated[-1] > 0.0


def test_a_damped_transient_settles_on_the_static_equilibrium():
    """d ramped to 3 mm in 1 ms after step 0 and held 1 ms, damped (c = 20000 /s, e^(-c t / 2) = 5e-5 over the hold), nothing
    sliding: the static solver's equilibrium x* at 3 mm and the last frame's x differ by the
    Newton step from x, H^-1 grad V(x) on the free dofs (H the Hessian at x: the first-order
    distance to the equilibrium), within the second-order rest (a quarter of that step) and
    the static step's own error bound; and that step is small against the motion (the
    damping has settled the frame)."""
    text = transient_text(VALUES + VALUES, 3e-3, 1e-3, STICKING, damping=20000.0)
    model = build_model(parse_scene_text(text))
    frame = list(make_solver(model, "dynamic").advance(model.initial_state()))[-1]
    static = run(parse_scene_text(scene_text(FRAME, VALUES, STICKING)), solver="static")
    assert not static.steps["sliding"].any() and float(frame["dissipated"]) == 0.0
    f, pos, anchors = model.structure, frame["positions"], frame["anchors"]
    limit = model.friction_limits(pos)
    grad = np.zeros_like(pos)
    spatial.gradient(pos, f, np.zeros(0), anchors, limit, grad)
    pattern = spatial.pattern_of(f)
    H = spatial.sparse_hessian(f, pos, anchors, limit)
    newton = pattern.expand(scipy.sparse.linalg.spsolve(H, pattern.reduce(grad)))
    difference = np.abs(pos - static.steps["positions"][-1]).ravel()
    step = np.abs(newton)
    assert np.abs(difference - step).max() <= 0.25 * step.max() + static.steps[
        "error_estimate"][-1]
    assert step.max() < 1e-3 * VALUES[0]


def test_a_resumed_transient_writes_the_uninterrupted_frames_and_its_view_and_figures(tmp_path):
    """`run_to_file` stopped (as a Ctrl-C) after its second frame and resumed from the file
    writes the very bits of the run done in one go (every frame dataset); its XDMF view has a
    grid of every node per frame, `dynfab plot` draws its figures and the summary lists d and
    the clamp force per frame."""
    scene = parse_scene_text(transient_text(VALUES, DURATION, DURATION / 4))
    whole, names = resumed_equals_whole(scene, tmp_path, 5)
    assert set(FRAME_KEYS) | set(SPECIMEN_NAMES) <= set(names)
    assert "xdmf/shear_angle" in names
    with meshio.xdmf.TimeSeriesReader(whole.with_suffix(".xdmf")) as view:
        points, _ = view.read_points_cells()
        assert view.num_steps == 5
        assert points.shape[0] == build_model(scene).structure.rest_position.shape[0]
    figures = plot_results(whole, tmp_path / "figures")
    assert figures and all(path.stat().st_size > 0 for path in figures)
    table = io.StringIO()
    print_summary(read_results(whole), table)
    header, *rows = table.getvalue().splitlines()[:6]
    assert "clamp F [N]" in header and len(rows) == 5  # a row per frame, d and the force in it


def test_the_node_parallel_layout_runs_a_specimen_transient_as_the_grouped_one_bit_for_bit():
    """The node-parallel layout (the GPU's: a launch per stage, each node gathering its
    elements' forces and driving its own rows of the drive) writes the grouped layout's
    gather-order frames bit for bit: `--device cuda` changes the layout, not the answer. On
    0.2 ms of the frame, d = 0 for 0.1 ms and then ramped to 3 mm (about 6,000 time steps;
    a launch per stage per time step costs the CPU 10-45 us)."""
    model = build_model(parse_scene_text(transient_text(VALUES, 2e-4, 1e-4)))
    runs = [list(DynamicSolver(model, layout=layout, order="gather").transient(
        model.initial_state())) for layout in ("grouped", "node_parallel")]
    assert len(runs[0]) == len(runs[1]) == 3
    for grouped, parallel in zip(*runs):
        assert set(grouped) == set(parallel)
        for name in grouped:
            np.testing.assert_array_equal(parallel[name], grouped[name], err_msg=name)
    assert runs[0][-1]["energy/kinetic"] > 0.0  # sheared to 3 mm by then: it moves
