"""The fabric's semi-implicit solver (`kernels/fabric_semi_implicit.py`) against the static
reference: its tangent against the exact Hessian, its preconditioned CG against a dense
solve, its load steps against Newton's within their residual bounds (docs/model.md sections 5,
10).

Four kernels (float64, friction compiled in): the relaxation, the one-thread system
assembly/solve, and the per-step layout's two stage kernels (PCG, the rest of a step); the
force passes and the explicit relaxation are those tests/test_fabric_kernels.py builds.
"""

import numpy as np
import pytest
import scipy.linalg

from dynfab.errors import SolverError
from dynfab.fabric import assembly
from dynfab.fabric.dynamic import FabricDynamicSolver
from dynfab.static import StaticSolver
from dynfab.kernels import fabric_semi_implicit
from dynfab.run import run
from dynfab.scene import parse_scene_text
from dynfab.structure import uniform
from independent import PAPER_FRICTION
from test_fabric_dynamic import (DISPLACEMENTS, FORCES, TOLERANCE, agreement_bound,
                                 anchor_bound, paper_patch_model)
from test_fabric_dynamic_scenes import mixed_anchors, perturbed_state
from test_fabric_scenes import position_bound, small_pullout

EPS = np.finfo(float).eps


def loaded_state(n=2, friction=PAPER_FRICTION, value=0.3, **more):
    """(static solver, dynamic solver, positions at the end of a static step, anchors): a
    deformed patch with closed contacts; the anchors held during the step, under which every
    crossing of a clamped patch slides (k_t |s| > F_T), except every other crossing's moved
    to within 1e-3 F_T / k_t of its slip point, so that it sticks: both Huber branches
    present. `more`: `paper_patch_model`'s boundary, planes."""
    model = paper_patch_model(n, n, [(value, 0.1 * value)], friction=friction,
                              tolerance=TOLERANCE, **more)
    static = StaticSolver(model)
    dynamic = FabricDynamicSolver(model, method="semi_implicit")
    start = static.initial_state()
    state, _ = static.step(start, (value, 0.1 * value))
    f, pos = static.model.structure, state.positions
    anchors = start.anchors.copy()
    plane_x, plane_y = assembly.planes(pos, f)
    slip_point = np.stack([pos[f.tie_a, 0] - plane_x, pos[f.tie_b, 0] - plane_y], 1)
    stick = uniform(f.tie_friction_law)[3]  # k_t
    nearby = 1e-3 * static.backend.friction_limits(pos)[:, None] / max(stick, 1.0)
    anchors[::2] = slip_point[::2] - nearby[::2]
    return static, dynamic, pos, anchors


def assembled(dynamic, pos, anchors, **options):
    """The semi-implicit system's A on the unknowns (the static solver's, `Pattern.index`)
    after `FabricSemiImplicit.system` at pos, column by column from the kernels' product."""
    semi = dynamic.relaxation
    bad, iterations = semi.system(pos, np.zeros_like(pos), anchors + dynamic._plane_shift,
                                  **options)
    assert bad < 0
    return semi.dense(dynamic.model.pattern.index), iterations


def test_the_tangent_is_the_exact_hessian_without_its_psd_modifications():
    """With zero masses and dt = 1, A = K; with `definite` off, K is the static solver's exact
    Hessian (F_T frozen at F_T(R) of the same positions) on the free dofs, to the rounding of
    a few tens of operations on the largest entry. With `definite` on (the solver's K), the
    crossing blocks are unchanged, only the yarn bands lose the compressed segments' geometric
    part and the bending moment term, and K is positive semi-definite; at the as-woven state,
    where every segment has its rest length and every angle its rest angle, both coincide."""
    static, dynamic, pos, anchors = loaded_state()
    limit = static.backend.friction_limits(pos)
    R = static.backend.contact_forces(pos)
    assert R.min() > 0  # every contact closed
    f = static.model.structure
    s = pos[f.tie_a, 0] - f.tie_plane[:, 0] - anchors[:, 0]
    s_y = pos[f.tie_b, 0] - f.tie_plane[:, 1] - anchors[:, 1]
    sliding = uniform(f.tie_friction_law)[3] * np.hypot(s, s_y) > limit
    assert sliding.any() and not sliding.all()  # both Huber branches exercised
    zero = np.zeros(dynamic.arrays.nodes)
    H = static.backend.hessian(pos, anchors, limit).toarray()
    exact, _ = assembled(dynamic, pos, anchors, definite=False, masses=zero)
    scale = np.abs(H).max()
    assert np.abs(exact - H).max() <= 64 * EPS * scale
    definite, _ = assembled(dynamic, pos, anchors, definite=True, masses=zero)
    assert np.linalg.eigvalsh(definite).min() >= -64 * EPS * scale
    assert np.abs(definite - exact).max() > 1e-6 * scale  # the modifications are real here
    rest = dynamic.arrays.rest_position
    at_rest = [assembled(dynamic, rest, 0 * anchors, definite=flag, masses=zero)[0]
               for flag in (False, True)]
    assert np.abs(at_rest[0] - at_rest[1]).max() <= 64 * EPS * scale


