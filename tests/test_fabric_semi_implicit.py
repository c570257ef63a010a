"""The dynamic solver's semi-implicit method (`dynfab.solvers.dynamic.DynamicSolver`, method
"semi_implicit") on the woven fabric against the static reference: its load steps against
Newton's within their residual bounds, its records, its repeatability, a scene run (docs/model.md
sections 5, 10).

(Its layouts bit for bit and the direct solve of grounded chains:
tests/test_kernels_structure.py; its failure at the step limit: tests/test_fabric_dynamic.py.)

Kernel variants: float64 grouped semi-implicit, friction compiled in or not as the patch has
it, and the explicit one tests/test_fabric_dynamic.py builds.
"""

import numpy as np
import pytest

from dynfab.solvers.static import StaticSolver
from dynfab.run import run
from dynfab.scene import parse_scene_text
from dynfab.model.structure import uniform
from independent import PAPER_FRICTION
from test_fabric_dynamic import (DISPLACEMENTS, FORCES, TOLERANCE, agreement_bound,
                                 anchor_bound, dynamic_solver, paper_patch_model)
from test_fabric_scenes import position_bound, small_pullout

CASES = [("force", None), ("force", PAPER_FRICTION), ("displacement", None),
         ("displacement", PAPER_FRICTION)]


@pytest.mark.parametrize("control, friction", CASES,
                         ids=["force", "force-friction", "displacement", "displacement-friction"])
def test_semi_implicit_load_steps_agree_with_the_static_ones(control, friction):
    """On a clamped 4 x 4 patch, every load step's positions within `agreement_bound` of
    Newton's (||J^-1|| (r_static + r_dynamic + k_t anchor gap), tests/test_fabric_dynamic.py),
    contact forces within 2 k_c bound, the same crossings sliding, anchors within
    `anchor_bound`, the same stability."""
    values = FORCES if control == "force" else DISPLACEMENTS
    model = paper_patch_model(4, 4, values, control, friction, tolerance=TOLERANCE)
    static = StaticSolver(model)
    dynamic = dynamic_solver(model, method="semi_implicit")
    s_state, d_state = static.initial_state(), model.initial_state()
    cg_iterations = 0
    k_c = uniform(static.model.structure.tie_contact_law)[0]
    for warp_value, weft_value in values:
        anchors = s_state.anchors.copy()
        anchor_gap = float(np.hypot(*(d_state.anchors - s_state.anchors).T).max())
        start = s_state.positions
        s_state, s_record = static.step(s_state, (warp_value, weft_value))
        d_state, d_record = dynamic.step(d_state, (warp_value, weft_value))
        assert d_record["residual"] <= TOLERANCE
        cg_iterations += int(d_record["cg_iterations"])
        bound = agreement_bound(static, s_state, anchors, s_record, d_record["residual"],
                                anchor_gap)
        assert np.abs(s_state.positions - start).max() > 1e3 * bound
        error = np.abs(d_state.positions - s_state.positions).max()
        assert error <= bound, (error, bound)
        assert s_record["contact_force"].min() > 0
        R_error = np.abs(d_record["contact_force"] - s_record["contact_force"]).max()
        assert R_error <= 2 * k_c * bound
        assert d_record["stable"] == s_record["stable"]
        assert np.array_equal(d_record["sliding"], s_record["sliding"])
        if friction is not None:
            assert s_record["sliding"].any()
            gap = np.abs(d_state.anchors - s_state.anchors).max()
            assert gap <= anchor_bound(static, s_record, bound) + anchor_gap, gap
    assert cg_iterations > 0


def test_records_have_the_explicit_solvers_keys_and_runs_repeat_bit_for_bit():
    """The semi-implicit step returns the explicit step's record keys plus its CG iterations
    (those of the step, at least one per time step); a second solver on the same step gives
    identical positions (every sum in a fixed order, no atomics)."""
    model = paper_patch_model(2, 2, [(0.1, 0.0)], friction=PAPER_FRICTION, tolerance=TOLERANCE)
    explicit = dynamic_solver(model)
    semis = [dynamic_solver(model, method="semi_implicit") for _ in range(2)]
    _, e_record = explicit.step(model.initial_state(), (0.1, 0.0))
    states = [semi.step(model.initial_state(), (0.1, 0.0)) for semi in semis]
    assert states[0][1].keys() == e_record.keys() | {"cg_iterations"}
    assert states[0][1]["cg_iterations"] >= states[0][1]["time_steps"] > 0
    np.testing.assert_array_equal(states[0][0].positions, states[1][0].positions)


def test_a_semi_implicit_scene_runs_and_matches_the_static_run():
    """`[dynamic] method = "semi_implicit"` on a fabric scene (the 4 x 4 pull-out with friction
    and gravity) runs, each step within the sum of both runs' `position_bound` of the static
    run's (each state within its own bound of the exact equilibrium)."""
    text = small_pullout() + '\n[dynamic]\nmethod = "semi_implicit"\n'
    scene = parse_scene_text(text)
    from dynfab.model.fabric.model import FabricModel

    model = FabricModel.from_scene(scene)
    static, semi = run(scene, "static"), run(scene, "dynamic")
    assert semi.attrs["dynamic_method"] == "semi_implicit"
    for i in range(static.step_count):
        tol = position_bound(model, static, i) + position_bound(model, semi, i)
        for name in ("positions", "weft_positions"):
            np.testing.assert_allclose(semi.steps[name][i], static.steps[name][i], rtol=0, atol=tol)
        np.testing.assert_array_equal(semi.steps["sliding"][i], static.steps["sliding"][i])
