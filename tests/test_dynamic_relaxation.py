"""The dynamic solver's explicit relaxations: relaxed equilibria against the static reference
(docs/model.md sections 5-6).

A relaxation stops at a residual r (the largest free force component); the
static reference stops at its own r_s. Linearising the residual map g at the
solution, x_dyn - x_static = K^-1 (g(x_dyn) - g(x_static)), so

    |x_dyn - x_static|_inf <= ||K^-1||_inf (r + r_s),

with ||K^-1||_inf computed with numpy from the dense Hessian (the Jacobian of the
coupled friction problem where there is friction) over the free dofs at the
static solution. Every position comparison below uses exactly this bound.
Load paths are reduced to a few steps to keep the suite fast.
"""

import math
import warnings
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from dynfab.model import assembly
from dynfab.linalg.banded import BANDWIDTH, to_dense
from dynfab.solvers.dynamic import DynamicSolver
from dynfab.errors import SolverError
from dynfab.kernels import status, structure_checks
from dynfab.model.yarn import initial_state
from dynfab.model.builders import build_model
from dynfab.scene import Dynamic, load_scene, with_key
from dynfab.solvers.static import StaticSolver

RUNS = Path(__file__).resolve().parent.parent / "runs"


def inverse_stiffness_norm(model, positions, anchors, coupled) -> np.ndarray:
    """||K^-1||_inf [m/N] per yarn: K the dense Hessian (coupled: the friction Jacobian)
    on the free dofs."""
    free = ~model.fixed_dofs()
    norms = []
    for k, yarn in enumerate(model.yarns):
        band = assembly.tangent(positions[k], yarn, anchors[k], coupled)
        inverse = np.linalg.inv(to_dense(band)[np.ix_(free, free)])
        norms.append(np.abs(inverse).sum(axis=1).max())
    return np.array(norms)


def assert_same_equilibrium(model, static_state, static_record, dynamic_state, dynamic_record,
                            coupled=False):
    """Positions within ||K^-1||_inf (r_dynamic + r_static) of each other, yarn by yarn."""
    static, dynamic = model.per_yarn(static_state.positions), model.per_yarn(dynamic_state.positions)
    bound = inverse_stiffness_norm(model, static, static_record["anchors"], coupled) \
        * (dynamic_record["residual"] + static_record["residual"])
    error = np.abs(dynamic - static).max(axis=(1, 2))
    assert (error <= bound).all(), f"position error {error} m above the bound {bound} m"


def relax_path(scene, options=None):
    """Static and dynamic states and records of every load step, each solver from its own last state."""
    model = build_model(scene)
    static, dynamic = StaticSolver(model), DynamicSolver(model, options)
    static_state = dynamic_state = initial_state(model)
    for load_value in model.load_values:
        static_state, static_record = static.step(static_state, load_value)
        dynamic_state, dynamic_record = dynamic.step(dynamic_state, load_value)
        yield model, static_state, static_record, dynamic_state, dynamic_record


@pytest.fixture(scope="module")
def fig3():
    """Fig. 3's K sweep (three yarns batched), displacement control, two load steps."""
    return with_key(load_scene(RUNS / "paper_fig3.toml"), "load.values", [0.001, 0.003])


def test_kinetic_damping_matches_static_on_fig3_sweep(fig3):
    for model, *states in relax_path(fig3):
        assert model.yarn_count == 3
        assert_same_equilibrium(model, *states)


def test_kinetic_damping_as_woven_force_control(fig3):
    scene = with_key(with_key(fig3, "geometry.reference", "as_woven"), "load.control", "force")
    scene = with_key(scene, "load.values", [0.1, 0.3])
    for model, *states in relax_path(scene):
        assert_same_equilibrium(model, *states)


def test_kinetic_damping_with_friction_one_step_at_a_time():
    """Fig. 5 (friction on, and off as entry 1): both solvers start each step from the same state."""
    scene = with_key(load_scene(RUNS / "paper_fig5.toml"), "load.values", [0.0005, 0.002])
    model = build_model(scene)
    static, dynamic = StaticSolver(model), DynamicSolver(model)
    state, sliding = initial_state(model), []
    for load_value in model.load_values:
        static_state, static_record = static.step(state, load_value)
        dynamic_state, dynamic_record = dynamic.step(state, load_value)
        assert_same_equilibrium(model, static_state, static_record, dynamic_state, dynamic_record,
                                coupled=True)
        assert (dynamic_record["sliding"] == static_record["sliding"]).all()
        sliding.append(dynamic_record["sliding"][0].sum())
        state = static_state
    assert 0 < sliding[0] < model.crossings  # the first step has sticking and sliding crossings


