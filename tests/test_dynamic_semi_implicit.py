"""The dynamic solver's linearly implicit (semi_implicit) relaxation (docs/model.md section 5).

Equilibria against the static reference within ||K^-1||_inf (r + r_s) (derivation
in test_dynamic_relaxation.py), with and without friction, in far fewer time steps
than the explicit methods: its steps tend to Newton steps as dt grows.
"""

from pathlib import Path

import pytest

from dynfab.solvers.dynamic import DynamicSolver
from dynfab.errors import UserError
from dynfab.model.yarn import initial_state
from dynfab.model.builders import build_model
from dynfab.scene import Dynamic, load_scene, with_key
from dynfab.solvers.static import StaticSolver
from test_dynamic_relaxation import assert_same_equilibrium, relax_path

RUNS = Path(__file__).resolve().parent.parent / "runs"
SEMI_IMPLICIT = Dynamic(method="semi_implicit")
MAX_STEPS = 200
"""Time steps a load step may take: dt doubles after each accepted step, so about
log2(dt_Newton / dt_0) ~ 15 steps reach Newton's regime, then a few Newton steps;
undone steps near stick-slip switches add some (measured: at most 181 here)."""


def test_matches_static_on_fig3_sweep():
    scene = with_key(load_scene(RUNS / "paper_fig3.toml"), "load.values", [0.001, 0.003])
    for model, *states in relax_path(scene, SEMI_IMPLICIT):
        assert_same_equilibrium(model, *states)
        assert (states[3]["time_steps"] <= MAX_STEPS).all()


def test_matches_static_with_friction_one_step_at_a_time():
    scene = with_key(load_scene(RUNS / "paper_fig5.toml"), "load.values", [0.0005, 0.002])
    model = build_model(scene)
    static, dynamic = StaticSolver(model), DynamicSolver(model, SEMI_IMPLICIT)
    state = initial_state(model)
    for load_value in model.load_values:
        static_state, static_record = static.step(state, load_value)
        dynamic_state, dynamic_record = dynamic.step(state, load_value)
        assert_same_equilibrium(model, static_state, static_record, dynamic_state, dynamic_record,
                                coupled=True)
        assert (dynamic_record["sliding"] == static_record["sliding"]).all()
        assert (dynamic_record["time_steps"] <= MAX_STEPS).all()
        state = static_state


@pytest.mark.parametrize("damping", ["fire", "kinetic"])
def test_fire_and_kinetic_damping_are_refused(damping):
    model = build_model(load_scene(RUNS / "paper_fig3.toml"))
    with pytest.raises(UserError, match=f"{damping}.*semi_implicit"):
        DynamicSolver(model, Dynamic(method="semi_implicit", damping=damping))
