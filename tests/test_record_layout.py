"""The one record layout and a result file's view of it (`dynfab.model.record_layout`,
docs/model.md "The record layout"): each model's view of the flat arrays and its inverse give
back what they were made from, and a fabric's crossings sit where the scene numbers them.
Exact equality throughout: a view and its inverse copy and reshape floats, no arithmetic."""

from functools import lru_cache
from pathlib import Path

import numpy as np
import pytest

from dynfab.model.builders import build_model
from dynfab.scene import load_scene
from independent import pullout_scene, scene_with

RUNS = Path(__file__).resolve().parents[1] / "runs"


@lru_cache
def model_of(kind: str):
    """One model of each layout: the paper's yarns (a sweep of three), a clamped 8 x 8
    patch, the 60 mm picture frame; each a transient of 1 s, whose ramp a frame's load
    reads."""
    scene = {"yarn": lambda: load_scene(RUNS / "paper_fig3.toml"),
             "fabric": lambda: pullout_scene("fixed", 1),
             "specimen": lambda: load_scene(RUNS / "shear_frame_60mm.toml")}[kind]()
    transient = {"mode": "transient", "damping": "viscous", "masses": "physical",
                 "duration": 1.0, "output_interval": 0.5}
    return build_model(scene_with(scene, dynamic=transient))


@pytest.fixture(params=["yarn", "fabric", "specimen"])
def model(request):
    return model_of(request.param)


def flat_arrays(model, seed=0):
    """Random flat arrays of the structure's shapes: nodes (n, dim), anchors (T, k) with
    the columns a tie of the model has (a tie to ground's slip alone)."""
    rng = np.random.default_rng(seed)
    f = model.structure
    n, ties = f.rest_position.shape, f.tie_a.size
    width = model.initial_state().anchors.shape[1]
    anchors = rng.normal(size=(ties, width))
    anchors[:, model.record_layout.anchor_columns:] = 0.0
    return {"positions": rng.normal(size=n), "velocities": rng.normal(size=n),
            "force": rng.normal(size=n), "anchors": anchors}


def test_a_frame_read_back_gives_the_flat_arrays_it_was_made_from(model):
    """`frame_arrays(frame(t, arrays))` is `arrays`: what a resumed transient restores is what
    the run held (the frame's observables computed on the way are not compared)."""
    arrays = flat_arrays(model)
    frame = model.frame(0.25, {**arrays, "kinetic_energy": np.zeros(len(model.groups)),
                               "dissipated": np.zeros(len(model.groups))})
    back = model.frame_arrays(frame)
    assert back["time"] == 0.25
    for name, value in arrays.items():
        assert np.array_equal(back[name], value), name


def test_a_step_read_back_gives_its_state(model):
    """A record's positions and anchors in the file's layout, read back by `state_from_step`,
    are the state's (the other fields of `last` as a file holds them)."""
    arrays = flat_arrays(model, seed=1)
    layout = model.record_layout
    last = {**layout.nodes("positions", arrays["positions"]),
            "anchors": layout.anchors(arrays["anchors"]), "dissipated": 0.0, "work": 0.0,
            "load": np.zeros(1), "end_force": np.zeros(len(model.groups)),
            "clamp_force": 0.0, "reference_angle": np.zeros(model.structure.tie_a.size)}
    history = {"load": np.zeros(1), "clamp_force": np.zeros(1),
               "positions": arrays["positions"][None]}
    state = model.state_from_step(last, history)
    assert np.array_equal(state.positions, arrays["positions"])
    assert np.array_equal(state.anchors, arrays["anchors"])


def test_each_block_is_its_chains_in_chain_order(model):
    """Block b of the view holds the chains of its family one after another, as
    `Structure.chain_start` numbers their nodes."""
    f = model.structure
    chain = 0
    for block in model.record_layout.blocks_of(f.rest_position):
        if block.ndim == 2:  # the specimen's flat nodes: every chain, as they are
            assert np.array_equal(block, f.rest_position)
            return
        for nodes in block:
            start, stop = f.chain_start[chain], f.chain_start[chain + 1]
            assert np.array_equal(nodes, f.rest_position[start:stop])
            chain += 1
    assert chain == f.chain_start.size - 1


def test_a_fabrics_crossings_sit_where_the_scene_numbers_them():
    """Crossing c = k n_we + j is (warp k+1, weft j+1) (`FabricModel.crossing_name`) and sits
    at [k, j] of the file's (n_wa, n_we) view."""
    fabric = model_of("fabric")
    crossings = fabric.record_layout.per_crossing(np.arange(fabric.warps * fabric.wefts))
    for k, j in [(0, 0), (0, fabric.wefts - 1), (fabric.warps - 1, 2)]:
        c = int(crossings[k, j])
        assert fabric.crossing_name(c) == f"(warp {k + 1}, weft {j + 1})"