def test_step_record_has_the_dynamic_fields(fig3):
    model, _, _, _, record = next(relax_path(with_key(fig3, "load.values", [0.001])))
    for name in ("time_steps", "force_evaluations", "dt"):
        assert record[name].shape == (model.yarn_count,)
    assert (record["time_steps"] > 0).all()
    assert (record["force_evaluations"] == record["time_steps"] + 1).all()
    assert (record["dt"] == 1.0).all()  # fictitious masses: dt = 1 s


def test_step_limit_raises_with_the_residual_reached(fig3):
    model = build_model(with_key(fig3, "load.values", [0.001]))
    solver = DynamicSolver(model, replace(model.scene.dynamic, max_steps=10))
    with pytest.raises(SolverError, match=r"yarn 1: no convergence in 10 time steps .*residual"):
        solver.step(initial_state(model), 0.001)


@pytest.mark.parametrize("options", [Dynamic(damping="viscous"),
                                     Dynamic(damping="viscous", damping_coefficient=5e-3),
                                     Dynamic(damping="fire")],
                         ids=["viscous-adaptive", "viscous-given", "fire"])
def test_damping_methods_match_static_on_fig3_sweep(fig3, options):
    """c = 5e-3 1/s is about critical for the lowest mode: 2 sqrt(lambda_min / m) with
    lambda_min ~ 0.25 N/m and fictitious m ~ 4e4 kg (dt = 1 s)."""
    for model, *states in relax_path(fig3, options):
        assert_same_equilibrium(model, *states)


def test_physical_masses_match_static_on_fig3_sweep(fig3):
    """Physical masses (each node its share of the yarn's linear density, the time step the
    stable one of those masses: far below the fictitious masses' 1 s) relax Fig. 3's sweep
    to the static equilibrium within the same bound."""
    for model, *states in relax_path(fig3, Dynamic(masses="physical")):
        assert_same_equilibrium(model, *states)
        assert (states[3]["dt"] < 1e-3).all()


@pytest.fixture(scope="module")
def relaxed_yarn(fig3):
    """One paper yarn (K = 0.2 m/N) relaxed by the static solver at u = 1 mm."""
    scene = with_key(replace(fig3, sweep=()), "load.values", [0.001])
    model = build_model(scene)
    state, _ = StaticSolver(model).step(initial_state(model), 0.001)
    return model, state


def undamped_motion_is_bounded(model, state, dt, steps) -> bool:
    """True if `steps` undamped symplectic Euler steps (physical masses, c = 0) from `state`
    keep the residual, hence the energy, within status.DIVERGENCE_FACTOR of its start."""
    options = Dynamic(damping="viscous", damping_coefficient=0.0, masses="physical", dt=dt,
                      tolerance=1e-300, max_steps=steps)
    try:
        DynamicSolver(model, options).step(state, 0.001)
    except SolverError as error:
        return "no convergence" in str(error)
    raise AssertionError("an undamped motion cannot converge")


@pytest.mark.filterwarnings("ignore:dynamic.dt = .* above the predicted stable:RuntimeWarning")
def test_predicted_stable_dt_is_close_to_the_measured_one(relaxed_yarn):
    """Gershgorin bounds lambda_max from above, so the predicted dt is at most the true limit;
    on a chain dominated by its axial springs the row sums exceed lambda_max only by the end
    and bending couplings, a few % (measured: 4 %), so the bound is tight within 10 %."""
    model, state = relaxed_yarn
    rng = np.random.default_rng(5)
    perturbed = state.copy()
    inner = model.per_yarn(perturbed.positions)[:, 1:-1]  # a view of the state's (n, 2)
    inner += rng.normal(0.0, 1e-9, inner.shape)
    physical = Dynamic(damping="viscous", damping_coefficient=0.0, masses="physical")
    predicted = DynamicSolver(model, physical).predicted_stable_dt(perturbed, 0.001)[0]
    stable, unstable = 0.5 * predicted, 4.0 * predicted
    assert undamped_motion_is_bounded(model, perturbed, stable, 3000)
    assert not undamped_motion_is_bounded(model, perturbed, unstable, 3000)
    while unstable / stable > 1.02:
        middle = np.sqrt(stable * unstable)
        if undamped_motion_is_bounded(model, perturbed, middle, 3000):
            stable = middle
        else:
            unstable = middle
    assert predicted <= stable <= 1.1 * predicted


