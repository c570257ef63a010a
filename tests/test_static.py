"""The static Newton reference solver (docs/model.md sections 1-4, 6-8).

Verification tests: the Newton solution against scipy on the same energy,
symmetries (mirror yarns, sweep entries), displacement against force
control, the per-step record (residual, Gralen's law at the solution) and
the paper's trends on the paper's scenes. Each test states the equation it
checks and where its tolerance comes from (solver residual over the
smallest stiffness, float64 rounding, or the physics of the trend).

Contact forces used for Gralen's law are solved here from the positions
(scipy, docs/model.md section 3), independently of dynfab.model.terms.contact.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from scipy.optimize import minimize

from dynfab.model import assembly
from dynfab.model.yarn import initial_state
from dynfab.scene import expand_sweep, load_scene
from independent import (EPS, PAPER_FRICTION, PAPER_WARP, PAPER_WEFT, contact_forces, dense,
                         make_scene, pull, run, scene_gralen)

RUNS = Path(__file__).resolve().parent.parent / "runs"
GRALEN_TOLERANCE = 1e-12
"""docs/model.md section 4: at the solution every F_T equals Gralen's law at the solution's R to
1e-12 N."""


# --------------------------------------------------------------------------
# Scenes, runs and independent evaluations.


def paper_yarn(segments, crossings, load, friction=None, gravity=False, yarns=1, sweep=None):
    """The paper's yarn (docs/model.md section 7) at a reduced mesh, prestressed."""
    tables = {"geometry": {"length": 0.1, "segments": segments, "crossings": crossings,
                           "amplitude": 0.5e-3, "reference": "prestressed", "yarns": yarns},
              "warp": PAPER_WARP, "weft": PAPER_WEFT, "load": load}
    if sweep:
        del tables["geometry"]["yarns"]
    if friction:
        tables["friction"] = friction
    if gravity:
        tables["gravity"] = {"g": 9.81}
    return make_scene(sweep=sweep, **tables)


def jacobian(yarn, positions, anchors, coupled=True):
    """Dense d(grad V)/dr of the model at `positions` (Huber anchors `anchors`) [N/m]."""
    return dense(assembly.tangent(positions, yarn, anchors, coupled))


# --------------------------------------------------------------------------
# 4. Newton against scipy on the same energy.


def test_newton_agrees_with_scipy_trust_exact_within_the_residual_bound():
    # Frictionless paper yarn, N = 64, 4 crossings, prestressed, one force step
    # P = 0.3 N from the as-woven state. scipy's trust-exact minimises the same
    # V (dynfab.model.assembly energies / gradient / banded Hessian made dense) from
    # the same start. Both are stationary points with residuals r_N, r_S:
    #   g(x_S) - g(x_N) = Hbar (x_S - x_N),  Hbar = mean Hessian on the segment,
    #   ||x_S - x_N||_2 <= ||g(x_S) - g(x_N)||_2 / lambda_min(Hbar),
    # lambda_min computed with numpy (eigvalsh) on the dense free Hessian at both
    # ends; Hbar differs from them by |dx| x d3V ~ 1e-12 m x 6e6 N/m^2, 1e-5 of
    # lambda_min (~0.5 N/m), hence the bound's 1.01. The energies agree to rounding.
    P = 0.3
    scene = paper_yarn(64, 4, {"control": "force", "values": [P]})
    model, records = run(scene)
    yarn = model.yarns[0]
    free = ~model.fixed_dofs()
    start = model.per_yarn(initial_state(model).positions)[0]
    c = yarn.crossing_node.size
    none = np.zeros(c)

    def positions(q):
        full = start.ravel().copy()
        full[free] = q
        return full.reshape(start.shape)

    terms, grad = np.zeros(6), np.zeros_like(start)

    def energy(q):
        assembly.energies(positions(q), yarn, P, none, none, terms)
        return terms.sum()

    def gradient(q):
        assembly.gradient(positions(q), yarn, P, none, none, grad)
        return grad.ravel()[free].copy()

    def hessian(q):
        return jacobian(yarn, positions(q), none, coupled=False)[np.ix_(free, free)]

    result = minimize(energy, start.ravel()[free], jac=gradient, hess=hessian,
                      method="trust-exact", options={"gtol": 1e-13, "maxiter": 500})
    newton = records[0]["positions"][0].ravel()[free]
    r_newton, r_scipy = np.abs(gradient(newton)).max(), np.abs(gradient(result.x)).max()
    assert r_newton <= records[0]["residual"][0] <= 1e-11
    assert r_scipy < 1e-8  # trust-exact stops where energy differences reach rounding
    h_newton, h_scipy = hessian(newton), hessian(result.x)
    assert np.abs(h_newton - h_newton.T).max() <= 1e-12 * np.abs(h_newton).max()  # symmetric
    lam = min(np.linalg.eigvalsh(h_newton)[0], np.linalg.eigvalsh(h_scipy)[0])
    assert lam > 0  # a strict minimum
    bound = 1.01 * np.linalg.norm(gradient(result.x) - gradient(newton)) / lam
    assert np.linalg.norm(result.x - newton) <= bound, (np.linalg.norm(result.x - newton), bound)
    rounding = 64 * EPS * np.abs(terms).sum()
    assert energy(newton) <= energy(result.x) + rounding


