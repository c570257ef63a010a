"""The dynamic solver (`dynfab.solvers.dynamic.DynamicSolver`, the one of every model) on the woven
fabric against the static reference (Newton), docs/model.md sections 5, 6, 10.

Both solve the same load path on small clamped patches of the paper's yarns, each
carrying its own state from step to step (an independent run each), and every step's
positions, contact forces, sliding pattern and return-mapped anchors must agree within
the bound their residual tolerances allow (`agreement_bound`). A step reports its progress
within itself (after every launch of a chunk of time steps), a chunked relaxation keeps the
bits of an unchunked one, and the node-parallel layout (a GPU's) takes the grouped layout's
step bit for bit. Every [dynamic] setting runs the fabric (physical masses, float32, adaptive
viscous damping, FIRE; a given dt above the bound warns, far above it diverges in one line),
the relaxation leaves a saddle along the certificate's escape, and with every weft held each
warp is the one-yarn model with a rigid weft spring.

Kernel variants: float64 grouped (scatter order), friction compiled in or not as the patch
has it; the layouts' test runs the periodic cell, whose variant (friction and the boundary
couplings) tests/test_kernels_structure.py builds in both layouts.
"""

import math
import re
from dataclasses import replace

import numpy as np
import pytest

from dynfab.model import assembly
from dynfab.solvers.dynamic import DynamicSolver
from dynfab.errors import SolverError
from dynfab.model.fabric.model import FabricModel
from dynfab.model.yarn import initial_state
from dynfab.model.builders import build_model
from dynfab.reports.fabric_data import paper_patch_scene
from dynfab.solvers.static import StaticSolver
from dynfab.model.structure import chain_of_node, uniform
from independent import PAPER_FRICTION, dense, held_family, make_scene

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
    warp (1-based) or None, `tolerance` static.tolerance and dynamic.tolerance [N] (None: the
    scene's defaults), `geometry` its boundary and planes."""
    tables = {}
    if friction is not None:
        tables["friction"] = friction
    if gravity is not None:
        tables["gravity"] = {"g": gravity}
    if pullout is not None:
        tables["pullout"] = {"warp": pullout}
    if tolerance is not None:
        tables["static"] = {"tolerance": tolerance}
        tables["dynamic"] = {"tolerance": tolerance}
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


def dynamic_solver(model, status=None, **options) -> DynamicSolver:
    """The dynamic solver of `model` with its scene's [dynamic] options, `options` replaced."""
    return DynamicSolver(model, replace(model.scene.dynamic, **options), progress=status)


def end_rows(dynamic: DynamicSolver, positions, anchors) -> np.ndarray:
    """sum_j |K_ij| [N/m] of each yarn's end dof along it (Y,), at `positions`: the kernels'
    Gershgorin row sums of the stiffest tangent there (every contact at its bound k_s, every
    tie sticking, stretch and bending exact: at least the Hessian's, F_T frozen), read back
    from the fictitious masses the relaxation's start chooses, m = dt^2 rows / (4 safety^2)
    with dt = 1 s (docs/model.md section 5)."""
    relaxation = dynamic.relaxation
    relaxation.start(positions, None, anchors)
    rows = relaxation.group_values("mass") * 4 * relaxation.safety ** 2
    return rows[dynamic.model.structure.load_node]


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
    static, dynamic = StaticSolver(model), dynamic_solver(model)
    s_state, d_state = static.initial_state(), model.initial_state()
    k_c = uniform(static.model.structure.tie_contact_law)[0]
    for warp_value, weft_value in values:
        anchors = s_state.anchors.copy()  # held during the step
        anchor_gap = float(np.hypot(*(d_state.anchors - s_state.anchors).T).max())
        start = s_state.positions
        s_state, s_record = static.step(s_state, (warp_value, weft_value))
        d_state, d_record = dynamic.step(d_state, (warp_value, weft_value))
        # friction_solves counts the static solver's solves of its friction update; the
        # relaxation has none (F_T follows R at every time step)
        assert d_record.keys() >= s_record.keys() - {"friction_solves"}
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
            # sum times the bound (`end_rows`); the stretched last segment's geometric
            # stiffness T / l <= |end force| / l0 added as a margin for the change of K
            # between the two solutions
            rows = end_rows(dynamic, s_state.positions, anchors)
            l0 = static.model.structure.rest_length[static.model.structure.load_node - np.arange(model.yarns) - 1]
            row = rows + np.abs(s_record["end_force"]) / l0
            difference = np.abs(d_record["end_force"] - s_record["end_force"])
            assert (difference <= row * bound).all(), (difference, row * bound)


@pytest.mark.parametrize("method", ["explicit", "semi_implicit"])
def test_a_relaxation_that_cannot_finish_raises_one_line(method):
    """The time-step limit reached: SolverError, one line naming the patch, the step limit
    and the residual."""
    model = paper_patch_model(2, 2, [(0.3, 0.0)], tolerance=TOLERANCE)
    solver = dynamic_solver(model, max_steps=3, method=method)
    with pytest.raises(SolverError) as raised:
        solver.step(model.initial_state(), (0.3, 0.0))
    message = str(raised.value)
    assert "\n" not in message and message.startswith("fabric: no convergence in 3 time steps")
    assert "dynamic.max_steps" in message and "residual" in message


@pytest.mark.parametrize("method", ["explicit", "semi_implicit"])
def test_a_step_reports_within_itself_and_chunked_launches_keep_the_bits(method):
    """The grouped layout runs the time loop inside one kernel thread a chunk of time steps
    at a time (`StructureRelaxation.chunk` first, then chunks sized to `chunk_seconds`), so
    that the progress line (`status`) updates, and Ctrl-C is taken, within a step. A first
    chunk of 5 steps, then one step per launch (`chunk_seconds` 0), gives the very bits of the
    whole loop in one launch, and `status` is called after each with the steps taken and the
    residual; the stability check is announced too."""
    model = paper_patch_model(2, 2, [(0.3, 0.1)], friction=PAPER_FRICTION, tolerance=TOLERANCE)
    runs = []
    for chunk, seconds in ((10 ** 9, None), (5, 0.0)):
        calls = []
        solver = dynamic_solver(model, calls.append, method=method)
        solver.relaxation.chunk, solver.relaxation.chunk_seconds = chunk, seconds
        state, record = solver.step(model.initial_state(), (0.3, 0.1))
        runs.append((state, record, calls))
    (whole, whole_record, quiet), (chunked, chunked_record, calls) = runs
    np.testing.assert_array_equal(chunked.positions, whole.positions)
    np.testing.assert_array_equal(chunked.anchors, whole.anchors)
    assert chunked_record["time_steps"] == whole_record["time_steps"] > 10
    relaxing = [c for c in calls if "time steps, residual" in c]
    assert len(relaxing) >= whole_record["time_steps"] - 4  # 5 steps, then one per launch
    assert relaxing[0].startswith("dynamic: 5 time steps, residual ")
    assert relaxing[-1].endswith("0 of 1 groups running")
    assert len([c for c in quiet if "time steps, residual" in c]) < len(relaxing)
    assert any("stability check" in c for c in calls)


@pytest.mark.parametrize("method", ["explicit", "semi_implicit"])
def test_the_node_parallel_layout_takes_the_grouped_step_bit_for_bit(method):
    """The node-parallel layout (a GPU's: a launch per stage, the time loop here) takes the
    grouped layout's load step (in its gather order) bit for bit, the certificate and the
    record included: `--device cuda` changes the layout, not the answer. On the periodic cell
    with friction (tied cell lengths, moving planes, wrap springs), whose variant
    tests/test_kernels_structure.py builds in both layouts; its progress is reported too."""
    model = paper_patch_model(2, 2, [(0.2, 0.1)], friction=PAPER_FRICTION, tolerance=TOLERANCE,
                              boundary="periodic")
    runs = []
    for layout in ("grouped", "node_parallel"):
        calls = []
        solver = DynamicSolver(model, replace(model.scene.dynamic, method=method),
                               progress=calls.append, layout=layout, order="gather")
        runs.append((*solver.step(model.initial_state(), (0.2, 0.1)), calls))
    (grouped, grouped_record, _), (parallel, parallel_record, calls) = runs
    np.testing.assert_array_equal(parallel.positions, grouped.positions)
    np.testing.assert_array_equal(parallel.anchors, grouped.anchors)
    for name in grouped_record:
        np.testing.assert_array_equal(parallel_record[name], grouped_record[name], err_msg=name)
    assert [c for c in calls if "time steps, residual" in c]


SETTINGS = {"physical masses": dict(masses="physical"),
            "float32": dict(precision="float32", accuracy=math.inf),
            "adaptive viscous": dict(damping="viscous"), "FIRE": dict(damping="fire")}
"""[dynamic] settings the fabric's own dynamic solver refused before the one solver ran it
(float32's accuracy check off: its bound on this soft patch is above 0.1 of the step's
displacement, which the check would rightly refuse; the bound itself is checked here)."""


@pytest.mark.parametrize("name", sorted(SETTINGS))
def test_every_dynamic_setting_runs_the_fabric_to_the_static_step(name):
    """Physical masses, float32 (its default tolerance 1e-4 N), adaptive viscous damping and
    FIRE on a 2 x 2 patch without friction: the step within `agreement_bound` of the static
    solver's (||J^-1|| (r_dynamic + r_static); float32's residual is its kernel's, whose own
    rounding, about eps_32 x the 0.3 N forces, is far below 1e-4 N)."""
    model = paper_patch_model(2, 2, [(0.3, 0.1)], tolerance=TOLERANCE)
    options = dict(SETTINGS[name])
    if name == "float32":
        options["tolerance"] = None
    static = StaticSolver(model)
    start = model.initial_state()
    s_state, s_record = static.step(start, (0.3, 0.1))
    state, record = dynamic_solver(model, **options).step(start, (0.3, 0.1))
    bound = agreement_bound(static, s_state, start.anchors, s_record, record["residual"], 0.0)
    assert np.abs(s_state.positions - start.positions).max() > 10 * bound
    assert np.abs(state.positions - s_state.positions).max() <= bound
    assert record["residual"] <= (1e-4 if name == "float32" else TOLERANCE)


def test_a_given_dt_above_the_bound_warns_and_ten_times_it_diverges_in_one_line():
    """Physical masses with dynamic.dt given: 1.02 x the predicted stable dt (Gershgorin,
    conservative) runs with one warning; 10 x diverges within a few steps, a SolverError of
    one line naming the patch, the time step against the bound and the cause."""
    model = paper_patch_model(2, 2, [(0.3, 0.1)], tolerance=TOLERANCE)
    start = model.initial_state()
    bound = dynamic_solver(model, masses="physical").predicted_stable_dt(start, (0.3, 0.1))[0]
    with pytest.warns(RuntimeWarning, match="above the predicted stable time step"):
        dynamic_solver(model, masses="physical", dt=1.02 * bound).step(start, (0.3, 0.1))
    with pytest.raises(SolverError) as raised, pytest.warns(RuntimeWarning):
        dynamic_solver(model, masses="physical", dt=10 * bound).step(start, (0.3, 0.1))
    message = str(raised.value)
    assert "\n" not in message
    assert re.match(r"fabric: the explicit integration diverged after \d time steps .* against "
                    r"the predicted stable dt .*likely cause: the time step is above", message)


def test_the_dynamic_solver_leaves_the_fabric_saddle():
    """Held wefts, warps pushed in (tests/test_fabric_static.py: Newton on the symmetric path
    stops on a saddle): the relaxation from the symmetric start settles on the saddle too, the
    certificate (the sparse route, `dynfab.solvers.certificate.certify_groups`) finds it, the step
    leaves it along an escape and relaxes to a minimum: buckled at the first step, every
    step stable with its lowest eigenvalue proved positive (above its bracket's width)."""
    from test_fabric_static import patch_model

    values = (-3e-4, -6e-4)
    model = patch_model("displacement", values, None, hold="weft")
    solver = dynamic_solver(model, tolerance=TOLERANCE)
    state, buckled = model.initial_state(), []
    for value in values:
        state, record = solver.step(state, (value, 0.0))
        buckled.append(bool(record["buckled"]))
        assert record["stable"] and record["negative_eigenvalues"] == 0
        assert record["lowest_eigenvalue"] > record["lowest_eigenvalue_error"]
    assert buckled[0]


K_C = 1e5
"""The core stiffness k_c [N/m] of the held-weft patch (a fabric's default)."""
FRICTION_STICK = 1e3
"""k_t [N/m] of the held-weft friction comparison, given to both models (the fabric's default
is the smaller family's EA / segment length, the one-yarn model's its warp's)."""


def held_weft_patch(friction):
    """2 warps x 3 wefts of the paper's yarn (8 segments per half-wave), every weft dof held,
    the warps pulled by 0.3 N; `friction` a [friction] table or None."""
    tables = {} if friction is None else {"friction": friction}
    scene = paper_patch_scene(2, 3, load={"control": "force", "values": [0.3]},
                              contact={"core_stiffness": K_C},
                              dynamic={"tolerance": 1e-10}, **tables)
    return held_family(scene, "weft")


def rigid_weft_yarns(patch: FabricModel, friction):
    """The one-yarn model of the patch's warps (geometry.yarns = 2, phases +-1) with a rigid
    weft spring: contact_law k_s = k_c exactly (docs/model.md section 10: k_we -> infinity)."""
    family, weft = patch.warp, patch.weft
    tables = {} if friction is None else {"friction": friction}
    scene = make_scene(**tables,
                       geometry={"length": family.length, "segments": family.segments,
                                 "crossings": patch.wefts, "amplitude": family.amplitude,
                                 "yarns": patch.warps},
                       warp={"EA": family.EA, "EI": family.EI, "kawabata_C": family.kawabata_C,
                             "kawabata_K": family.kawabata_K},
                       weft={"EI": weft.EI, "length": weft.length, "count": patch.warps,
                             "amplitude": weft.amplitude, "kawabata_C": weft.kawabata_C,
                             "kawabata_K": weft.kawabata_K},
                       contact={"core_stiffness": K_C}, load={"control": "force", "values": [0.3]})
    model = build_model(scene)
    yarns = tuple(y._replace(contact_law=np.r_[K_C, y.contact_law[1:]]) for y in model.yarns)
    return replace(model, yarns=yarns)


def one_yarn_inverse_norm(model, positions, anchors, coupled) -> float:
    """max over yarns of ||K^-1||_inf [m/N], K the Hessian on the free dofs (coupled: the
    Jacobian of the friction problem, F_T following R), with the step's anchors (yarns, C)."""
    free = ~model.fixed_dofs()
    norms = []
    for k, yarn in enumerate(model.yarns):
        band = assembly.tangent(positions[k], yarn, anchors[k], coupled)
        norms.append(np.abs(np.linalg.inv(dense(band)[np.ix_(free, free)])).sum(axis=1).max())
    return max(norms)


@pytest.mark.parametrize("with_friction, damping", [(False, "kinetic"), (True, "kinetic"),
                                                    (False, "fire")])
def test_held_wefts_give_the_one_yarn_model_with_a_rigid_weft_spring(with_friction, damping):
    """Every weft node held: each warp is the one-yarn model with k_s = k_c
    (docs/model.md section 10); with friction, the weft node's slip y - Y_k - xi_y stays 0, so
    the isotropic Huber term is the one-yarn model's on x alone. The dynamic solver's step on
    the patch against the one-yarn static reference.

    Linearising the residual at the solution, x_fabric - x_static = K^-1 (r_fabric - r_static),
    so |x_fabric - x_static|_inf <= ||K^-1||_inf (r + r_s), K the warp's Hessian on its free
    dofs (with the wefts held the fabric's K is block-diagonal, one one-yarn K per warp; with
    friction, the Jacobian of the coupled problem at the step's anchors). The return-mapped
    anchors then agree to the same bound: xi = x - F_T s / (k_t |s|) at a sliding crossing
    moves with x and with F_T / k_t, whose change alpha dR / k_t <= alpha k_c dz / k_t adds the
    factor (1 + alpha k_c / k_t)."""
    friction = dict(PAPER_FRICTION, stick_stiffness=FRICTION_STICK) if with_friction else None
    patch = held_weft_patch(friction)
    model = rigid_weft_yarns(patch, friction)
    start = initial_state(model)
    state, record = StaticSolver(model).step(start, 0.3)
    fabric, fabric_record = dynamic_solver(patch, damping=damping).step(patch.initial_state(),
                                                                        patch.step_load(0))
    f = patch.structure
    weft_nodes = f.chain_family[chain_of_node(f)] == 1
    assert np.array_equal(fabric.positions[weft_nodes], f.rest_position[weft_nodes])
    norm = one_yarn_inverse_norm(model, model.per_yarn(state.positions),
                                 model.per_crossing(start.anchors), with_friction)
    bound = norm * (fabric_record["residual"] + np.max(record["residual"]))
    error = np.abs(fabric_record["positions"] - model.per_yarn(state.positions)).max()
    assert np.abs(state.positions - start.positions).max() > 1e3 * bound
    assert error <= bound, (error, bound)
    if with_friction:
        planes = f.tie_plane[:, 0].reshape(patch.warps, patch.wefts)
        fabric_anchors = fabric_record["anchors"][..., 0] + planes
        slid = np.abs(state.anchors - start.anchors).max()
        law = uniform(f.tie_friction_law)
        anchor_gap = bound * (1 + law[0] * K_C / law[3])
        assert slid > 1e3 * anchor_gap  # crossings slide
        assert np.abs(fabric_anchors - model.per_crossing(state.anchors)).max() <= anchor_gap
        assert not fabric_record["anchors"][..., 1].any()  # the wefts do not slip


CELL_SETTINGS = {"physical masses": dict(masses="physical"),
                 "float32": dict(precision="float32", accuracy=math.inf, tolerance=None)}
"""The [dynamic] settings of `SETTINGS` that no other test runs on the periodic cell (its
tied cell lengths, moving planes and wrap springs compiled in; float32's accuracy check off
and its default tolerance, as in `SETTINGS`)."""


@pytest.mark.parametrize("name", sorted(CELL_SETTINGS))
def test_physical_masses_and_float32_run_the_periodic_cell_to_the_static_step(name):
    """The periodic 2 x 2 cell with friction (the variant of
    `test_the_node_parallel_layout_takes_the_grouped_step_bit_for_bit`, in float32 its own):
    the step within `agreement_bound` of the static solver's (the same start, so the same
    anchors), float32's residual within its default tolerance 1e-4 N (its rounding, about
    eps_32 x the 0.2 N forces, far below), the cell stretched far beyond the bound."""
    model = paper_patch_model(2, 2, [(0.2, 0.1)], friction=PAPER_FRICTION, tolerance=TOLERANCE,
                              boundary="periodic")
    static = StaticSolver(model)
    start = model.initial_state()
    s_state, s_record = static.step(start.copy(), (0.2, 0.1))
    state, record = dynamic_solver(model, **CELL_SETTINGS[name]).step(start.copy(), (0.2, 0.1))
    assert record["residual"] <= (1e-4 if name == "float32" else TOLERANCE)
    if name == "physical masses":
        assert record["dt"] < 1e-3  # the physical time step, not the fictitious masses' 1 s
    bound = agreement_bound(static, s_state, start.anchors, s_record, record["residual"], 0.0)
    assert np.abs(s_state.positions - start.positions).max() > 10 * bound
    assert np.abs(state.positions - s_state.positions).max() <= bound