@pytest.mark.parametrize("case", ["affine", "periodic", "periodic-displacement"])
def test_the_tangent_has_the_moving_planes_wrap_springs_and_tied_cell_lengths(case):
    """Where the planes move (a clamped patch with planes "affine", the periodic cell), with
    zero masses, dt = 1 and `definite` off, the kernels' product on the unknowns (a tied
    family's end nodes one unknown: T^T A T) is the static solver's exact Hessian, to the
    rounding of a few tens of operations on the largest entry, at perturbed positions with
    sliding and sticking crossings: the planes' rank-one blocks sum_c J_c^T H_c J_c (J_c
    carrying -w_c on the end dofs moving the planes), the wrap springs' blocks between a
    yarn's first and last nodes, and the cell length's summed rows. Not vacuous: each of
    the three is far above the bound where it acts (leaving it out fails). With `secant`
    (the relaxation's blocks where the planes move) it is the static solver's Hessian with
    the sliding crossings' secant stiffness, to the same rounding, and differs from the
    exact one (sliding crossings present)."""
    boundary = "clamped" if case == "affine" else "periodic"
    control = "displacement" if case.endswith("displacement") else "force"
    values = (2e-5, 1e-5) if control == "displacement" else (0.2, 0.1)
    model = paper_patch_model(2, 2 if boundary == "periodic" else 3, [values], control,
                              PAPER_FRICTION, boundary=boundary,
                              planes="affine" if case == "affine" else "fixed",
                              tolerance=TOLERANCE)
    static = StaticSolver(model)
    dynamic = FabricDynamicSolver(model, method="semi_implicit")
    pos = perturbed_state(static)
    anchors = mixed_anchors(static, pos)
    limit = static.backend.friction_limits(pos)
    H = static.backend.hessian(pos, anchors, limit).toarray()
    semi = dynamic.relaxation
    semi.system(pos, np.zeros_like(pos), anchors + dynamic._plane_shift, definite=False,
                masses=np.zeros(dynamic.arrays.nodes))
    A = semi.dense(static.backend.pattern.index)
    scale = np.abs(H).max()
    assert np.abs(A - H).max() <= 64 * EPS * scale
    beyond = ~local_pattern(dynamic, static.backend.pattern.index)
    assert np.abs(H[beyond]).max() > 1e6 * 64 * EPS * scale
    secant = static.backend.hessian(pos, anchors, limit, secant=True).toarray()
    semi.system(pos, np.zeros_like(pos), anchors + dynamic._plane_shift, definite=False,
                masses=np.zeros(dynamic.arrays.nodes), secant=True)
    assert np.abs(semi.dense(static.backend.pattern.index) - secant).max() <= 64 * EPS * scale
    assert np.abs(secant - H).max() > 1e6 * 64 * EPS * scale


def local_pattern(dynamic, index) -> np.ndarray:
    """(U, U) True where two unknowns share a yarn band (nodes at most two apart on one
    yarn) or a crossing: the clamped patch's pattern with fixed planes; the entries beyond it
    are the planes', the wrap springs' and the tied cell length's."""
    a = dynamic.arrays
    start = fabric_semi_implicit.yarn_starts(a)
    node_yarn = np.repeat(np.arange(start.size - 1), np.diff(start))
    nodes = np.arange(a.nodes)
    near = (node_yarn[:, None] == node_yarn[None, :]) & (np.abs(nodes[:, None] - nodes) <= 2)
    near[a.crossing_warp, a.crossing_weft] = near[a.crossing_weft, a.crossing_warp] = True
    near = np.repeat(np.repeat(near, 2, axis=0), 2, axis=1)
    known = np.flatnonzero(index >= 0)
    rows, cols = np.nonzero(near[np.ix_(known, known)])
    local = np.zeros((index.max() + 1,) * 2, bool)
    local[index[known[rows]], index[known[cols]]] = True
    return local


