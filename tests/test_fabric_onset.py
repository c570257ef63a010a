"""The fabric's static solver at the friction onset (docs/model.md sections 4 and 10).

Clamped 4 x 4 patches of the paper's yarns at small loads, where crossings open and close
and sit at the onset: each step solved through the solver's default path and, at the
hardest steps, through each of its fallbacks alone (`force_fallback`: the under-relaxed
fixed point on F_T, the open/closed active set with its continuation in R_0), every state
checked against Gralen's law and the contact law evaluated here independently and the
fallbacks' states against the default path's; a 5 x 5 patch whose plain fixed point on
F_T cycles; the literal jump law (R_0 = 0) stopping with exit status 3 naming a crossing;
and R_0 -> 0 converging at first order (docs/model.md section 4).
"""

import re
import subprocess
import sys

import h5py
import numpy as np

from dynfab.model.fabric.model import FabricModel
from dynfab.scene import parse_scene_text
from dynfab.solvers.static import StaticSolver
from independent import contact_force, gralen, record_inverse_norm, scene_toml

ALPHA, BETA, ELL, R_F = 0.2, 1e3, 2e-3, 1e-3
"""The paper's Gralen constants (docs/model.md section 7): beta ell r_f = 2 mN."""
EPS = np.finfo(float).eps


def patch(n: int, onset: float, control: str, values, weft_values) -> str:
    """A clamped n x n patch of the paper's yarns (segment length of section 7, 14 per
    half-wave), friction on with R_0 = `onset`, as scene text."""
    yarn = {"EA": 13.72, "EI": 1.47e-7, "kawabata_C": 0.2e-3, "kawabata_K": 0.2}
    return scene_toml({
        "geometry": {"model": "fabric", "boundary": "clamped", "length": 0.00625 * n,
                     "segments": 14 * n, "crossings": n, "amplitude": 0.5e-3},
        "warp": yarn,
        "weft": {**yarn, "count": n, "segments": 14 * n, "amplitude": 0.5e-3},
        "friction": {"alpha": ALPHA, "beta": BETA, "contact_length": ELL,
                     "fiber_radius": R_F, "onset_force": onset},
        "load": {"control": control, "values": [float(v) for v in values],
                 "weft_values": [float(v) for v in weft_values]}})


def patch_solver(text: str) -> StaticSolver:
    """The static solver of a scene's text (`patch`)."""
    return StaticSolver(FabricModel.from_scene(parse_scene_text(text)))


def check_consistent(solver: StaticSolver, before, after, record, load) -> None:
    """The state `after` of a step from `before` obeys the laws (docs/model.md section 4):
    every crossing's F_T equals Gralen's law at its contact force to 1e-12 N, and the force
    residual with those F_T is within the tolerance (or the step's rounding floor)."""
    f, backend = solver.model.structure, solver.backend
    pos = after.positions
    g = f.tie_gap_offset - f.tie_side * (pos[f.tie_a, 1] - pos[f.tie_b, 1])
    R = np.array([contact_force(value, row) for value, row in zip(g, f.tie_contact_law)])
    law = gralen(R, solver.model.scene.friction.onset_force)
    # R agrees with the solver's to the bracketing's rounding (4 eps relative)
    np.testing.assert_allclose(np.ravel(record["contact_force"]), R, rtol=1e-12, atol=0)
    assert np.abs(np.ravel(record["friction_limit"]) - law).max() <= 1e-12
    begun = solver.model.start_of_step(before, load)
    anchors, P = begun.anchors, begun.chain_loads
    residual = backend.residual(backend.gradient(pos, P, anchors, law))
    H = backend.hessian(pos, anchors, law)
    floor = 4 * EPS * np.abs(H.diagonal()).max() * np.abs(pos).max()  # docs/model.md section 6
    assert residual <= max(solver.tolerance, floor if record["rounding_floor"] else 0.0)


FALLBACKS = {"relaxed": ("relaxed",), "active set": ("sets", "continuation")}
"""The sparse backend's fallbacks in the friction chain (`dynfab.solvers.friction_chain`), after its
frozen-F_T and coupled Newton ("unilateral") from the step's start: the under-relaxed fixed
point on F_T, and the open/closed active set with its continuation in R_0."""


