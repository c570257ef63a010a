"""One static solver, two backends (docs/model.md section 6, and "Decisions": the friction
chain): the backend follows the structure, not the model's kind; both walk the one friction
chain in its order; and the sparse backend, which takes any structure, solves the paper's
yarn to the banded backend's answer.
"""

from dataclasses import replace
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from dynfab.solvers.friction_chain import CHAIN
from dynfab.model.builders import build_model
from dynfab.solvers.newton_banded import BandedNewton
from dynfab.errors import UserError
from dynfab.solvers.newton_sparse import SparseNewton
from dynfab.scene import expand_sweep, load_scene, with_key
from dynfab.solvers.by_name import make_solver
from dynfab.solvers.static import StaticSolver
from dynfab.model.structure import grounded

RUNS = Path(__file__).resolve().parent.parent / "runs"
SCENES = sorted(p for p in RUNS.glob("*.toml") if not p.name.startswith("study_"))
"""The scene files of runs/ (runs/study_*.toml are study files: README, "Studies")."""


@pytest.mark.parametrize("path", SCENES, ids=[p.stem for p in SCENES])
def test_the_backend_follows_the_structure(path):
    """Every scene of runs/: a one-yarn scene (its ties to ground, its yarns independent)
    gets the banded backend, a fabric (warps tied to wefts) the sparse one, through the
    solver factory as through StaticSolver; and the choice reads the structure alone (a
    bare object holding it and the scene gets the same backend)."""
    scene = expand_sweep(load_scene(path))[0]
    model = build_model(scene)
    expected = SparseNewton if scene.geometry.model == "fabric" else BandedNewton
    assert grounded(model.structure) == (expected is BandedNewton)
    assert type(StaticSolver(model).backend) is expected
    if scene.dynamic.mode == "transient":  # it runs by time, with the dynamic solver only
        with pytest.raises(UserError, match="--solver dynamic"):
            make_solver(model, "static")
    else:
        assert type(make_solver(model, "static").backend) is expected
    bare = SimpleNamespace(structure=model.structure, scene=scene)
    assert type(StaticSolver(bare).backend) is expected


@pytest.mark.parametrize("friction", [None, 0.0, 1e-5], ids=["frictionless", "R0=0", "R0>0"])
def test_both_backends_offer_their_strategies_in_the_chain_order(friction):
    """The paper's yarn cut to 32 segments, as its banded backend and as the sparse one: what
    each offers is a subsequence of the one chain (`friction_chain.CHAIN`), so the fallbacks
    run in one order for every model; without friction both solve on the unilateral law
    alone."""
    entry = expand_sweep(load_scene(RUNS / "paper_fig5.toml"))[0]
    scene = with_key(with_key(entry, "geometry.segments", 32), "geometry.crossings", 4)
    scene = (replace(scene, friction=None) if friction is None else
             with_key(scene, "friction.onset_force", friction))
    model = build_model(scene)
    start = model.start_of_step(model.initial_state(), model.step_load(0))
    for backend in (BandedNewton(model), SparseNewton(model)):
        offered = list(backend.strategies(backend.problems(start)[0]))
        assert offered == [name for name in CHAIN if name in offered]
        if friction is None:
            assert offered == ["unilateral"]
        else:
            assert "sets" in offered  # the shared active set, after the backend's own
            assert ("continuation" in offered) == (friction > 0.0)


def test_the_sparse_backend_solves_a_yarn_to_the_banded_answer():
    """runs/paper_fig5.toml with friction (its first entry), cut to its first 3 load steps: each
    step solved from the banded run's state by both backends. Each solution lies within its
    record's error bound of the exact one (error_estimate = residual x est ||H^-1||_inf,
    docs/model.md section 6, first order), so the two lie within the sum of the bounds;
    both are stable minima with the same crossings sliding. The one data model: the same
    structure, whichever backend solves it."""
    entry = expand_sweep(load_scene(RUNS / "paper_fig5.toml"))[0]
    scene = with_key(entry, "load.values", list(np.asarray(entry.load.values)[:3]))
    model = build_model(scene)
    banded = StaticSolver(model)
    sparse = StaticSolver(model)
    sparse.backend = SparseNewton(model)
    assert type(banded.backend) is BandedNewton
    state = model.initial_state()
    for index in range(3):
        load = model.step_load(index)
        state_b, record_b = banded.step(state, load)
        _, record_s = sparse.step(state, load)
        bound = record_b["error_estimate"][0] + record_s["error_estimate"][0]
        difference = np.abs(record_b["positions"] - record_s["positions"]).max()
        assert 0.0 < bound and difference <= bound, (index, difference, bound)
        assert record_b["stable"][0] and record_s["stable"][0]
        assert np.array_equal(record_b["sliding"], record_s["sliding"])
        assert np.abs(record_b["positions"] - state.positions).max() > 1e3 * bound  # it moved
        state = state_b