@pytest.mark.parametrize("case", ["clamped", "affine", "periodic"])
@pytest.mark.parametrize("dt", [1.0, 1e4])
def test_preconditioned_cg_meets_its_stopping_bound_against_a_dense_solve(dt, case):
    """At a deformed state with velocities, the right-hand side is dt (f - dt K v) (K from A)
    on the unknowns, CG stops with r^T P^-1 r <= CG_TOLERANCE^2 b^T P^-1 b, and its error in
    the A-norm is within the bound that criterion gives: ||x - x*||_A^2 = r^T A^-1 r <=
    r^T P^-1 r / lambda_min, lambda_min the smallest eigenvalue of the pencil (A, P); x* from
    a dense solve. dt = 1 (the start: A near M) and 1e4 (A near dt^2 K: a Newton step). On the
    reduced system: a tied cell length is one unknown (its copies' rows summed, its mass the
    family's, the inner product counting it once), its P entry A's diagonal alone; the
    planes' and wrap springs' couplings are in A, not in P."""
    more = {"clamped": {}, "affine": dict(planes="affine"), "periodic": dict(boundary="periodic")}
    static, dynamic, pos, anchors = loaded_state(**more[case])
    semi = dynamic.relaxation
    rng = np.random.default_rng(7)
    index = dynamic.model.pattern.index
    step = rng.standard_normal(index.max() + 1) * 1e-6
    velocities = np.where(index >= 0, step[index], 0.0).reshape(pos.shape)  # copies alike
    _, iterations = assembled(dynamic, pos, anchors, dt=dt, solve=True, velocities=velocities)
    A = semi.dense(index)
    first = np.array([np.flatnonzero(index == u)[0] for u in range(A.shape[0])])
    tied = np.bincount(index[index >= 0]) > 1  # a family's end dofs sharing an unknown
    assert tied.any() == (case == "periodic")
    b, x = semi.work.rhs.numpy()[first], semi.work.x.numpy()[first]
    mass = np.repeat(semi.mass.numpy(), 2)[first]  # a tied family's: the sum of its ends'
    K = (A - np.diag(mass)) / dt ** 2
    force = semi.force.numpy().ravel()[first]  # a tied end's: its family's summed force
    expected = dt * (force - dt * K @ velocities.ravel()[first])
    assert np.abs(b - expected).max() <= 1e-9 * np.abs(dt * force).max()
    yarn = block_pattern(dynamic)[np.ix_(first, first)] & ~tied[:, None] & ~tied[None, :]
    P = np.where(yarn, A, 0.0)
    P[np.diag_indices_from(P)] = np.diag(A)  # plus the crossing blocks' and ties' diagonals
    exact = np.linalg.solve(A, b)
    r = b - A @ x
    tolerance = fabric_semi_implicit.CG_TOLERANCE
    b_norm2 = b @ np.linalg.solve(P, b)
    r_norm2 = r @ np.linalg.solve(P, r)
    assert 0 < iterations < b.size
    assert r_norm2 <= tolerance ** 2 * b_norm2 * (1 + 1e-6)
    smallest = scipy.linalg.eigh(A, P, eigvals_only=True).min()
    error = x - exact
    assert error @ A @ error <= r_norm2 / smallest * (1 + 1e-6)


def test_the_launch_per_stage_pcg_is_the_persistent_one_bit_for_bit():
    """The GPU's layout of one PCG solve (a launch per stage, threads per dof, node and yarn,
    sums over the yarns in order) gives the persistent kernel's x exactly and the same
    iteration count, whether the done flag is read back every iteration or every 4th."""
    static, dynamic, pos, anchors = loaded_state(n=4, value=0.1)
    semi = dynamic.relaxation
    semi.cg_tolerance = 1e-10  # many iterations
    dt = 1e4
    _, iterations = assembled(dynamic, pos, anchors, dt=dt, solve=True)
    x = semi.work.x.numpy().copy()
    assert iterations > 4
    for interval in (1, 4):
        assert fabric_semi_implicit.pcg_launches(semi, dt, check_interval=interval) == iterations
        np.testing.assert_array_equal(semi.work.x.numpy(), x)