# --------------------------------------------------------------------------
# 5. Adjacent yarns are mirror images without gravity.


def test_two_adjacent_yarns_are_mirror_images_without_gravity():
    # geometry.yarns = 2: yarn 2 has phase s_2 = -1, so its rest shape, crossing
    # sides and closures are yarn 1's with z -> -z, and V is invariant under
    # that reflection (docs/model.md section 1). Without gravity
    #   x_2 = x_1,  z_2 = -z_1.
    # The two Newton solves perform the same operations up to the sign of z
    # (IEEE negation is exact; atan2 is odd), so the agreement is to rounding:
    # 1e-14 m (~50 ulp of L) -- a rounding-level difference in one iterate is
    # not amplified, Newton's map having zero derivative at the solution.
    # (Observed: bitwise equal.) Friction on, prestressed, three force steps.
    scene = paper_yarn(64, 16, {"control": "force", "values": [0.05, 0.1, 0.3]},
                       friction=PAPER_FRICTION, yarns=2)
    _, records = run(scene)
    for record in records:
        p = record["positions"]
        np.testing.assert_allclose(p[1, :, 0], p[0, :, 0], rtol=0, atol=1e-14)
        np.testing.assert_allclose(p[1, :, 1], -p[0, :, 1], rtol=0, atol=1e-14)
        np.testing.assert_allclose(record["friction_force"][1], record["friction_force"][0],
                                   rtol=0, atol=1e-14 * record["friction_limit"].max() + 1e-18)


def test_gravity_breaks_the_mirror_by_its_linear_response():
    # With gravity both yarns sag along -z, which the reflection M (z -> -z)
    # does not map to itself. Expanding in g, with K the Hessian of yarn 1 at
    # the gravity-free solution, f_g = -m_i g e_z (m_i = rho_l lbar_i, docs/model.md section 5)
    # and Q the second-order response:
    #   r_1 = r_1(0) + K^-1 f_g + Q(f_g) + O(g^3),
    #   r_2 = M [r_1(0) + K^-1 (M f_g) + Q(M f_g)] + ...,   M f_g = -f_g, Q even,
    #   => z_1 + z_2 = 2 (K^-1 f_g)_z + O(g^3),   x_1 - x_2 = 2 (K^-1 f_g)_x + O(g^3):
    # the second-order terms cancel between the mirrored yarns. Tolerance: the
    # third-order remainder, relative (sag / A)^2 ~ (2e-7 / 5e-4)^2 < 1e-6 (A,
    # the crimp, the length over which the stiffness varies), plus each solve's
    # accuracy r sqrt(n) / lambda_min (numpy eigvalsh on K's free block).
    # Frictionless (path-independent), prestressed, one force step P = 0.3 N.
    load = {"control": "force", "values": [0.3]}
    _, free_fall = run(paper_yarn(64, 16, load, yarns=2))
    scene = paper_yarn(64, 16, load, gravity=True, yarns=2)
    model, records = run(scene)
    p, p0 = records[0]["positions"], free_fall[0]["positions"]
    yarn = model.yarns[0]
    rest = yarn.rest_position
    lengths = np.hypot(*np.diff(rest, axis=0).T)
    lbar = np.concatenate([[lengths[0] / 2], (lengths[:-1] + lengths[1:]) / 2, [lengths[-1] / 2]])
    weight = np.zeros_like(rest)
    weight[:, 1] = -scene.warp.linear_density * lbar * scene.gravity.g
    free = ~model.fixed_dofs()
    K = jacobian(yarn, p0[0], np.zeros(yarn.crossing_node.size), coupled=False)[np.ix_(free, free)]
    response = np.zeros(rest.size)
    response[free] = np.linalg.solve(K, weight.ravel()[free])
    response = response.reshape(rest.shape)
    scale = np.abs(2 * response).max()
    residuals = records[0]["residual"].sum() + free_fall[0]["residual"].sum()
    accuracy = residuals * np.sqrt(free.sum()) / np.linalg.eigvalsh(K)[0]
    tolerance = 1e-6 * scale + accuracy
    assert scale > 1e3 * tolerance  # gravity's effect stands far above both
    np.testing.assert_allclose(p[0, :, 1] + p[1, :, 1], 2 * response[:, 1], rtol=0, atol=tolerance)
    np.testing.assert_allclose(p[0, :, 0] - p[1, :, 0], 2 * response[:, 0], rtol=0, atol=tolerance)
    assert (p[0, :, 1] + p[1, :, 1]).mean() < 0  # both sag


