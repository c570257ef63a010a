"""The dynamic solver against the static one on every fabric scene in runs/ (docs/model.md
sections 5, 10): `dynfab run runs/<scene>.toml --solver dynamic`, with `--method explicit`
and `semi_implicit`, over the first load steps of the scene's own path, each step compared
with the static solver's step from the same state (positions, anchors), within the bound their
residual tolerances allow (`agreement_bound` of tests/test_fabric_dynamic.py); the other
dampings (FIRE, adaptive viscous) and the node-parallel layout on two of them; a resumed run of
the periodic cell bit for bit; displacement control moving the planes.

(The kernels' forces with moving planes, wrap springs and tied cell lengths against the static
gradient, and their layouts bit for bit: tests/test_kernels_structure.py.)

Kernel variants: float64 grouped (scatter order) with friction and the boundary couplings
(the periodic cell and "affine" planes) or friction alone (the clamped patches), and the
node-parallel one tests/test_kernels_structure.py builds.
"""

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from dynfab.solvers.dynamic import DynamicSolver
from dynfab.model.fabric import assembly
from dynfab.model.fabric.model import FabricModel
from dynfab.results.file import MACHINE_TIMES
from dynfab.solvers.static import StaticSolver
from dynfab.scene import load_scene
from dynfab.model.structure import uniform
from independent import PAPER_FRICTION, pullout_scene, scene_with
from test_fabric_dynamic import (agreement_bound, anchor_bound, dynamic_solver, end_rows,
                                 paper_patch_model)
from test_fabric_scenes import run_interrupted

RUNS = Path(__file__).resolve().parent.parent / "runs"


# --- 2. every fabric scene of runs/ ---

SCENES = {"fabric_biaxial": 2, "fabric_biaxial_2to1": 2, "fabric_biaxial_1to2": 2,
          "fabric_strip": 1, "fabric_pullout": 2}
"""Scene -> load steps compared. The load paths are truncated (CI time): every step of a
scene runs the same code (the static solver's start, one relaxation, the certificate and the
return map), so the first steps exercise every term the scene has. Two for the biaxial cells
(2 x 2, under a second each); one for the 16 x 16 strip (7,200 nodes: its first relaxation
takes about 16,000 time steps, several seconds, and its ||J^-1|| a dense inverse of 14,000
unknowns, too slow: see `scene_model`); two for the pull-out, its steps 2 and 3: the end of
the first stage (the wefts tensioned, pressing the crossings) reached in one step, then the
first pull of the warp, where the crossings on it slide (`scene_model`)."""


def scene_model(name: str, steps: int | None = None) -> FabricModel:
    """The scene's model at static.tolerance = dynamic.tolerance = TOLERANCE, its load path cut
    to `steps` steps
    (default SCENES[name]; the pull-out's from its step 2). The strip is
    the same scene on a 4 x 4 patch of the same yarns (pitch, segment length, planes
    "affine", friction, loads per yarn), as tests/test_fabric_scenes.py runs it: the
    bound needs ||J^-1|| by a dense inverse. The pull-out's crossings are fixed pairs of nodes
    here: crossings that slide run on the static solver alone (docs/model.md 11.13)."""
    scene = pullout_scene() if name == "fabric_pullout" else load_scene(RUNS / f"{name}.toml")
    steps = SCENES[name] if steps is None else steps
    first = 1 if name == "fabric_pullout" else 0  # the pull-out from its step 2
    path = FabricModel.from_scene(scene).load_values[first:first + steps]
    tables = {"static": {"tolerance": TOLERANCE}, "dynamic": {"tolerance": TOLERANCE},
              "load": {"values": tuple(map(float, path[:, 0])),
                       "weft_values": tuple(map(float, path[:, 1]))}}
    if name == "fabric_strip":
        g, weft = scene.geometry, scene.weft
        pitch_wa, pitch_we = g.length / g.crossings, weft.length / weft.count
        per_wa, per_we = g.segments // g.crossings, weft.segments // weft.count
        tables["geometry"] = {"crossings": 4, "length": 4 * pitch_wa, "segments": 4 * per_wa}
        tables["weft"] = {"count": 4, "length": 4 * pitch_we, "segments": 4 * per_we}
    return FabricModel.from_scene(scene_with(scene, **tables))


