"""The fabric's dynamic solver (Warp relaxation) against the static reference (Newton),
docs/model.md sections 5, 6, 10.

Both solve the same load path on small clamped patches of the paper's yarns, each
carrying its own state from step to step (an independent run each), and every step's
positions, contact forces, sliding pattern and return-mapped anchors must agree within
the bound their residual tolerances allow (`agreement_bound`).

The relaxation uses the kernel configuration tests/test_fabric_kernels.py builds
(float64, friction compiled in, kinetic damping, persistent layout; the crossing and
node passes and the return map): no new kernel variant.
"""

import numpy as np
import pytest

from dynfab.errors import SolverError
from dynfab.fabric.dynamic import FabricDynamicSolver
from dynfab.fabric.model import FabricModel
from dynfab.static import StaticSolver
from dynfab.kernels.fabric_arrays import gershgorin_masses
from dynfab.reports.fabric_data import paper_patch_scene
from dynfab.structure import uniform
from independent import PAPER_FRICTION

TOLERANCE = 1e-10
"""Residual tolerance [N] of both solvers: with k_c = 1e5 N/m the static residual's rounding
floor is about 1e-11 N (tests/test_fabric_static.py), so 1e-10 is reached by both."""
FORCES = ((0.1, 0.03), (0.3, 0.1), (0.5, 0.2))
"""(warp, weft) end forces per yarn [N] of the three load steps."""
DISPLACEMENTS = ((2e-4, 5e-5), (6e-4, 2e-4), (1e-3, 3e-4))
"""(warp, weft) end displacements [m] of the three load steps."""


def paper_patch_model(warps, wefts, values, control="force", friction=None, gravity=None,
                      pullout=None, tolerance=None, **geometry) -> FabricModel:
    """A patch of the paper's yarn (`paper_patch_scene`: 8 segments per half-wave, the
    paper's pitch, k_c = 1e5 N/m) under the (warp, weft) load path `values` [N or m];
    `friction` a [friction] table or None, `gravity` g [m/s^2] or None, `pullout` the pulled
    warp (1-based) or None, `tolerance` static.tolerance [N] (None: the scene's default),
    `geometry` its boundary and planes."""
    tables = {}
    if friction is not None:
        tables["friction"] = friction
    if gravity is not None:
        tables["gravity"] = {"g": gravity}
    if pullout is not None:
        tables["pullout"] = {"warp": pullout}
    if tolerance is not None:
        tables["static"] = {"tolerance": tolerance}
    load = {"control": control, "values": [float(v[0]) for v in values],
            "weft_values": [float(v[1]) for v in values]}
    return FabricModel.from_scene(paper_patch_scene(warps, wefts, load=load, **geometry,
                                                    **tables))


def inverse_norm(solver: StaticSolver, state, anchors, limit) -> float:
    """||J^-1||_inf [m/N], J the Jacobian of the static residual on the free dofs at the
    static solution with the step's anchors: the Hessian (F_T frozen) plus, with friction,
    the coupling of F_T to R (`SparseNewton.coupling`), since both solvers converge
    to the point where F_T follows Gralen's law."""
    J = solver.backend.hessian(state.positions, anchors, limit)
    if solver.model.structure.has_friction:
        J = J + solver.backend.coupling(state.positions, anchors, limit)
    return float(np.abs(np.linalg.inv(J.toarray())).sum(axis=1).max())


def agreement_bound(solver, static_state, anchors, record, dynamic_residual, anchor_gap):
    """The largest position difference [m] the two solutions may show.

    Linearising the residual r(x) at the static solution x_s, x_d - x_s = J^-1 (r(x_d) - r(x_s))
    to first order (the differences are ~1e-11 m: the second-order remainder is far below the
    first), so |x_d - x_s|_inf <= ||J^-1||_inf |r(x_d) - r(x_s)|_inf. |r(x_s)| <= r_static; the
    dynamic solver's residual r_dynamic is against its own anchors, which differ from the
    static solver's by `anchor_gap` (the previous steps' return maps, max_c |dxi_c|_2): the
    friction force -k_t s or -F_T s/|s| is k_t-Lipschitz in the anchor (F_T / |s| <= k_t while
    sliding), so r(x_d) <= r_dynamic + k_t anchor_gap. Valid where both solutions sit on the
    same branch of every Huber kink and contact (checked: the sliding patterns agree, the
    contacts closed)."""
    norm = inverse_norm(solver, static_state, anchors, record["friction_limit"].ravel())
    slack = uniform(solver.model.structure.tie_friction_law)[3] * anchor_gap  # k_t
    return norm * (dynamic_residual + record["residual"] + slack)