def force_fallback(monkeypatch, solver: StaticSolver, fallback: str) -> None:
    """Make `solver`'s steps solve by `fallback` (a key of FALLBACKS) alone: the friction chain
    is offered its strategies only, so it runs them from the step's start, and a step they
    do not solve raises."""
    monkeypatch.setattr(solver.backend, "strategies", lambda problem: FALLBACKS[fallback])


def assert_same_state(solver, before, states) -> None:
    """States of one step from `before`, each (state, record), are the same equilibrium: with
    R_0 > 0 a step's solution is unique (docs/model.md section 4), and a state whose residual
    is r lies within r ||H^-1||_inf of it (docs/model.md (5.7)), so two differ by at most
    ||H^-1||_inf (r_1 + r_2), each r at least the tolerance (||H^-1||_inf the first state's
    record's, `record_inverse_norm`: the Hessian at its solution with the step's anchors); the
    step moves the patch far beyond that."""
    (first, first_record), *others = states
    inverse = record_inverse_norm(first_record)
    residual = max(float(first_record["residual"]), solver.tolerance)
    for state, record in others:
        bound = inverse * (residual + max(float(record["residual"]), solver.tolerance))
        assert np.abs(state.positions - first.positions).max() <= bound
        assert np.abs(first.positions - before.positions).max() > 1e3 * bound


def solve_path(text: str, fallback_steps: set[int], monkeypatch):
    """Every step of the scene's path solved by the default path and checked
    (`check_consistent`); at the steps in `fallback_steps` (1-based) also by each fallback
    alone from the step's start (`force_fallback`), each state checked and the same as the
    default path's (`assert_same_state`)."""
    solver = patch_solver(text)
    state = solver.initial_state()
    for index, load in enumerate(solver.model.load_values, start=1):
        new, record = solver.step(state, load)
        check_consistent(solver, state, new, record, load)
        if index in fallback_steps:
            solved = [(new, record)]
            for fallback in FALLBACKS:
                with monkeypatch.context() as patched:
                    force_fallback(patched, solver, fallback)
                    solved.append(solver.step(state, load))
                check_consistent(solver, state, *solved[-1], load)
            assert_same_state(solver, state, solved)
        state = new
    return solver, state


def test_displacement_control_through_closing_crossings_at_a_small_onset_force(monkeypatch):
    """A 4 x 4 patch stretched by small end displacements (R_0 = 1e-7 N): at step 3
    crossings close and slide at the onset; the default path, the relaxed fixed point and the
    active set each reach a consistent state, the same one. (At the default R_0 = 1e-5 N
    the frozen and coupled Newton, its factorisation in the nested-dissection order, passes
    this whole path.)"""
    values = np.linspace(1e-6, 2e-5, 8)[:3]
    weft = np.linspace(0.0, 1e-5, 8)[:3]
    solve_path(patch(4, 1e-7, "displacement", values, weft), {3}, monkeypatch)


def test_force_control_at_a_small_onset_force(monkeypatch):
    """A 4 x 4 patch under 0.1 mN per warp and 0.05 mN per weft with R_0 = 1e-7 N: the
    default path, the relaxed fixed point and the active set with its continuation in R_0
    from 1e-3 N each reach a consistent state, the same one."""
    solve_path(patch(4, 1e-7, "force", [0.0, 1e-4], [0.0, 5e-5]), {2}, monkeypatch)


def test_the_literal_jump_law_stops_naming_a_crossing(tmp_path):
    """R_0 = 0 (docs/model.md section 4): where the set updates keep switching a crossing at
    g = 0 the run stops with exit status 3, one line naming the crossing as the scene counts
    it and the residual reached, the finished step kept on disk."""
    scene = tmp_path / "jump.toml"
    scene.write_text(patch(4, 0.0, "force", [0.0, 1e-4], [0.0, 5e-5]))
    out = tmp_path / "jump.h5"
    done = subprocess.run([sys.executable, "-m", "dynfab.cli", "run", str(scene), "--out",
                           str(out), "--quiet"], capture_output=True, text=True)
    assert done.returncode == 3, done.stderr
    lines = done.stderr.strip().splitlines()
    assert len(lines) == 1
    match = re.fullmatch(
        r"dynfab: error: load step 2/2 \(load 0\.0001 5e-05 N\): fabric: crossing \(warp (\d), "
        r"weft (\d)\) keeps opening and closing at g = 0, where Gralen's friction limit jumps "
        r"by beta\*ell\*r_f = 0\.002 N \(R_0 = 0 N\); no open/closed state consistent with the "
        r"contact and friction laws was found \(residual (\S+) N, tolerance 1e-11 N\); the 1 "
        r"finished steps are kept", lines[0])
    assert match, lines[0]
    assert 1 <= int(match[1]) <= 4 and 1 <= int(match[2]) <= 4
    assert float(match[3]) > 1e-11
    with h5py.File(out) as results:
        assert results["steps/residual"].shape == (1,)