TOLERANCE = 1e-10
"""Residual tolerance [N] of both solvers (as tests/test_fabric_dynamic.py: above the static
residual's rounding floor on these yarns, about 1e-11 N at k_c = 1e5 N/m)."""


@pytest.mark.parametrize("method", ["explicit", "semi_implicit"])
@pytest.mark.parametrize("name", sorted(SCENES))
def test_every_fabric_scene_agrees_with_the_static_solver(name, method):
    """Each step of the dynamic run (explicit with kinetic damping, semi-implicit) against the
    static solver's step from the same state:
    positions within `agreement_bound` (||J^-1|| (r_static + r_dynamic); the same anchors
    held), contact forces within 2 k_c times it, the same open/closed and sliding patterns
    and stability, the return-mapped anchors within `anchor_bound`, the step moving the
    fabric far beyond the bound.

    Why from the same state rather than two independent runs (tests/test_fabric_dynamic.py):
    two runs' anchors differ after a return map by ~1e-11 m, which `agreement_bound` charges
    at the stick stiffness (k_t ~ 3e4 N/m on the pull-out) through the worst direction of
    J^-1 (17 m/N there): a bound of 1e-5 m against a pull of 2e-4 m, where the positions
    differ by 2e-10 m. Started from one state, the steps share their anchors, and the anchors'
    agreement after the return map is checked instead."""
    model = scene_model(name)
    static, dynamic = StaticSolver(model), dynamic_solver(model, method=method)
    state = model.initial_state()
    k_c = uniform(static.model.structure.tie_contact_law)[0]
    for warp_value, weft_value in model.load_values:
        start = state.copy()
        s_state, s_record = static.step(start.copy(), (warp_value, weft_value))
        state, d_record = dynamic.step(start, (warp_value, weft_value))
        assert d_record["residual"] <= TOLERANCE
        bound = agreement_bound(static, s_state, start.anchors, s_record, d_record["residual"], 0.0)
        assert np.abs(s_state.positions - start.positions).max() > 1e3 * bound
        error = np.abs(state.positions - s_state.positions).max()
        assert error <= bound, (error, bound)
        closed = s_record["contact_force"] > 0
        assert np.abs(d_record["contact_force"] - s_record["contact_force"]).max() <= 2 * k_c * bound
        assert np.array_equal(d_record["contact_force"] > 0, closed)
        assert np.array_equal(d_record["sliding"], s_record["sliding"])
        assert d_record["stable"] == s_record["stable"]
        if s_record["sliding"].any():
            gap = np.abs(state.anchors - s_state.anchors).max()
            assert gap <= anchor_bound(static, s_record, bound), gap


@pytest.mark.parametrize("damping, layout", [("fire", "grouped"), ("viscous", "grouped"),
                                             ("kinetic", "node_parallel")])
@pytest.mark.parametrize("name", ["fabric_biaxial_2to1", "fabric_strip"])
def test_the_other_dampings_and_layouts_reach_the_same_step(name, damping, layout):
    """FIRE and adaptive viscous damping (grouped layout) and kinetic damping in the
    node-parallel layout (a GPU's) on the periodic cell and the affine strip (4 x 4 copy): the
    first step within `agreement_bound` of the static solver's, as the default configuration
    in `test_every_fabric_scene_agrees_with_the_static_solver`."""
    model = scene_model(name, steps=1)
    static = StaticSolver(model)
    dynamic = DynamicSolver(model, replace(model.scene.dynamic, damping=damping), layout=layout)
    start = model.initial_state()
    load = tuple(model.load_values[0])
    s_state, s_record = static.step(start.copy(), load)
    state, d_record = dynamic.step(start, load)
    bound = agreement_bound(static, s_state, start.anchors, s_record, d_record["residual"], 0.0)
    assert np.abs(s_state.positions - start.positions).max() > 1e3 * bound
    assert np.abs(state.positions - s_state.positions).max() <= bound