def anchor_bound(solver, record, bound: float) -> float:
    """The largest anchor difference [m] after the return map, from the position bound.

    A sliding crossing's new anchor is xi = p - (F_T / k_t) u, p = (x_a - X_j, y_b - Y_k),
    u = s/|s|: p moves by at most sqrt 2 bound (2-norm), (F_T / k_t) u by at most |ds| < the same
    (|du| <= |ds| / |s| and F_T / (k_t |s|) < 1 sliding) plus dF_T / k_t; R moves by at most
    k_c |dg| <= 2 k_c bound (dR/dg <= k_c, the core in series with Kawabata's laws) and F_T by
    dF_T/dR = alpha + (beta ell r_f / R_0) exp(-R / R_0) times that, the exponential taken at
    the smallest R of a sliding crossing less that change."""
    f = solver.model.structure
    dR = 2 * uniform(f.tie_contact_law)[0] * bound
    sliding = record["sliding"].ravel()
    R_low = max(record["contact_force"].ravel()[sliding].min(initial=0.0) - dR, 0.0)
    alpha, constant, onset, stick = uniform(f.tie_friction_law)
    slope = alpha + constant / onset * np.exp(-R_low / onset)
    return 2 * np.sqrt(2) * bound + slope * dR / stick


CASES = [(2, "force", None, None, {}), (2, "force", PAPER_FRICTION, None, {}),
         (2, "force", PAPER_FRICTION, 9.81, {}), (4, "force", PAPER_FRICTION, None, {}),
         (4, "displacement", None, None, {}), (4, "displacement", PAPER_FRICTION, None, {}),
         (2, "displacement", PAPER_FRICTION, 9.81, {"pullout": 1})]
"""(n, control, friction, gravity, more `paper_patch_model` arguments); the pull-out (docs/model.md section 10) frees
its warp's first node and needs gravity to press the warp onto the wefts."""


@pytest.mark.parametrize("n, control, friction, gravity, more", CASES,
                         ids=["2x2-force", "2x2-force-friction", "2x2-force-friction-gravity",
                              "4x4-force-friction", "4x4-displacement",
                              "4x4-displacement-friction", "2x2-pullout-gravity"])
def test_dynamic_solver_agrees_with_the_static_one(n, control, friction, gravity, more):
    """Positions and contact forces within `agreement_bound` (R: dR/dg <= k_c and |dg| <= 2
    bound), anchors within `anchor_bound`, the same crossings sliding, the same stability,
    step after step; under displacement control the end reactions within the bound times
    the end dof's stiffness row sum."""
    values = FORCES if control == "force" else DISPLACEMENTS
    model = paper_patch_model(n, n, values, control, friction, gravity, tolerance=TOLERANCE,
                              **more)
    static, dynamic = StaticSolver(model), FabricDynamicSolver(model)
    s_state, d_state = static.initial_state(), dynamic.initial_state()
    k_c = uniform(static.model.structure.tie_contact_law)[0]
    for warp_value, weft_value in values:
        anchors = s_state.anchors.copy()  # held during the step
        anchor_gap = float(np.hypot(*(d_state.anchors - s_state.anchors).T).max())
        start = s_state.positions
        s_state, s_record = static.step(s_state, (warp_value, weft_value))
        d_state, d_record = dynamic.step(d_state, (warp_value, weft_value))
        assert d_record.keys() >= s_record.keys()
        assert d_record["residual"] <= TOLERANCE
        bound = agreement_bound(static, s_state, anchors, s_record, d_record["residual"],
                                anchor_gap)
        moved = np.abs(s_state.positions - start).max()
        assert moved > 1e3 * bound  # the step moves the patch far beyond the bound
        error = np.abs(d_state.positions - s_state.positions).max()
        assert error <= bound, (error, bound)
        R_static = s_record["contact_force"]
        assert R_static.min() > 0  # every contact closed: on the same branch
        assert np.abs(d_record["contact_force"] - R_static).max() <= 2 * k_c * bound
        assert d_record["stable"] == s_record["stable"]
        assert np.array_equal(d_record["sliding"], s_record["sliding"])
        if friction is not None:
            assert s_record["sliding"].any()  # crossings slide: the return map is exercised
            gap = np.abs(d_state.anchors - s_state.anchors).max()
            assert gap <= anchor_bound(static, s_record, bound) + anchor_gap, gap
        if control == "displacement":
            # the reaction dV/du_N changes by K_(end, :) dx, at most the end dof's Hessian row
            # sum times the bound: the kernels' Gershgorin row sums (`gershgorin_masses` at
            # dt = 2 s, safety 1: the rows themselves) cover the stretch and bending blocks;
            # the stretched last segment adds its geometric stiffness T / l <= |end force| / l0
            rows = gershgorin_masses(dynamic.arrays, 2.0, 1.0)[static.model.structure.load_node]
            l0 = dynamic.arrays.rest_length[static.model.structure.load_node - 1]
            row = rows + np.abs(s_record["end_force"]) / l0
            difference = np.abs(d_record["end_force"] - s_record["end_force"])
            assert (difference <= row * bound).all(), (difference, row * bound)