@pytest.mark.parametrize("case", ["clamped", "affine", "periodic"])
def test_the_per_step_layout_relaxes_as_the_persistent_one_bit_for_bit(case):
    """The GPU's layout of the whole relaxation (`FabricSemiImplicit._per_step`: a launch per
    stage, decisions from values read back) takes the persistent kernel's time steps exactly:
    the same positions, steps, CG iterations, rejected and shortened steps, with friction, on a
    4 x 4 clamped patch (pulled harder, 5 N and 1 N: steps both shortened by the line search
    and undone), a 3 x 3 patch with moving planes, a 2 x 2 periodic cell (its cell lengths
    tied); a tied family's end nodes keep one in-plane coordinate."""
    n, (warp, weft), more = {"clamped": (4, (5.0, 1.0), {}),
                             "affine": (3, (0.3, 0.1), dict(planes="affine")),
                             "periodic": (2, (0.3, 0.1), dict(boundary="periodic"))}[case]
    model = paper_patch_model(n, n, [(warp, weft)], friction=PAPER_FRICTION, tolerance=TOLERANCE,
                              **more)
    ends = []
    for layout in ("persistent", "per_step"):
        dynamic = FabricDynamicSolver(model, method="semi_implicit", layout=layout)
        begun = dynamic.model.start_of_step(dynamic.initial_state(), (warp, weft))
        pos, anchors, P = begun.positions, begun.anchors, begun.chain_loads
        ends.append(dynamic.relax(pos, P, anchors))
    (x_persistent, persistent), (x_per_step, per_step) = ends
    assert persistent.cg_iterations > persistent.steps
    assert persistent.shortened > 0
    if case == "clamped":
        assert persistent.rejected > 0
    assert vars(per_step) == vars(persistent)
    np.testing.assert_array_equal(x_per_step, x_persistent)
    tie = dynamic.arrays.node_tie
    for family in (0, 1):
        ends = x_persistent[tie == family, 0]
        assert ends.size == (n if case == "periodic" else 0)
        assert np.all(ends == ends[:1])


def block_pattern(dynamic) -> np.ndarray:
    """True where two dofs belong to the same yarn (the preconditioner's blocks)."""
    start = fabric_semi_implicit.yarn_starts(dynamic.arrays)
    yarn = np.repeat(np.repeat(np.arange(start.size - 1), np.diff(start)), 2)
    return yarn[:, None] == yarn[None, :]


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
    dynamic = FabricDynamicSolver(model, method="semi_implicit")
    s_state, d_state = static.initial_state(), dynamic.initial_state()
    k_c = uniform(static.model.structure.tie_contact_law)[0]
    for warp_value, weft_value in values:
        anchors = s_state.anchors.copy()
        anchor_gap = float(np.hypot(*(d_state.anchors - s_state.anchors).T).max())
        start = s_state.positions
        s_state, s_record = static.step(s_state, (warp_value, weft_value))
        d_state, d_record = dynamic.step(d_state, (warp_value, weft_value))
        assert d_record["residual"] <= TOLERANCE
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
    assert dynamic.linear_iterations > 0


def test_records_have_the_explicit_solvers_keys_and_runs_repeat_bit_for_bit():
    """The semi-implicit step returns the explicit step's record keys plus its CG iterations
    (those of the step); a second solver on the same step gives identical positions (every
    sum in a fixed order, no atomics)."""
    model = paper_patch_model(2, 2, [(0.1, 0.0)], friction=PAPER_FRICTION, tolerance=TOLERANCE)
    explicit = FabricDynamicSolver(model)
    semis = [FabricDynamicSolver(model, method="semi_implicit") for _ in range(2)]
    _, e_record = explicit.step(explicit.initial_state(), (0.1, 0.0))
    states = [semi.step(semi.initial_state(), (0.1, 0.0)) for semi in semis]
    assert states[0][1].keys() == e_record.keys() | {"cg_iterations"}
    assert 0 < states[0][1]["cg_iterations"] == semis[0].linear_iterations
    np.testing.assert_array_equal(states[0][0].positions, states[1][0].positions)


def test_a_semi_implicit_scene_runs_and_matches_the_static_run():
    """`[dynamic] method = "semi_implicit"` on a fabric scene (the 4 x 4 pull-out with friction
    and gravity) runs, each step within twice `position_bound` of the static run's."""
    text = small_pullout() + '\n[dynamic]\nmethod = "semi_implicit"\n'
    scene = parse_scene_text(text)
    from dynfab.fabric.model import FabricModel

    model = FabricModel.from_scene(scene)
    static, semi = run(scene, "static"), run(scene, "dynamic")
    assert semi.attrs["dynamic_method"] == "semi_implicit"
    for i in range(static.step_count):
        tol = 2 * position_bound(model, static, i)
        for name in ("positions", "weft_positions"):
            np.testing.assert_allclose(semi.steps[name][i], static.steps[name][i], rtol=0, atol=tol)
        np.testing.assert_array_equal(semi.steps["sliding"][i], static.steps["sliding"][i])


def test_a_semi_implicit_relaxation_that_cannot_finish_raises_one_line():
    """The time-step limit reached: SolverError, one line naming the cause and the residual."""
    model = paper_patch_model(2, 2, [(0.3, 0.0)], tolerance=TOLERANCE)
    solver = FabricDynamicSolver(model, max_steps=3, method="semi_implicit")
    with pytest.raises(SolverError) as raised:
        solver.step(solver.initial_state(), (0.3, 0.0))
    message = str(raised.value)
    assert "\n" not in message and "time-step limit" in message and "3 time steps" in message