def test_the_onset_converges_at_first_order_to_the_jump_law():
    """docs/model.md section 4: as R_0 -> 0 the solution converges at first order to the
    set-valued closure of the jump. A 2 x 2 patch stretched by displacement, where one
    crossing is held near g = 0 with R about R_0 / 4: the change of the positions from
    R_0 to R_0 / 2 halves with R_0 (ratio 2 + O(R_0): its error halves too), far above the
    solver's position error, the tolerance times ||H^-1||_inf (docs/model.md (5.7))."""
    onsets = 1.6e-5 / 2.0 ** np.arange(6)
    positions, smallest = [], []
    for onset in onsets:
        solver = patch_solver(patch(2, onset, "displacement", np.linspace(1e-6, 2e-5, 8)[:2],
                                    np.linspace(0.0, 1e-5, 8)[:2]))
        state, records = solver.run()
        bound = solver.tolerance * record_inverse_norm(records[-1])
        positions.append(state.positions)
        smallest.append(np.min(records[-1]["contact_force"]))
    # the crossing held at the onset: R proportional to R_0
    assert np.all(np.array(smallest) < 0.5 * onsets) and np.all(np.array(smallest) > 0)
    change = np.array([np.abs(a - b).max() for a, b in zip(positions, positions[1:])])
    assert change[-1] > 100 * 2 * bound  # each difference of two solutions resolved
    ratio = change[:-1] / change[1:]
    error = np.abs(ratio - 2.0)
    assert error[-1] < 0.1
    assert np.all(error[1:] < 0.75 * error[:-1])  # the O(R_0) term halving with R_0


def test_a_step_the_fallback_cannot_solve_names_its_crossing(monkeypatch):
    """With the active set's budget cut to one max_iterations (200 Newton iterations; the
    step needs about 1,600), the step of `test_force_control_at_a_small_onset_force` stops
    with a SolverError naming a crossing as the scene counts it, the onset and the laws'
    residual reached (above the tolerance), not a silent state."""
    from dynfab.solvers import friction_chain
    from dynfab.errors import SolverError

    monkeypatch.setattr(friction_chain, "FALLBACK_BUDGET", 1)
    solver = patch_solver(patch(4, 1e-7, "force", [0.0, 1e-4], [0.0, 5e-5]))
    state, _ = solver.step(solver.initial_state(), (0.0, 0.0))
    try:
        solver.step(state, (1e-4, 5e-5))
    except SolverError as error:
        message = str(error)
    else:
        raise AssertionError("the step was solved within 200 iterations")
    match = re.fullmatch(r"fabric: crossing \(warp ([1-4]), weft ([1-4])\) at the friction onset "
                         r"\(R_0 = 1e-07 N\): no open/closed state consistent with the contact "
                         r"and friction laws was found, also by continuation in R_0 from 0\.001 N "
                         r"\((\d+) Newton iterations, at most 1 x static\.max_iterations; "
                         r"residual (\S+) N, tolerance 1e-11 N\)", message)
    assert match, message
    assert float(match[4]) > 1e-11