def test_time_step_ten_times_the_bound_diverges_quickly(relaxed_yarn):
    """At 10x the bound the stiffest mode grows ~(omega dt)^2 ~ 400x a step: caught in < 10 steps;
    the finished state (the caller's) is left as it was."""
    model, state = relaxed_yarn
    finished = state.copy()
    physical = Dynamic(masses="physical")
    bound = DynamicSolver(model, physical).predicted_stable_dt(state, 0.002)[0]
    solver = DynamicSolver(model, replace(physical, dt=10 * bound))
    with pytest.raises(SolverError, match=r"yarn 1: the explicit integration diverged after [1-9] "
                                          r"time steps .* against the predicted stable dt"), \
            pytest.warns(RuntimeWarning, match="above the predicted stable time step"):
        solver.step(state, 0.002)
    assert np.array_equal(state.positions, finished.positions)
    assert np.array_equal(state.anchors, finished.anchors)


def test_float32_reaches_its_tolerance_or_rounding_floor(fig3):
    """float32 rounds positions near x = 0.1 m to 7e-9 m, so a 3e4 N/m spring's force to
    ~2e-4 N: the default 1e-4 N may be out of reach, met by stalling at the rounding floor
    16 eps max|K_ii| max|x| (docs/model.md sections 5-6). Either way the equilibrium is within
    ||K^-1||_inf (r + r_s) of the float64 reference. That bound (about 1.1e-3 m here) is
    not small against the 1e-3 m pulled, so the accuracy check (dynamic.accuracy) would
    stop this step with exit status 3 (tests/test_certificate.py); accuracy = inf lets the
    step finish so that the bound itself can be checked."""
    scene = with_key(replace(fig3, sweep=()), "load.values", [0.001])
    with warnings.catch_warnings(record=True):
        for model, static_state, static_record, state, record in relax_path(
                scene, Dynamic(precision="float32", accuracy=math.inf)):
            positions = model.per_yarn(state.positions)[0]
            band = assembly.tangent(positions, model.yarns[0], model.per_crossing(state.anchors)[0],
                                    False)
            floor = 16 * np.finfo(np.float32).eps * np.abs(band[:, BANDWIDTH]).max() \
                * np.abs(positions).max()
            assert record["residual"][0] <= max(1e-4, floor)
            assert_same_equilibrium(model, static_state, static_record, state, record)


@pytest.mark.parametrize("options", [Dynamic(), Dynamic(method="semi_implicit")],
                         ids=["kinetic", "semi_implicit"])
def test_default_tolerance_follows_a_tiny_load(fig3, options):
    """As-woven yarn pulled by 1 and 2 uN: an absolute 1e-8 N would allow an end displacement
    error of 1e-8 N x ||K^-1|| (several m/N here), about the 5.7e-8 m displacement itself. The
    default tolerance is min(1e-8 N, max(1e-6 x the force scale, rounding floor)) (docs/model.md
    section 5), so the residual x ||K^-1|| bound, which the positions must meet, is now within 1 %
    of the end displacement; a tolerance the user gives is used as given."""
    scene = with_key(replace(fig3, sweep=()), "geometry.reference", "as_woven")
    scene = with_key(with_key(scene, "load.control", "force"), "load.values", [1e-6, 2e-6])
    for model, static_state, static_record, state, record in relax_path(scene, options):
        assert record["tolerance"][0] < 1e-8
        assert_same_equilibrium(model, static_state, static_record, state, record)
        bound = inverse_stiffness_norm(model, model.per_yarn(static_state.positions),
                                       static_record["anchors"], False) * (record["residual"] + static_record["residual"])
        assert (bound <= 0.01 * np.abs(static_record["end_displacement"])).all()
    # A given 1e-8 N is used as given; the step's accuracy check (docs/model.md, stability and
    # accuracy) would rightly refuse what it leaves here, so it is switched off for this check.
    given = DynamicSolver(model, replace(options, tolerance=1e-8, accuracy=float("inf")))
    _, record = given.step(initial_state(model), 1e-6)
    assert (record["tolerance"] == 1e-8).all()


def fine_yarn(fig3, segments):
    """One paper yarn (K = 0.2 m/N) at `segments`, pulled by 1 mm in one load step."""
    scene = with_key(replace(fig3, sweep=()), "load.values", [0.001])
    return build_model(with_key(scene, "geometry.segments", segments))


