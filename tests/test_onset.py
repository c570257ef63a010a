"""The regularised friction onset and the contact core stiffness (docs/model.md sections 3 and 4).

- F_T(R) = alpha R + beta ell r_f (1 - exp(-R / R_0)) and dF_T/dR against an
  independent formula and central differences (numba; the Warp twin is checked in
  tests/test_dynamic_kernels.py with the kernel variant that file already builds);
- the coupled Jacobian entry d(dH/ds)/dz = sign(s) dF_T/dR dR/dg dg/dz at a crossing
  whose R is of order R_0, against central differences of the gradient with F_T
  recomputed;
- the core stiffness k_c: the series law R/k_we + R/k_c + deltas = g, solved here with
  scipy, and dE/dg = R by central differences;
- the static solver on the as-woven onset path: the state converges at first order as
  R_0 -> 0, to a limit where crossings sit at g = 0 with a friction force below
  beta ell r_f; the literal law (R_0 = 0) still stops at step 1 with the exit-3 message;
- the semismooth fallback (contact forces as unknowns; a scalar root on one crossing)
  against the active-set state, and the path through the step (19, at 512 segments)
  where the active set with the R_0 continuation stopped;
- runs/onset_path.toml itself, cut to every 10th load value: the laws hold at every step,
  the traction curve rises, friction stiffens it against the frictionless yarn and
  dissipates ever more, and the pull presses every crossing shut.
"""

from __future__ import annotations

import math
import subprocess
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from dynfab.model import assembly

from dynfab.solvers import newton_banded
from dynfab.solvers.friction_chain import friction_chain
from dynfab.linalg.banded import zeros_band
from dynfab.model.yarn import initial_state
from dynfab.model.builders import build_model
from dynfab.run import run as run_scene
from dynfab.scene import load_scene, with_key
from dynfab.solvers.static import StaticSolver
from dynfab.model.terms import contact, friction
from independent import (EPS, PAPER_FRICTION, PAPER_WARP, PAPER_WEFT, contact_force, dense,
                         contact_forces, gralen, make_scene, scene_gralen)

RUNS = Path(__file__).resolve().parents[1] / "runs"
ALPHA, CONSTANT = 0.2, 1e3 * 2e-3 * 1e-3
"""The paper's Gralen alpha and beta ell r_f [N] (docs/model.md section 7)."""
ONSET = 1e-5
"""R_0 [N], the default onset force (docs/model.md section 4)."""


def onset_scene(segments=32, onset=ONSET, values=(0.005,), core_stiffness=None):
    """The paper's yarn and friction, as woven, force control: the onset path's first step."""
    tables = dict(geometry={"length": 0.1, "segments": segments, "crossings": 16,
                            "amplitude": 0.5e-3},
                  warp=PAPER_WARP, weft=PAPER_WEFT,
                  friction=dict(PAPER_FRICTION, onset_force=onset),
                  load={"control": "force", "values": list(values)})
    if core_stiffness is not None:
        tables["contact"] = {"core_stiffness": core_stiffness}
    return make_scene(**tables)


# --------------------------------------------------------------------------
# 1. The law and its slope.


@pytest.mark.parametrize("R", [1e-9, 1e-7, 3e-6, 1e-5, 4e-5, 3e-4, 2e-2])
def test_onset_law_and_its_slope(R):
    # F_T = alpha R + c (1 - exp(-R/R_0)), the tests' reference (numpy's expm1, not numba's).
    expected = float(gralen(R, ONSET, ALPHA, CONSTANT))
    assert friction.limit(R, ALPHA, CONSTANT, ONSET) == pytest.approx(expected, rel=4 * EPS)
    # dF_T/dR by central differences, h = 1e-3 min(R, R_0): truncation h^2 |F'''| / 6 with
    # |F'''| <= c / R_0^3, rounding 2 eps F / h (two evaluations of F, each to eps F).
    h = 1e-3 * min(R, ONSET)
    fd = (friction.limit(R + h, ALPHA, CONSTANT, ONSET)
          - friction.limit(R - h, ALPHA, CONSTANT, ONSET)) / (2 * h)
    bound = h * h * CONSTANT / (6 * ONSET ** 3) + 2 * EPS * (expected + ALPHA * h) / h
    assert abs(friction.limit_slope(R, ALPHA, CONSTANT, ONSET) - fd) <= bound