@pytest.mark.parametrize("method", ["explicit", "semi_implicit"])
def test_a_resumed_dynamic_run_of_the_periodic_cell_repeats_the_uninterrupted_one(tmp_path,
                                                                                  method):
    """`--solver dynamic --resume` on the periodic cell (tied cell lengths, moving planes),
    with each dynamic method: a run stopped after 4 steps and resumed writes the same bits as
    the run done in one go, every steps/ dataset but the wall time (each step relaxes from the
    stored positions and anchors, at rest, in a fixed order of sums: docs/model.md section
    10's determinism)."""
    import h5py

    from dynfab.run import run_to_file
    from dynfab.scene import parse_scene_text

    text = (RUNS / "fabric_biaxial_1to2.toml").read_text()
    scene = parse_scene_text(text + f'\n[dynamic]\nmethod = "{method}"\n')
    whole, part = tmp_path / "whole.h5", tmp_path / "part.h5"
    run_to_file(scene, "dynamic", whole)
    run_interrupted(scene, "dynamic", part)
    assert run_to_file(scene, "dynamic", part, resume=True) == 6
    with h5py.File(whole, "r") as a, h5py.File(part, "r") as b:
        assert a.attrs["solver"] == "dynamic" and a.attrs["dynamic_method"] == method
        compared = 0
        for name, dataset in a["steps"].items():
            if isinstance(dataset, h5py.Dataset) and name not in MACHINE_TIMES:
                np.testing.assert_array_equal(dataset[:], b["steps"][name][:], err_msg=name)
                compared += 1
        assert compared > 20 and "warp_planes" in a["steps"]


@pytest.mark.parametrize("boundary, planes", [("periodic", "fixed"), ("clamped", "affine")])
def test_displacement_control_moves_the_planes_with_the_prescribed_ends(boundary, planes):
    """Under displacement control the cell lengths (periodic) or the loaded ends (affine
    planes) are prescribed and the planes move with them: each step of the dynamic run
    against the static step from the same state, positions within `agreement_bound` and the
    end reactions (which carry the planes' friction reaction) within the bound times the end
    dof's stiffness row sum, as tests/test_fabric_dynamic.py bounds them."""
    values = ((2e-4, 5e-5), (6e-4, 2e-4))
    n = 2 if boundary == "periodic" else 4
    model = paper_patch_model(n, n, values, "displacement", PAPER_FRICTION, boundary=boundary,
                              planes=planes, tolerance=TOLERANCE)
    static, dynamic = StaticSolver(model), dynamic_solver(model)
    state = model.initial_state()
    f = static.model.structure
    for warp_value, weft_value in values:
        start = state.copy()
        s_state, s_record = static.step(start.copy(), (warp_value, weft_value))
        state, d_record = dynamic.step(start, (warp_value, weft_value))
        bound = agreement_bound(static, s_state, start.anchors, s_record, d_record["residual"], 0.0)
        assert np.abs(s_state.positions - start.positions).max() > 1e3 * bound
        assert np.abs(state.positions - s_state.positions).max() <= bound
        px, py = assembly.planes(state.positions, f)
        assert np.abs(px - f.tie_plane[:, 0]).min() > 1e3 * bound  # the planes moved
        rows = end_rows(dynamic, s_state.positions, start.anchors)
        row = rows + np.abs(s_record["end_force"]) / f.rest_length[f.load_node
                                                                   - np.arange(model.yarns) - 1]
        difference = np.abs(d_record["end_force"] - s_record["end_force"])
        assert (difference <= row * bound).all(), (difference, row * bound)
        assert np.abs(s_record["end_force"]).max() > 1e3 * (row * bound).max()