# --------------------------------------------------------------------------
# 6. A sweep's yarns are independent one-yarn runs.


def test_sweep_entries_equal_one_yarn_runs():
    # A [sweep] of n entries simulates n copies of the representative yarn
    # (s_k = +1), each with its own parameters (docs/model.md section 1); the solver treats
    # the yarns one by one, so yarn k of the sweep and the one-yarn run of
    # expand_sweep(scene)[k] perform the same arithmetic:
    #   positions, anchors, dissipation, end force equal (bitwise).
    # K sweep (both yarns' Kawabata K) with friction, N = 64, 16 crossings,
    # displacement control to 4 mm in 8 steps.
    scene = paper_yarn(64, 16, {"control": "displacement", "max": 0.004, "steps": 8},
                       friction=PAPER_FRICTION,
                       sweep={"warp.kawabata_K": [0.02, 0.2, 1.0],
                              "weft.kawabata_K": [0.02, 0.2, 1.0]})
    _, swept = run(scene)
    entries = expand_sweep(scene)
    assert [e.warp.kawabata_K for e in entries] == [0.02, 0.2, 1.0]
    for k, entry in enumerate(entries):
        _, single = run(entry)
        for a, b in zip(swept, single):
            for key in ("positions", "anchors", "dissipated", "end_force", "contact_force"):
                np.testing.assert_array_equal(a[key][k], b[key][0], err_msg=f"{key}, entry {k}")
    # the entries differ: the sweep is not trivially equal
    last = swept[-1]["end_force"]
    assert len(set(last.tolist())) == 3


# --------------------------------------------------------------------------
# 7. The paper's trends on the paper's scenes (docs/model.md section 8).


@pytest.fixture(scope="module")
def fig3():
    scene = load_scene(RUNS / "paper_fig3.toml")
    model, records = run(scene)
    return scene, model, records


@pytest.fixture(scope="module")
def fig5():
    scene = load_scene(RUNS / "paper_fig5.toml")
    model, records = run(scene)
    return scene, model, records


def test_fig3a_smaller_kawabata_K_gives_a_stiffer_traction_curve(fig3):
    # Fig. 3a: K = 0.02 > 0.2 > 1.0 m/N in stiffness of the yarn compression;
    # the stiffer contact resists the straightening (decrimping) of the yarn,
    # so at equal end displacement the end force is larger:
    #   P(K=0.02) > P(K=0.2) > P(K=1.0)  at every step beyond the first three
    # (the first step relaxes the prestress together with the first load).
    # The differences (>= 2e-4 N) are 7 orders above the force accuracy
    # (residual 1e-11 N), so a strict inequality is meaningful.
    scene, _, records = fig3
    assert [e.warp.kawabata_K for e in expand_sweep(scene)] == [0.02, 0.2, 1.0]
    force = np.array([r["end_force"] for r in records])
    assert (force[3:, 0] > force[3:, 1]).all() and (force[3:, 1] > force[3:, 2]).all()