def test_onset_law_is_continuous_at_zero_and_the_literal_law_jumps():
    # R_0 > 0: F_T(0+) = 0 = F_T(0); slope alpha + c / R_0 there. R_0 = 0: the jump c.
    assert friction.limit(0.0, ALPHA, CONSTANT, ONSET) == 0.0
    assert friction.limit(1e-300, ALPHA, CONSTANT, ONSET) < 1e-290
    assert friction.limit_slope(1e-300, ALPHA, CONSTANT, ONSET) == ALPHA + CONSTANT / ONSET
    assert friction.limit(1e-300, ALPHA, CONSTANT, 0.0) == CONSTANT
    assert friction.limit(-1e-9, ALPHA, CONSTANT, ONSET) == 0.0
    # far above R_0 the onset factor is 1 to rounding: the paper's contact forces (>= 1e-3 N)
    R = 1e-3
    assert friction.limit(R, ALPHA, CONSTANT, ONSET) == ALPHA * R + CONSTANT


# --------------------------------------------------------------------------
# 2. The coupled Jacobian at the onset.


def test_coupled_jacobian_entry_at_the_onset_is_the_derivative_through_R():
    # One sliding crossing closed by g with R = 0.5 R_0, where dF_T/dR = alpha + (c/R_0) e^-0.5
    # = 121 and dF_T/dz = dF_T/dR dR/dg (-s_j) about 2.4e3 N/m. The entry
    # d(grad_x)/dz of its node against central differences of the gradient with F_T
    # recomputed from R(g(z)): h = 1e-11 m (g ~ 2.5e-7 m, so the regimes hold within h);
    # truncation h^2 |d3 grad_x/dz3| / 6 <= h^2 (c / R_0^3) k_we^3 / 6, rounding
    # 2 eps |grad_x| / (2 h), |grad_x| bounded by EA (the stretch force's operands).
    scene = onset_scene()
    model = build_model(scene)
    yarn = model.yarns[0]
    c = yarn.crossing_node.size
    pos = model.per_yarn(initial_state(model).positions)[0].copy()
    j = 3
    node, side = yarn.crossing_node[j], yarn.crossing_side[j]
    g_target = contact.closure_from_force(0.5 * ONSET, yarn.contact_law)
    pos[node, 1] = (yarn.gap_offset[j] - g_target) * side  # g_j = c_j - s_j z
    anchors = pos[yarn.crossing_node, 0] - 1e-3  # every crossing slides (k_t |s| = 30 N > F_T)

    def coupled_gradient(p):
        R, limit, tangent = np.zeros(c), np.zeros(c), np.zeros(c)
        assembly.contact_state(p, yarn, R, limit, tangent)
        out = np.zeros_like(p)
        assembly.gradient(p, yarn, 0.005, anchors, limit, out)
        return out

    R, limit, tangent = np.zeros(c), np.zeros(c), np.zeros(c)
    assembly.contact_state(pos, yarn, R, limit, tangent)
    assert R[j] == pytest.approx(0.5 * ONSET, rel=1e-12)
    band = zeros_band(pos.size)
    assembly.hessian(pos, yarn, anchors, limit, tangent, True, band)
    entry = dense(band)[2 * node, 2 * node + 1]
    h = 1e-11
    plus, minus = pos.copy(), pos.copy()
    plus[node, 1] += h
    minus[node, 1] -= h
    fd = (coupled_gradient(plus)[node, 0] - coupled_gradient(minus)[node, 0]) / (
        plus[node, 1] - minus[node, 1])
    k_we = yarn.contact_law[0]
    bound = h * h * (CONSTANT / ONSET ** 3) * k_we ** 3 / 6 + 2 * EPS * PAPER_WARP["EA"] / (2 * h)
    slope = friction.limit_slope(R[j], ALPHA, CONSTANT, ONSET)
    expected = -side * slope * tangent[j]  # sign(s) = +1: x - xi = 1e-3 m
    assert abs(expected) > 1e3  # the onset's coupling, not alpha's (alpha dR/dg ~ 4 N/m)
    assert abs(entry - expected) <= 1e-12 * abs(expected)  # the band holds exactly that entry
    assert abs(entry - fd) <= bound


# --------------------------------------------------------------------------
# 3. The core stiffness in series.