def test_a_relaxation_that_cannot_finish_raises_one_line():
    """The time-step limit reached: SolverError, one line naming the cause and the residual."""
    model = paper_patch_model(2, 2, [(0.3, 0.0)], tolerance=TOLERANCE)
    solver = FabricDynamicSolver(model, max_steps=10)
    with pytest.raises(SolverError) as raised:
        solver.step(solver.initial_state(), (0.3, 0.0))
    message = str(raised.value)
    assert "\n" not in message and "time-step limit" in message and "10 time steps" in message


@pytest.mark.parametrize("method", ["explicit", "semi_implicit"])
def test_a_step_reports_within_itself_and_chunked_launches_keep_the_bits(method):
    """The persistent layouts run the time loop inside one kernel thread; they launch it a
    chunk of time steps at a time (`fabric_relaxation.PatchRelaxation.chunks`) so that the
    progress line (`status`) updates, and Ctrl-C is taken, within a step. Chunks of a few
    steps give the very bits of the whole loop in one launch, and `status` is called
    between them with the steps taken and the residual; the stability check is announced
    too."""
    model = paper_patch_model(2, 2, [(0.3, 0.1)], friction=PAPER_FRICTION, tolerance=TOLERANCE)
    runs = []
    for first_chunk in (10**9, 5):
        calls = []
        solver = FabricDynamicSolver(model, method=method, status=calls.append)
        solver.relaxation.first_chunk, solver.relaxation.chunk_seconds = first_chunk, 0.0
        state, record = solver.step(solver.initial_state(), (0.3, 0.1))
        runs.append((state, record, calls))
    (whole, whole_record, quiet), (chunked, chunked_record, calls) = runs
    np.testing.assert_array_equal(chunked.positions, whole.positions)
    np.testing.assert_array_equal(chunked.anchors, whole.anchors)
    assert chunked_record["time_steps"] == whole_record["time_steps"] > 10
    relaxing = [c for c in calls if "time steps, residual" in c]
    assert len(relaxing) >= whole_record["time_steps"] // 5 - 1  # one per chunk of 5 but the last
    assert relaxing[0].startswith("5 time steps, residual ")
    assert not [c for c in quiet if "time steps" in c]  # one launch: nothing between launches
    assert any("stability check" in c for c in calls)


@pytest.mark.parametrize("method", ["explicit", "semi_implicit"])
def test_a_step_in_the_per_step_layout_reports_within_itself(method):
    """The per-step layouts (a GPU's), whose time loop is in Python, report at most every
    `chunk_seconds` (here 0: at every residual they read back)."""
    model = paper_patch_model(2, 2, [(0.3, 0.1)], friction=PAPER_FRICTION, tolerance=TOLERANCE)
    calls = []
    solver = FabricDynamicSolver(model, method=method, layout="per_step", status=calls.append)
    solver.relaxation.chunk_seconds = 0.0
    solver.step(solver.initial_state(), (0.3, 0.1))
    assert [c for c in calls if "time steps, residual" in c]