def test_fig3b_contact_force_grows_and_saturates(fig3):
    # Fig. 3b: the contact force grows with extension and saturates -- the
    # crimp is pulled out, so the closure approaches its limit while the yarn
    # straightens. With Rbar the mean over the 16 crossings at 40 steps of 0.25 mm:
    #   Rbar increases at every step (for every K, at every crossing);
    #   its rise over each quarter of the curve (2.5 mm) decreases, and the last
    #   quarter's rise is below a tenth of the first's (a concave curve
    #   flattening out: "saturates"; measured ratios 0.03-0.04).
    _, _, records = fig3
    R = np.array([r["contact_force"] for r in records])  # (steps, yarns, crossings)
    assert (np.diff(R, axis=0) > 0).all()
    mean = R.mean(axis=2)
    rises = np.array([mean[9] - mean[0], mean[19] - mean[9], mean[29] - mean[19], mean[39] - mean[29]])
    assert (np.diff(rises, axis=0) < 0).all(), rises
    assert (rises[3] < 0.1 * rises[0]).all(), rises[3] / rises[0]


def test_fig5_friction_stiffens_the_curve_by_a_gap_that_saturates(fig5):
    # Fig. 5: entry 0 friction on (alpha 0.2, beta 1e3), entry 1 off.
    # (a) P_on > P_off at every step.
    # (b) The gap grows while the crossings go from sticking to sliding and
    #     R grows (0 - 5 mm), then nearly constant: its change over 5 - 10 mm is
    #     below a tenth of its change over 0.25 - 5 mm. Expected ~0.05: once
    #     all crossings slide, the gap changes only through alpha dR
    #     (16 x 0.2 x ~7e-4 N x 1/2 ~ 1e-3 N) against ~2.5e-2 N of growth.
    # (c) Magnitude (a check of the "why"): at equal u a yarn carries the
    #     same mean tension with or without friction. With T(X) = P -
    #     sum_{X_j > X} |f_j| along the yarn (crossing j at X_j/L = (2j-1)/(2 N_we)):
    #       gap = P_on - P_off = sum_j |f_j| X_j / L.
    #     The argument neglects the crimp's nonlinear local response to each
    #     tension step |f_j|, relatively O(max_j |f_j| / P_off): that bound is
    #     the tolerance, for u >= 5 mm where every crossing slides.
    scene, model, records = fig5
    assert [(e.friction.alpha, e.friction.beta) for e in expand_sweep(scene)] == [(0.2, 1e3), (0, 0)]
    force = np.array([r["end_force"] for r in records])
    u = np.array([r["end_displacement"][0] for r in records])
    gap = force[:, 0] - force[:, 1]
    assert (gap > 0).all()
    at_5mm = int(np.argmin(np.abs(u - 0.005)))
    early, late = gap[at_5mm] - gap[0], gap[-1] - gap[at_5mm]
    assert early > 0 and abs(late) < 0.1 * early, (early, late)
    j = np.arange(1, model.crossings + 1)
    lever = (2 * j - 1) / (2 * model.crossings)
    friction = np.abs(np.array([r["friction_force"][0] for r in records]))
    estimate = friction @ lever
    sliding = np.array([r["sliding"][0].all() for r in records])
    late_steps = (u >= 0.005 - 1e-12) & sliding
    assert late_steps.sum() >= 20
    tolerance = friction.max(axis=1) / force[:, 1]
    error = np.abs(gap - estimate) / gap
    assert (error[late_steps] <= tolerance[late_steps]).all(), (error, tolerance)


# --------------------------------------------------------------------------
# 8. Displacement control reports the reaction.