@pytest.mark.parametrize("g", [1e-7, 3e-5, 2e-4, 5e-4])
def test_core_stiffness_is_a_spring_in_series(g):
    # docs/model.md section 3: R / k_we + R / k_c + delta_wa(R) + delta_we(R) = g, solved by
    # the tests' reference (brentq, tests/independent.py) with the two springs in series; the
    # model's R to 1e-12 relative (the left side is monotone, its root found to rounding). dE/dg = R by central differences,
    # h = 1e-4 g: truncation h^2 |dR/dg''|/6 ~ h^2 k^3 sum C a^2 / 6, rounding 2 eps E / h.
    k_core = 50.0  # N/m, comparable to k_we so that it matters
    scene = onset_scene(core_stiffness=k_core)
    law = build_model(scene).yarns[0].contact_law
    plain = build_model(onset_scene()).yarns[0].contact_law
    k_we, C_wa, a_wa, C_we, a_we = plain

    in_series = 1 / (1 / k_we + 1 / k_core)  # R / k_we + R / k_c = R / in_series
    R_expected = contact_force(g, (in_series, C_wa, a_wa, C_we, a_we))
    R = contact.force_from_closure(g, law)
    assert R == pytest.approx(R_expected, rel=1e-12)
    h = 1e-4 * g
    E = contact.energy_of_force(R, law)
    fd = (contact.energy_of_force(contact.force_from_closure(g + h, law), law)
          - contact.energy_of_force(contact.force_from_closure(g - h, law), law)) / (2 * h)
    k = law[0]
    bound = h * h * k ** 3 * (C_wa * a_wa ** 2 + C_we * a_we ** 2) / 6 + 4 * EPS * max(E, R * g) / h
    assert abs(fd - R) <= bound + 1e-12 * R
    # the tangent of the series: 1 / (1/k_we + 1/k_c + sum C a e^-aR)
    expected_tangent = 1 / (1 / k_we + 1 / k_core + C_wa * a_wa * math.exp(-a_wa * R)
                            + C_we * a_we * math.exp(-a_we * R))
    assert contact.tangent(R, law) == pytest.approx(expected_tangent, rel=8 * EPS)


def test_without_core_stiffness_the_law_is_the_weft_spring_alone():
    # default none (docs/model.md section 3): the series spring is k_we itself, bit for bit
    law = build_model(onset_scene()).yarns[0].contact_law
    scene = onset_scene(core_stiffness=1e300)
    assert build_model(scene).yarns[0].contact_law[0] == law[0]


# --------------------------------------------------------------------------
# 4. The static solver on the onset path, and the limit R_0 -> 0.


TOLERANCE = 1e-12
"""Newton tolerance [N] for the R_0 sequence: above the 32-segment yarn's rounding floor
(4 eps max K_ii max|r| ~ 1e-12 N, docs/model.md section 6), and small enough that the solver's
position error, tolerance / 20 N/m (the softest crossing's contact tangent) ~ 5e-14 m,
stays below 1 % of the smallest difference measured (2e-11 m)."""


def solve_first_step(onset):
    """Positions and closures of the onset path's first step (P = 5 mN) at R_0 = onset."""
    model = build_model(with_key(onset_scene(), "friction.onset_force", onset))
    backend = StaticSolver(model, tolerance=TOLERANCE, max_iterations=200).backend
    problem = backend.problems(model.start_of_step(initial_state(model), 0.005))[0]
    assert friction_chain(backend, problem).converged  # the chain alone, no certificate
    return model, problem.positions


def test_state_converges_at_first_order_as_the_onset_force_vanishes():
    # docs/model.md section 4: as R_0 -> 0 the solution converges at first order to the set-valued
    # limit. Measured (this test's sequence, 32 segments): max |r(R_0) - r(R_0/2)| =
    # 1.69e-10, 8.9e-11, 4.59e-11, 2.33e-11 m for R_0 = 1e-5 .. 6.25e-7 N, ratios 1.89,
    # 1.94, 1.97: the ratio approaches 2 with a deviation that halves with R_0 (the
    # next-order term, ratio = 2 - C R_0). The last order, log2(ratio), is then
    # 1 - 0.022; the tolerance 0.05 allows the deviation of the pair before (0.045) and
    # the solver's position error (< 1 % of each difference, TOLERANCE).
    onsets = [1e-5, 5e-6, 2.5e-6, 1.25e-6, 6.25e-7]
    states = [solve_first_step(r) for r in onsets]
    differences = [np.abs(a[1] - b[1]).max() for a, b in zip(states, states[1:])]
    orders = [math.log2(a / b) for a, b in zip(differences, differences[1:])]
    assert abs(orders[-1] - 1.0) <= 0.05, (differences, orders)
    assert abs(orders[-1] - 1.0) <= abs(orders[0] - 1.0)  # in the asymptotic range
    # The limit: some crossings sit at g = 0 (within the first-order distance of the
    # finest R_0, R_0 / k_we) carrying a friction force strictly between 0 and beta ell r_f.
    model, pos = states[-1]
    yarn = model.yarns[0]
    c = yarn.crossing_node.size
    R, limit, tangent = np.zeros(c), np.zeros(c), np.zeros(c)
    assembly.contact_state(pos, yarn, R, limit, tangent)
    g = newton_banded._closures(pos, yarn)
    at_onset = (np.abs(g) <= onsets[-1] / yarn.contact_law[0]) & (limit > 0)
    assert at_onset.any()
    assert np.all(limit[at_onset] < CONSTANT)