def test_a_fixed_point_on_friction_that_cycles_is_relaxed(monkeypatch):
    """A 5 x 5 patch under 0.1 mN per warp and 0.05 mN per weft (R_0 = 1e-5 N), its first
    step: crossings sit at g ~ 1e-9 m with R ~ R_0 / 100, where dF_T/dR = beta ell r_f / R_0
    = 200, and the plain fixed point on F_T falls into a 2-cycle (a crossing closed in
    one solve is open in the next and closed again in the one after). The step reaches a
    state consistent with the laws through the default path, and through the under-relaxed
    fixed point (`SparseNewton.solve_relaxed`) alone (`force_fallback`: without the active set,
    which, before the relaxed fixed point existed, found no consistent state here in
    31,770 Newton iterations, about 90 s: too long to show here): the same state."""
    text = patch(5, 1e-5, "force", [1e-4], [5e-5])
    solver = patch_solver(text)
    state = solver.initial_state()
    begun = solver.model.start_of_step(state, (1e-4, 5e-5))
    pos, anchors, P = begun.positions, begun.anchors, begun.chain_loads
    backend = solver.backend
    limit = backend.friction_limits(pos)
    closed = []
    for _ in range(30):  # the plain update, F_T = the law at the last solution
        assert backend.newton(pos, P, anchors, limit).converged
        limit = backend.friction_limits(pos)
        closed.append(backend.closures(pos) > 0)
    assert np.array_equal(closed[-1], closed[-3]) and np.array_equal(closed[-2], closed[-4])
    assert not np.array_equal(closed[-1], closed[-2])
    assert backend.law_residual(pos, P, anchors) > 1e3 * solver.tolerance

    load = (1e-4, 5e-5)
    new, record = solver.step(state, load)  # the default path
    check_consistent(solver, state, new, record, load)

    with monkeypatch.context() as patched:
        force_fallback(patched, solver, "relaxed")
        relaxed = solver.step(state, load)
    check_consistent(solver, state, *relaxed, load)
    assert_same_state(solver, state, [(new, record), relaxed])


def test_the_relaxed_fixed_point_and_the_active_set_reach_the_same_state(monkeypatch):
    """With R_0 > 0 a step's solution is unique (docs/model.md section 4), so the two
    fallbacks, each from the step's start, must agree: on the step of
    `test_force_control_at_a_small_onset_force` (which the relaxed fixed point now solves
    first) the active set with its continuation in R_0 is run too, and the positions differ
    by at most twice the position error of a residual within the tolerance,
    tolerance ||H^-1||_inf (docs/model.md (5.7))."""
    solver = patch_solver(patch(4, 1e-7, "force", [0.0, 1e-4], [0.0, 5e-5]))
    backend = solver.backend
    state, _ = solver.step(solver.initial_state(), (0.0, 0.0))
    solved = []
    for fallback in FALLBACKS:
        begun = solver.model.start_of_step(state, (1e-4, 5e-5))
        pos, anchors, P = begun.positions, begun.anchors, begun.chain_loads
        with monkeypatch.context() as patched:
            force_fallback(patched, solver, fallback)
            assert backend.equilibrium(pos, P, anchors)[0].converged
        assert backend.law_residual(pos, P, anchors) <= solver.tolerance
        solved.append(pos)
    H = backend.hessian(solved[0], anchors, backend.friction_limits(solved[0])).toarray()
    bound = solver.tolerance * np.abs(np.linalg.inv(H)).sum(axis=1).max()
    assert np.abs(solved[0] - solved[1]).max() <= 2 * bound
    assert np.abs(solved[0] - state.positions).max() > 1e3 * bound  # the step moved the patch


def test_the_periodic_cell_at_a_small_onset_force(monkeypatch):
    """The periodic 2 x 2 cell (tied cell lengths, wrap springs, moving planes) under 0.1 mN
    per warp and 0.05 mN per weft from its as-woven state, where every crossing starts at
    g = 0 (R = 0, F_T = 0: the onset itself), with R_0 = 1e-5 N (the default): the contact
    forces reached, about 2.5e-5 N, lie on the onset's curved part (exp(-R / R_0) ~ 0.1, checked
    here), each step consistent with Gralen's law through R_0 and the contact law, and at the
    second step the default path, the relaxed fixed point and the active set with its
    continuation in R_0 reach the same state."""
    text = patch(2, 1e-5, "force", [0.0, 1e-4], [0.0, 5e-5])
    assert text.count('boundary = "clamped"') == 1
    solver, state = solve_path(text.replace('boundary = "clamped"', 'boundary = "periodic"'),
                               {2}, monkeypatch)
    assert solver.model.scene.geometry.boundary == "periodic"
    R = contact_force_of(solver, state)
    assert (0.5 < R / 1e-5).all() and (R / 1e-5 < 5).all()  # within the onset's scale


def contact_force_of(solver: StaticSolver, state) -> np.ndarray:
    """Each crossing's contact force R [N] at `state`, from the contact law evaluated here."""
    f = solver.model.structure
    pos = state.positions
    g = f.tie_gap_offset - f.tie_side * (pos[f.tie_a, 1] - pos[f.tie_b, 1])
    return np.array([contact_force(value, row) for value, row in zip(g, f.tie_contact_law)])
