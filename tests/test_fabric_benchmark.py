"""benchmarks/fabric.py on its quick mode's smallest patch (4 x 4), through its functions.

No wall-clock assertion (performance is the benchmark's to report): the test checks that
every part yields the keys its JSON and table are built from, and that the end states it
compares agree as the solvers' residual tolerances allow (`agreement_bound` of
tests/test_fabric_dynamic.py). The explicit part (Warp against numba) is left out: its
viscous frictionless kernels are variants no other test builds; the dynamic part uses the
configuration tests/test_fabric_dynamic.py builds.
"""

import importlib.util
import json
from pathlib import Path

import numpy as np
import pytest

from dynfab.solvers.static import StaticSolver
from test_fabric_dynamic import agreement_bound

PATH = Path(__file__).resolve().parents[1] / "benchmarks" / "fabric.py"
_spec = importlib.util.spec_from_file_location("fabric_benchmark", PATH)
bench = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(bench)

N = bench.QUICK_SIZES[0]
PARTS = ("newton", "pcg", "static", "dynamic")
KEYS = {"newton": {"dofs_free", "newton_s", "newton_iterations", "s_per_newton_iteration",
                   "residual_N"},
        "static": {"step_s", "certificate_s", "inertia_s", "nearest_eigenvalue_s",
                   "negative_eigenvalues", "residual_N"},
        "pcg": {"step_s", "newton_iterations", "cg_iterations_mean", "fallbacks",
                "static_difference_m"},
        "dynamic": {"step_s", "time_steps", "relax_s_per_time_step", "residual_N",
                    "static_difference_m"},
        "pieces": {"gradient_s", "hessian_s", "splu_symmetric_s", "inertia_s",
                   "inertia_negatives", "inertia_method", "dense_negatives"}}


@pytest.fixture(scope="module")
def rows():
    """The parts of the 4 x 4 patch as measure_size emits them."""
    emitted = {}
    bench.measure_size(N, PARTS, pieces=True, emit=emitted.__setitem__)
    return emitted


def test_every_part_gives_its_keys_and_the_summary_its_fits(rows):
    assert set(rows) == set(PARTS) | {"pieces"}
    for part, keys in KEYS.items():
        assert keys <= set(rows[part]), (part, keys - set(rows[part]))
    row = {"n": N, "nodes": bench.nodes(N), **rows}
    summary = bench.summary([row])
    assert set(summary["aims"]) == set(bench.AIMS)
    assert set(summary["exponents"]) == set(bench.FITS)
    # one size: no fit, the aim reported as not measured rather than met
    assert summary["exponents"]["exponent_newton_iteration"]["all_sizes"] is None
    assert summary["aims"]["exponent_newton_iteration"]["met"] is None
    json.dumps({"rows": [row], "summary": summary})  # the JSON is writable
    text = bench.report({"rows": [row], "summary": summary})
    assert f"{N}x{N}" in text and "Newton s/it" in text
    # the inertia by Schur complement counts what the dense eigenvalues count
    assert rows["pieces"]["inertia_negatives"] == rows["pieces"]["dense_negatives"]


def test_the_solvers_end_states_agree_within_their_residual_bound():
    """The static, PCG and dynamic end states of the load step: both stop at a residual
    <= the tolerance, so they differ by at most ||H^-1|| (r_static + r_other)."""
    static_row, state, record = bench.static_costs(N)
    dynamic_row, dynamic_state, dynamic_record = bench.dynamic_costs(N, state.positions)
    pcg_row = bench.pcg_costs(N, state.positions)
    solver = StaticSolver(bench.patch_model(N))
    anchors = solver.initial_state().anchors
    difference = np.abs(dynamic_state.positions - state.positions).max()
    assert dynamic_row["static_difference_m"] == difference
    bound = agreement_bound(solver, state, anchors, record, dynamic_record["residual"], 0.0)
    assert np.abs(state.positions - solver.initial_state().positions).max() > 1e3 * bound
    assert difference <= bound, (difference, bound)
    pcg_bound = agreement_bound(solver, state, anchors, record, bench.TOLERANCE, 0.0)
    assert pcg_row["static_difference_m"] <= pcg_bound, (pcg_row["static_difference_m"], pcg_bound)
    assert static_row["residual_N"] <= bench.TOLERANCE
    assert static_row["negative_eigenvalues"] == 0  # a stable state: the bound's H^-1 exists
    assert dynamic_row["residual_N"] <= bench.TOLERANCE


def test_a_size_over_its_budget_is_recorded_as_not_run():
    """A budget shorter than the subprocess's imports: every part is recorded as not run."""
    row = bench.run_size(N, 0.05, bench.PARTS, friction=False, pieces=False)
    assert row["stopped"]
    for part in bench.PARTS + ("memory",):
        assert row[part]["not run"].startswith("exceeded budget"), row[part]
    assert "-" in bench.table([row])  # the table shows a part not run as '-'