@pytest.mark.filterwarnings("ignore:dynamic.dt = .* above the predicted stable:RuntimeWarning")
def test_fine_mesh_above_the_bound_diverges_within_a_bounded_step_count(fig3):
    """N = 896 at 1.3 x the predicted dt. The chain folds and its forces saturate (about 40 N)
    before the residual reaches 1e6 x its start: the energy test catches it (status.ENERGY_FACTOR).
    Step bound: the true limit is at most 1.1 x the prediction (test above), so omega dt >=
    2 x 1.3 / 1.1 = 2.36 and the unstable mode's amplitude grows by |lambda| >= 3.27 a step
    (symplectic Euler: lambda + 1/lambda = 2 - (omega dt)^2); KE / work grows with the
    amplitude, from at least the rounding 1e-16 to ENERGY_FACTOR = 1e3 in at most
    log(1e19) / log(3.27) = 37 steps, seen at the next test, every ENERGY_CHECK_INTERVAL = 16
    steps: 48 (measured: 16)."""
    model = fine_yarn(fig3, 896)
    state = initial_state(model)
    physical = Dynamic(masses="physical")
    bound = DynamicSolver(model, physical).predicted_stable_dt(state, 0.001)[0]
    solver = DynamicSolver(model, replace(physical, dt=1.3 * bound))
    with pytest.raises(SolverError, match=r"diverged after \d+ time steps \(the kinetic energy"):
        solver.step(state, 0.001)
    assert solver.relaxation.group_values("status")[0] == status.DIVERGED
    interval = structure_checks.ENERGY_CHECK_INTERVAL
    assert solver.last_relaxation()["time_steps"][0] <= interval * math.ceil(37 / interval)


@pytest.mark.parametrize("options", [Dynamic(), Dynamic(damping="viscous"), Dynamic(damping="fire"),
                                     Dynamic(masses="physical")],
                         ids=["kinetic", "viscous", "fire", "kinetic-physical"])
def test_paper_relaxations_stay_far_from_the_energy_test(fig3, options):
    """A stable motion from rest cannot have more kinetic energy than f0 . (x - x0) with a
    convex energy (ratio <= 1); symplectic Euler's half-step velocities at safety 0.9 raise
    that by at most 1 / (1 - 0.9^2) = 5.3. Every paper relaxation here (fig. 3's three
    yarns, fig. 5 with friction, N = 896) stays below that, 190 x under ENERGY_FACTOR."""
    fig5 = with_key(load_scene(RUNS / "paper_fig5.toml"), "load.values", [0.0005, 0.002])
    scenes = [fig3, fig5] if options == Dynamic() else [fig3]
    models = [build_model(scene) for scene in scenes] + [fine_yarn(fig3, 896)]
    for model in models:
        solver, state = DynamicSolver(model, options), initial_state(model)
        for load_value in model.load_values:
            state, _ = solver.step(state, load_value)
            assert (solver.last_relaxation()["energy_ratio"] <= 5.3).all()


@pytest.mark.filterwarnings("ignore:dynamic.dt = .* above the predicted stable:RuntimeWarning")
def test_step_limit_with_dt_above_the_bound_says_so(relaxed_yarn):
    """A mode just beyond its limit can oscillate at a bounded amplitude (measured at N = 896,
    1.024 x the bound: residual 2.8 to 3.7 N through 3 x 10^5 steps, KE / work 7, under the
    energy test), so a step limit reached with dt above the bound names it."""
    model, state = relaxed_yarn
    physical = Dynamic(masses="physical")
    bound = DynamicSolver(model, physical).predicted_stable_dt(state, 0.002)[0]
    solver = DynamicSolver(model, replace(physical, dt=1.02 * bound, max_steps=10))
    with pytest.raises(SolverError, match=r"no convergence in 10 time steps .* is above the "
                                          r"predicted stable dt .* lower dynamic\.dt"):
        solver.step(state, 0.002)


def test_default_tolerance_tightens_to_the_accuracy_target(fig3):
    """As-woven yarn at 5 mN, default tolerance: the load-scaled residual (5e-9 N) leaves an
    error bound (residual x ||H^-1||) above an accuracy target of 1e-5 of the displacement,
    so the relaxation continues to the residual the target needs, and the step's bound then
    meets it (docs/model.md, stability and accuracy). A given tolerance is not tightened:
    the same target then stops the step with exit status 3."""
    scene = with_key(replace(fig3, sweep=()), "geometry.reference", "as_woven")
    model = build_model(with_key(with_key(scene, "load.control", "force"), "load.values", [0.005]))
    loose = DynamicSolver(model, Dynamic(accuracy=0.1)).step(initial_state(model), 0.005)[1]
    _, record = DynamicSolver(model, Dynamic(accuracy=1e-5)).step(initial_state(model), 0.005)
    scale = np.abs(record["positions"] - model.stacked("rest_position")).max()
    assert record["tolerance"][0] < loose["tolerance"][0]
    assert loose["error_estimate"][0] > 1e-5 * scale >= record["error_estimate"][0]
    with pytest.raises(SolverError, match="above dynamic.accuracy = 1e-05"):
        DynamicSolver(model, Dynamic(accuracy=1e-5, tolerance=5e-9)).step(initial_state(model),
                                                                            0.005)
