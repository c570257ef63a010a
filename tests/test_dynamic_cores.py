"""Batched yarns split across cores (dynfab.solvers.dynamic: `DynamicSolver.use_cores`).

A split launches the same kernel once per contiguous group of yarns, on views of
the same arrays, from several threads at once; thread y of a group does exactly
the arithmetic of thread first + y in one launch of all the yarns. So every
output of a split run must equal the one-launch run's bit for bit: positions,
anchors, residuals, step counts, time steps, transient frames, and the errors.
"""

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from dynfab.solvers.dynamic import DynamicSolver
from dynfab.errors import SolverError
from dynfab.model.yarn import initial_state
from dynfab.model.builders import build_model
from dynfab.scene import Dynamic, load_scene, validate_scene, with_key

RUNS = Path(__file__).resolve().parent.parent / "runs"


@pytest.fixture(scope="module")
def fig3():
    """Fig. 3's K sweep: three yarns of different stiffness, which need different step counts
    (so one group goes on after the other has finished)."""
    return build_model(with_key(load_scene(RUNS / "paper_fig3.toml"), "load.values", [0.001, 0.003]))


@pytest.fixture(scope="module")
def fig5():
    """Fig. 5: friction on (entry 0) and off (entry 1)."""
    return build_model(with_key(load_scene(RUNS / "paper_fig5.toml"), "load.values", [0.0005, 0.002]))


def relax_path(model, options, cores):
    """Every load step's record of a run on `cores` cores, from the as-woven state."""
    solver = DynamicSolver(model, options)
    solver.use_cores(cores)
    state, records = initial_state(model), []
    for load_value in model.load_values:
        state, record = solver.step(state, load_value)
        records.append(record)
    return solver, records


def assert_records_identical(first, second):
    for one, other in zip(first, second, strict=True):
        assert one.keys() == other.keys()
        for name in one:
            assert np.array_equal(one[name], other[name]), name


@pytest.mark.parametrize("options", [Dynamic(damping="kinetic"), Dynamic(damping="viscous"),
                                     Dynamic(damping="fire"), Dynamic(method="semi_implicit")],
                         ids=["kinetic", "viscous", "fire", "semi_implicit"])
def test_split_is_bit_identical_to_one_launch(fig3, options):
    one, whole = relax_path(fig3, options, cores=1)
    split, parts = relax_path(fig3, options, cores=2)
    assert len(one.ranges) == 1 and len(split.ranges) == 2
    assert_records_identical(whole, parts)
    steps = whole[0]["time_steps"]
    assert len(set(steps.tolist())) > 1  # the yarns finished at different steps


def test_split_with_friction_is_bit_identical(fig5):
    _, whole = relax_path(fig5, Dynamic(), cores=1)
    _, parts = relax_path(fig5, Dynamic(), cores=2)
    assert_records_identical(whole, parts)


def test_one_group_per_yarn_at_most(fig3):
    """More groups than cores queue on the pool: still identical, one yarn per group."""
    _, whole = relax_path(fig3, Dynamic(method="semi_implicit"), cores=1)
    solver, parts = relax_path(fig3, Dynamic(method="semi_implicit"), cores=8)
    assert solver.ranges == [(0, 1), (1, 2), (2, 3)]
    assert_records_identical(whole, parts)


def test_groups_are_contiguous_and_balanced():
    scene = with_key(load_scene(RUNS / "paper_fig3.toml"), "load.values", [0.001])
    scene = replace(scene, sweep=(("warp.kawabata_K", tuple(0.2 + 0.01 * k for k in range(7))),))
    solver = DynamicSolver(build_model(scene))
    solver.use_cores(2)
    assert solver.ranges in ([(0, 3), (3, 7)], [(0, 4), (4, 7)])
    solver.use_cores(3)
    bounds = solver.ranges
    assert bounds[0][0] == 0 and bounds[-1][1] == 7
    assert all(a[1] == b[0] for a, b in zip(bounds, bounds[1:]))
    assert all(2 <= stop - first <= 3 for first, stop in bounds)


def test_one_yarn_is_never_split():
    scene = with_key(replace(load_scene(RUNS / "paper_fig3.toml"), sweep=()), "load.values", [0.001])
    solver = DynamicSolver(build_model(scene))
    solver.use_cores(2)
    assert solver.ranges == [(0, 1)]


def test_split_failure_names_the_same_yarn(fig3):
    """max_steps = 10: the same SolverError (first failing yarn, its residual) either way."""
    messages = []
    for cores in (1, 2):
        solver = DynamicSolver(fig3, Dynamic(max_steps=10))
        solver.use_cores(cores)
        with pytest.raises(SolverError, match=r"yarn 1: no convergence in 10 time steps") as error:
            solver.step(initial_state(fig3), 0.001)
        messages.append(str(error.value))
    assert messages[0] == messages[1]


def test_split_progress_reports_every_yarn(fig3):
    lines = []
    solver = DynamicSolver(fig3, Dynamic(), progress=lines.append)
    solver.use_cores(2)
    solver.step(initial_state(fig3), 0.001)
    relaxing = [line for line in lines if "time steps" in line]
    assert relaxing and relaxing[-1].endswith("0 of 3 groups running")


def test_split_predicted_stable_dt_is_identical(fig3):
    physical = Dynamic(masses="physical")
    predicted = []
    for cores in (1, 2):
        solver = DynamicSolver(fig3, physical)
        solver.use_cores(cores)
        predicted.append(solver.predicted_stable_dt(initial_state(fig3), 0.001))
    assert np.array_equal(*predicted)


def test_split_transient_frames_are_identical():
    """The transient kernel split the same way: every frame bit for bit (friction on and off)."""
    scene = with_key(load_scene(RUNS / "paper_fig5.toml"), "load.values", [0.0005])
    transient = replace(scene.dynamic, mode="transient", duration=2e-4, output_interval=1e-4)
    model = build_model(validate_scene(replace(scene, dynamic=transient)))
    runs = []
    for cores in (1, 2):
        solver = DynamicSolver(model)
        solver.use_cores(cores)
        runs.append(list(solver.transient(initial_state(model))))
    assert len(runs[0]) == len(runs[1]) == 3
    for one, other in zip(*runs):
        for name in one:
            assert np.array_equal(one[name], other[name]), name


def test_split_of_rods_without_crossings():
    """geometry.crossings = 0: the per-crossing arrays have no element (Warp cannot slice them;
    empty stand-ins) and the split run is still identical."""
    scene = load_scene(RUNS / "paper_fig3.toml")
    geometry = replace(scene.geometry, crossings=0, amplitude=0.0, yarns=3, reference="as_woven")
    scene = validate_scene(replace(scene, sweep=(), weft=None, geometry=geometry))
    model = build_model(with_key(with_key(scene, "load.control", "force"), "load.values", [0.1]))
    _, whole = relax_path(model, Dynamic(), cores=1)
    solver, parts = relax_path(model, Dynamic(), cores=2)
    assert len(solver.ranges) == 2 and (whole[0]["time_steps"] > 0).all()
    assert_records_identical(whole, parts)