@pytest.mark.parametrize("friction", [None, PAPER_FRICTION], ids=["frictionless", "friction"])
def test_displacement_control_reports_the_end_reaction(friction):
    # From the as-woven start (same anchors), a force step at P gives u; a
    # displacement step at u from the same start must solve the same equations
    # G_f(x) = 0, so its reported reaction dV/dx_N equals P. With residuals
    # r_F, r_D of the two solves, J the Jacobian (coupled with friction) and
    # v = J_ff^-T J_fN (the reaction's sensitivity to forces on free dofs):
    #   |P_D - P| <= r_F + ||v||_1 (r_F + r_D) + (|J_NN| + |J_Nf J_ff^-1 J_fN|) ulp(x_N)
    # (the last term: x0_N + u rounds x_N by up to an ulp).
    P = 0.3
    base = dict(segments=64, crossings=16, friction=friction)
    force_scene = paper_yarn(load={"control": "force", "values": [P]}, **base)
    model, (forced,) = run(force_scene)
    u = forced["end_displacement"][0]
    disp_model, (displaced,) = run(paper_yarn(load={"control": "displacement", "values": [u]},
                                              **base))
    yarn = model.yarns[0]
    J = jacobian(yarn, forced["positions"][0], model.per_crossing(initial_state(model).anchors)[0])
    free = ~disp_model.fixed_dofs()
    N = J.shape[0] - 2
    v = np.linalg.solve(J[np.ix_(free, free)].T, J[N, free])
    r_F, r_D = forced["residual"][0], displaced["residual"][0]
    ulp = np.spacing(forced["positions"][0, -1, 0])
    bound = r_F + np.abs(v).sum() * (r_F + r_D) + (abs(J[N, N]) + abs(v @ J[free, N])) * ulp
    assert abs(displaced["end_force"][0] - P) <= bound, (displaced["end_force"][0] - P, bound)
    # and the states agree within the same linear bound
    assert displaced["end_displacement"][0] == pytest.approx(u, abs=ulp)
    delta = np.abs(displaced["positions"][0] - forced["positions"][0]).max()
    assert delta <= np.abs(np.linalg.inv(J[np.ix_(free, free)])).sum(axis=1).max() * (r_F + r_D) + 4 * ulp


# --------------------------------------------------------------------------
# 9. Each step's record: residual and Gralen's law at the solution.


@pytest.mark.parametrize("figure", ["fig3", "fig5"])
def test_every_step_meets_the_tolerance_and_gralens_law(figure, request):
    # For every yarn and step of the paper's scenes (40 steps, N = 224):
    #   residual <= tolerance 1e-11 N (docs/model.md section 6; the rounding floor at N = 224
    #     is ~6e-13 N, below it, so no step may stop at the floor);
    #   R_j = the series law solved here from the step's positions, to 1e-12 N;
    #   F_T,j = alpha R_j + beta ell r_f (R_j > 0, else 0) to 1e-12 N (docs/model.md section 4);
    #   node equilibrium with that F_T: a sliding crossing's pull equals F_T,
    #     a sticking one's is below it, up to the step's residual.
    scene, model, records = request.getfixturevalue(figure)
    entries = expand_sweep(scene)
    tolerance = scene.static.tolerance
    assert tolerance == 1e-11
    for step, record in enumerate(records):
        assert (record["residual"] <= tolerance).all(), (step, record["residual"])
        for k, (entry, yarn) in enumerate(zip(entries, model.yarns)):
            positions = record["positions"][k]
            R = contact_forces(entry, positions)
            np.testing.assert_allclose(record["contact_force"][k], R, rtol=0, atol=GRALEN_TOLERANCE)
            if entry.friction is None:
                assert (record["friction_limit"][k] == 0).all()
                continue
            limit = scene_gralen(entry, R)
            np.testing.assert_allclose(record["friction_limit"][k], limit, rtol=0,
                                       atol=GRALEN_TOLERANCE)
            carried = np.abs(pull(yarn, positions))
            slack = record["residual"][k] + GRALEN_TOLERANCE
            sliding = record["sliding"][k]
            assert (np.abs(carried - limit)[sliding] <= slack).all(), (step, k)
            assert (carried[~sliding] <= limit[~sliding] + slack).all(), (step, k)


def test_a_step_of_several_yarns_reports_each_yarn_within_itself():
    """`status` is called within a step after each yarn of a batch (a yarn's Newton runs
    compiled and cannot report): the progress line of a long sweep step."""
    from dynfab.model.builders import build_model
    from dynfab.solvers.static import StaticSolver

    model = build_model(paper_yarn(64, 16, {"control": "force", "values": [0.1]}, yarns=2))
    calls = []
    _, record = StaticSolver(model, status=calls.append).step(initial_state(model), 0.1)
    assert [c[:17] for c in calls] == ["yarn 1 of 2 solve", "yarn 2 of 2 solve"]
    for k, call in enumerate(calls):
        assert call.endswith(f"{record['iterations'][k]} Newton iterations, residual "
                             f"{record['residual'][k]:.3g} N")