def test_literal_law_still_stops_at_the_first_step_naming_the_crossing(tmp_path):
    # onset_force = 0 keeps the jump law: the as-woven path cycles at step 1 and the run
    # stops with exit status 3 and one line naming the crossing (docs/model.md section 4).
    scene = onset_scene(onset=0.0, values=(0.005, 0.006))
    path = tmp_path / "literal.toml"
    path.write_text(scene.text)
    done = subprocess.run([sys.executable, "-m", "dynfab.cli", "run", str(path), "--out",
                           str(tmp_path / "literal.h5"), "--quiet"], capture_output=True, text=True)
    assert done.returncode == 3, done.stderr
    lines = done.stderr.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in done.stderr
    assert "load step 1/2" in lines[0] and "keeps opening and closing at g = 0" in lines[0]
    assert "crossing" in lines[0] and "node" in lines[0]


def assert_steps_obey_the_law(scene, records):
    """Every step converged to the static tolerance, and every F_T equals the regularised
    law (docs/model.md section 4) at the step's R to 1e-12 N, the law evaluated by the tests'
    reference (tests/independent.py, numpy's expm1)."""
    for record in records:
        assert record["residual"].max() <= scene.static.tolerance
        R = record["contact_force"][0]
        law = scene_gralen(scene, R)
        assert np.abs(record["friction_limit"][0] - law).max() <= 1e-12


def test_regularised_path_runs_and_satisfies_the_law():
    # The first 12 steps of the onset path at 32 segments (the literal law stops at step 1):
    # every step to tolerance, every F_T equal to the law at the solution's R to 1e-12 N.
    from independent import run
    values = list(np.linspace(0.005, 0.6, 400)[:12])
    scene = onset_scene(values=values)
    model, records = run(scene)
    assert_steps_obey_the_law(scene, records)



@pytest.mark.parametrize("hold_crossing", [False, True])
def test_semismooth_newton_reaches_the_active_set_state(hold_crossing):
    # The onset fallback's two parts (docs/model.md section 4): `newton_banded._semismooth` (contact forces
    # as unknowns, the complementarity in min-form) and `newton_banded._onset_root` (one crossing's
    # contact force as a scalar root, the rest relaxed, then the free solve). On the onset
    # path's first step at R_0 = 1e-3 N (where the continuation starts: F_T is smooth on
    # the scale of the steps) both must land on the state the active-set path
    # (`StaticSolver`'s friction chain) finds: docs/model.md section 4 claims one solution per step. Both stop at
    # TOLERANCE; the position error that leaves is TOLERANCE x |K^-1| with K's smallest
    # eigenvalue about 0.25 N/m on this yarn (docs/model.md section 5): 4e-12 m each, so 1e-10 m has
    # margin, and is 1e-5 of the first step's displacement (2e-5 m).
    model, reference = solve_first_step(1e-3)
    yarn, state = model.yarns[0], initial_state(model)
    fixed, anchors = model.fixed_dofs(), model.per_crossing(state.anchors)[0]
    pos = model.per_yarn(state.positions)[0].copy()
    R = newton_banded._contact_forces(pos, yarn)
    if hold_crossing:
        g_reference = newton_banded._closures(reference, yarn)
        closed = np.flatnonzero(g_reference > 0)
        j = int(closed[np.argmin(g_reference[closed])])  # the closed crossing nearest g = 0
        found, _ = newton_banded._onset_root(pos, yarn, 0.005, fixed, anchors, R, TOLERANCE, j)
        assert found
    _, converged = newton_banded._semismooth(pos, yarn, 0.005, fixed, anchors, R, TOLERANCE, 200)
    assert converged
    # consistent with the unilateral contact law and Gralen's law: R from g, F_T from R
    assert newton_banded._natural_residual(pos, yarn, 0.005, anchors, fixed) <= TOLERANCE
    assert np.abs(pos - reference).max() <= 1e-10
    # the unknowns R agree with the law at the solution's closures
    law = yarn.contact_law
    assert np.abs(R - [contact.force_from_closure(g, law)
                       for g in newton_banded._closures(pos, yarn)]).max() <= TOLERANCE


def test_onset_path_passes_the_step_the_set_updates_could_not_solve():
    # The as-woven onset path at 512 segments, its first 19 load steps: at step 19 the
    # active set with the R_0 continuation stopped (exit status 3, naming crossing 2) at
    # 512, 672, 896 and 1792 segments (448 and 224 pass). The state it could not reach
    # has crossing 2 open and crossing 3 closed with a contact force below R_0 (at 1792
    # segments R = 7.06e-6 N at g = 3.3e-7 m); the semismooth fallback
    # (`newton_banded._solve_semismooth`) reaches it. Checked here: every step converges to the
    # tolerance, every F_T is the law at the step's R to 1e-12 N (docs/model.md section 4: the law
    # evaluated independently, with numpy's expm1), and step 19 has a closed crossing
    # inside the onset, 0 < R < R_0.
    from independent import run
    values = list(np.linspace(0.005, 0.6, 400)[:19])
    scene = onset_scene(segments=512, values=values)
    model, records = run(scene)
    assert_steps_obey_the_law(scene, records)
    R = records[-1]["contact_force"][0]
    assert np.any((R > 0) & (R < scene.friction.onset_force))


def test_the_onset_path_scene_file():
    # runs/onset_path.toml, static, cut to every 10th of its 400 load values and its last
    # (41 steps, 5 mN to 0.6 N; the whole path costs several times more, most of it in its first
    # 20 steps, which the cut crosses in two). Checked at every step: the residual within
    # the tolerance; R equal to the series law at the step's closures (tests/independent.py,
    # brentq) and F_T to Gralen's law at that R, to 1e-12 N (docs/model.md section 4). The
    # path starts at the onset: every crossing at g = 0 in the as-woven reference, and at
    # the first step crossings closed with 0 < R < R_0. Then the traction curve rises
    # (force control: the end moves on at every step), friction stiffens it against the same
    # yarn without friction (it resists the slip, so the end moves less at every load) and
    # only dissipates (steps/dissipated never falls), and at the last step the pull has
    # pressed every crossing shut, each sliding at its limit (to the rounding of the return
    # map's xi = fl(x - F_T / k_t): k_t eps |x| / 2, doubled, plus a few ulps of F_T).
    scene = load_scene(RUNS / "onset_path.toml")
    values = list(scene.load.values[::10]) + [scene.load.values[-1]]
    scene = with_key(scene, "load.values", values)
    steps = run_scene(scene, solver="static").steps
    assert len(steps["load"]) == len(values)
    assert scene.geometry.reference == "as_woven"
    yarn = build_model(scene).yarns[0]
    reference = yarn.rest_position
    assert not contact_forces(scene, reference).any()  # g = 0: no crossing pressed at rest
    for i in range(len(values)):
        assert steps["residual"][i, 0] <= scene.static.tolerance or steps["rounding_floor"][i, 0]
        R = contact_forces(scene, steps["positions"][i, 0])
        np.testing.assert_allclose(steps["contact_force"][i, 0], R, rtol=0, atol=1e-12)
        np.testing.assert_allclose(steps["friction_limit"][i, 0], scene_gralen(scene, R),
                                   rtol=0, atol=1e-12)
    first = steps["contact_force"][0, 0]
    assert np.any((first > 0) & (first < scene.friction.onset_force))
    end = steps["end_displacement"][:, 0]
    assert np.all(np.diff(end) > 0)
    frictionless = run_scene(replace(scene, friction=None), solver="static").steps
    assert np.all(end < frictionless["end_displacement"][:, 0])
    assert np.all(np.diff(steps["dissipated"][:, 0]) >= 0) and steps["dissipated"][-1, 0] > 0
    assert np.all(steps["contact_force"][-1, 0] > 0) and steps["sliding"][-1, 0].all()
    limit = steps["friction_limit"][-1, 0]
    x = steps["positions"][-1, 0][yarn.crossing_node, 0]
    rounding = yarn.stick_stiffness * EPS * np.abs(x) + 4 * EPS * limit
    assert np.all(np.abs(np.abs(steps["friction_force"][-1, 0]) - limit) <= rounding)
