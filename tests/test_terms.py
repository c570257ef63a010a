"""Energy terms: each energy against docs/model.md's formula, each gradient and banded Hessian
against central finite differences, the series contact law, Lc and k_we
(docs/model.md sections 2-4).

Finite-difference tolerances (one rule for every check, stated once here):

- A central difference of f with step h errs by h^2/6 |f'''| (truncation) plus
  the rounding of the two evaluations divided by 2h. Steps are taken "as
  rounded" (the step is (x + h) - (x - h) in floating point), so the rounding
  of x + h does not count.
- Gradient from energies, h = 1e-6 l0 (l0 = L/N, the geometry scale):
  rounding <= eps S / h with S = n |E| + sum_i |dE/dr_i| |r_i| (n additions in
  the energy sum, each rounding to eps of the running total; a rounding eps |r_i|
  in a coordinate moves E by |dE/dr_i| eps |r_i|); truncation <= h^2 K / (6 ell),
  K the term's stiffness bound and ell the length over which it varies.
- Hessian from gradients, h = 1e-5 l0 (near the optimum (eps r ell^2)^(1/3)
  for a gradient rounding eps K r): rounding <= eps K r / h, r the largest
  coordinate the term reads; truncation <= h^2 K / (6 ell^2).
- Asserted with a factor 10 over the sum of the two estimates (sums of many
  roundings, bounds of derivatives by their scale). The estimates are
  1e-9 to 1e-8 of the gradient or of K; a wrong factor, sign or missing
  entry in an implementation is O(1).
"""

import math

import numpy as np
import pytest
from scipy.special import ellipe

from dynfab.model import assembly, geometry
from dynfab.linalg.banded import zeros_band
from dynfab.model.builders import build_model
from dynfab.scene import with_key
from dynfab.model.terms import bending, contact, friction, gravity, load, registry, stretch
from independent import (closure_of_force, contact_energy, dense, fd_gradient, fd_jacobian,
                         yarn_energies)

EPS = np.finfo(float).eps

# Paper parameters (docs/model.md section 7) on a small mesh: N = 16, 4 crossings (nodes 2, 6, 10,
# 14), two adjacent yarns (phases s_k = +1, -1), weft as in the paper (N_wa = 16, L_we = L).
L, N, CROSSINGS, A_WA = 0.1, 16, 4, 0.5e-3
EA, EI, C_WA, K_WA = 13.72, 1.47e-7, 0.2e-3, 0.2
EI_WE, A_WE, C_WE, K_WE, N_WA = 1.47e-7, 0.5e-3, 0.2e-3, 0.2, 16
ALPHA, BETA, ELL, R_F = 0.2, 1e3, 2e-3, 1e-3
RHO, G, P = 3e-5, 9.81, 0.5
L0 = L / N
"""The geometry scale: the projected segment length [m]."""
H_GRAD, H_HESS = 1e-6 * L0, 1e-5 * L0

# The state of crossing j (j = 1..4): (closure g_j / (C_wa + C_we), friction regime).
# Closed crossings sit well inside the Kawabata range (0.05, 0.5) and past it (3);
# the open one at g = -0.25 (C_wa + C_we). Sticking slips are 0.4 F_T / k_t,
# sliding ones +-2.5 F_T / k_t: the kinks are >= 0.6 F_T / k_t >= 5e-7 m away, and
# g = 0 >= 1.6e-5 m away, both far beyond the largest FD step (6e-8 m).
CROSSING_STATES = ((0.5, "stick"), (3.0, "slide+"), (-0.25, "open"), (0.05, "slide-"))
SLIP = {"stick": 0.4, "slide+": 2.5, "slide-": -2.5, "open": 1.0}


def paper_scene(make_scene, reference):
    """The small one-yarn test model (two adjacent warp yarns) with every term on: contact,
    friction, gravity, force load."""
    return make_scene(
        geometry=dict(length=L, segments=N, crossings=CROSSINGS, amplitude=A_WA,
                      reference=reference, yarns=2),
        warp=dict(EA=EA, EI=EI, kawabata_C=C_WA, kawabata_K=K_WA, linear_density=RHO),
        weft=dict(EI=EI_WE, amplitude=A_WE, kawabata_C=C_WE, kawabata_K=K_WE, count=N_WA),
        friction=dict(alpha=ALPHA, beta=BETA, contact_length=ELL, fiber_radius=R_F),
        gravity=dict(g=G),
        load=dict(control="force", values=[P]),
    )


# --------------------------------------------------------------------------
# The model as docs/model.md writes it, independently of dynfab (numpy and scipy; each term's
# energy is tests/independent.py's yarn_energies).


def as_woven(phase):
    """r0_i = (i L/N, s_k A sin(N_we pi x0_i / L)) (docs/model.md section 1)."""
    x = np.arange(N + 1) * L / N
    return np.stack([x, phase * A_WA * np.sin(CROSSINGS * math.pi * x / L)], axis=1)


def crossing_nodes():
    """n_j = (2j - 1) N / (2 N_we)."""
    return np.array([(2 * j - 1) * N // (2 * CROSSINGS) for j in range(1, CROSSINGS + 1)])


def crossing_sides(phase):
    """s_j = s_k (-1)^(j+1)."""
    return np.array([phase * (-1.0) ** (j + 1) for j in range(1, CROSSINGS + 1)])


def half_wave_arc_length(p, A):
    """Lc = int_0^p sqrt(1 + (A pi/p)^2 cos^2(pi x/p)) dx = (2p/pi) sqrt(1+m) E(m/(1+m)),
    m = (A pi / p)^2.

    Derivation: u = pi x / p gives (p/pi) int_0^pi sqrt(1 + m cos^2 u) du, symmetric
    about pi/2, = (2p/pi) int_0^(pi/2) sqrt(1 + m - m sin^2 u) du
    = (2p/pi) sqrt(1+m) int_0^(pi/2) sqrt(1 - k^2 sin^2 u) du with k^2 = m/(1+m) in [0, 1):
    the complete elliptic integral of the second kind, scipy's ellipe(k^2).
    """
    m = (A * math.pi / p) ** 2
    return 2 * p / math.pi * math.sqrt(1 + m) * ellipe(m / (1 + m))


def paper_law():
    """(k_we, C_wa, a_wa, C_we, a_we) of the paper fabric, from eq. 4 and a_m = K_m / Lc_m."""
    k_we = math.pi ** 4 / 2 * EI_WE / (L / N_WA) ** 3  # P_we = 0
    return np.array([k_we, C_WA, K_WA / half_wave_arc_length(L / CROSSINGS, A_WA),
                     C_WE, K_WE / half_wave_arc_length(L / N_WA, A_WE)])


# --------------------------------------------------------------------------
# A perturbed state with every contact and friction regime.


def perturbed_state(yarn, phase, reference, seed):
    """Positions (N+1, 2), anchors, frozen F_T and the closures, every regime of CROSSING_STATES.

    Every coordinate moves by up to 0.05 l0 (random, seeded); then the crossing
    nodes are placed at the closures of CROSSING_STATES (docs/model.md section 3 formulas),
    and the anchors at the slips of the friction regimes, F_T = alpha R + beta ell r_f.
    """
    rng = np.random.default_rng(seed)
    r = as_woven(phase) + rng.uniform(-0.05, 0.05, (N + 1, 2)) * L0
    nodes, sides = crossing_nodes(), crossing_sides(phase)
    g = np.array([f for f, _ in CROSSING_STATES]) * (C_WA + C_WE) * rng.uniform(0.8, 1.0, 4)
    if reference == "as_woven":
        r[nodes, 1] = as_woven(phase)[nodes, 1] - sides * g
    else:
        r[nodes, 1] = sides * (A_WA + A_WE - g)
    R, F_T, tangent = np.zeros(4), np.zeros(4), np.zeros(4)
    assembly.contact_state(r, yarn, R, F_T, tangent)
    assert np.array_equal(R > 0, g > 0)  # the closure of docs/model.md section 3 opens and closes
    # them
    k_t = EA / (L / N)
    scale = np.where(F_T > 0, F_T / k_t, 1e-6)
    anchors = r[nodes, 0] - np.array([SLIP[s] for _, s in CROSSING_STATES]) * scale
    return r, anchors, F_T, g


# --------------------------------------------------------------------------
# Finite differences.


def term_functions(yarn, anchors, F_T):
    """name -> (energy(r), gradient(r) (N+1, 2), dense Hessian(r), K [N/m], ell [m], n).

    K bounds the term's Hessian entries, from its parameters (docs/model.md sections 2-4):
    stretch 2 EA/l0 (two springs per node); bending (EI/lbar) |dphi/dr|^2 <= 6/l^2
    with l >= 0.85 l0 on these states, plus the moment term, so 16 EI/(lbar l0^2);
    contact k_we (the tangent bound); friction k_t. ell, the length over which the
    stiffness varies: l0 for stretch and bending, and for contact, from the law:
    |dT/dg| <= k_we^3 sum C a^2 = K / ell with ell = 1 / (k_we^2 sum C a^2); friction
    is piecewise quadratic (ell = inf away from the kink). Gravity and load are linear.
    n is the number of additions in the energy sum.
    """
    law = yarn.contact_law
    nodes, sides, offsets = yarn.crossing_node, yarn.crossing_side, yarn.gap_offset
    k_t = yarn.stick_stiffness

    def grad_of(add):
        def f(r):
            out = np.zeros_like(r)
            add(r, out)
            return out
        return f

    def hess_of(add):
        def f(r):
            band = zeros_band(r.size)
            add(r, band)
            return dense(band)
        return f

    no_hessian = hess_of(lambda r, band: None)
    contact_ell = 1.0 / (law[0] ** 2 * (law[1] * law[2] ** 2 + law[3] * law[4] ** 2))
    c0 = np.zeros(nodes.size)

    def total_energy(r):
        out = np.zeros(6)
        assembly.energies(r, yarn, P, anchors, F_T, out)
        return out.sum()

    stretch_K = 2 * yarn.stretch_stiffness.max()
    bend_K = 16 * yarn.bend_stiffness.max() / L0 ** 2
    return {
        "stretch": (lambda r: stretch.energy(r, yarn.rest_length, yarn.stretch_stiffness),
                    grad_of(lambda r, g: stretch.add_gradient(r, yarn.rest_length,
                                                              yarn.stretch_stiffness, g)),
                    hess_of(lambda r, b: stretch.add_hessian(r, yarn.rest_length,
                                                             yarn.stretch_stiffness, b)),
                    stretch_K, L0, N),
        "bending": (lambda r: bending.energy(r, yarn.bend_stiffness, yarn.rest_angle),
                    grad_of(lambda r, g: bending.add_gradient(r, yarn.bend_stiffness,
                                                              yarn.rest_angle, g)),
                    hess_of(lambda r, b: bending.add_hessian(r, yarn.bend_stiffness,
                                                             yarn.rest_angle, b)),
                    bend_K, L0, N),
        "contact": (lambda r: contact.energy(r, nodes, sides, offsets, law),
                    grad_of(lambda r, g: contact.add_gradient(r, nodes, sides, offsets, law, g)),
                    hess_of(lambda r, b: contact.add_hessian(r, nodes, sides, offsets, law, b)),
                    law[0], contact_ell, nodes.size),
        "friction": (lambda r: friction.energy(r, nodes, anchors, F_T, k_t),
                     grad_of(lambda r, g: friction.add_gradient(r, nodes, anchors, F_T, k_t, g)),
                     hess_of(lambda r, b: friction.add_hessian(r, nodes, anchors, F_T, k_t, b)),
                     k_t, np.inf, nodes.size),
        "gravity": (lambda r: gravity.energy(r, yarn.rest_position, yarn.mass, yarn.gravity),
                    grad_of(lambda r, g: gravity.add_gradient(yarn.mass, yarn.gravity, g)),
                    no_hessian, 0.0, np.inf, N + 1),
        "load": (lambda r: load.energy(r, yarn.rest_position, P),
                 grad_of(lambda r, g: load.add_gradient(P, g)),
                 no_hessian, 0.0, np.inf, 1),
        "total": (total_energy,
                  grad_of(lambda r, g: assembly.gradient(r, yarn, P, anchors, F_T, g)),
                  hess_of(lambda r, b: assembly.hessian(r, yarn, anchors, F_T, c0, False, b)),
                  stretch_K + bend_K + law[0] + k_t, min(L0, contact_ell), 6 + 2 * N),
    }


TERM_NAMES = ("stretch", "bending", "contact", "friction", "gravity", "load", "total")
REFERENCES = ("as_woven", "prestressed")


@pytest.fixture(scope="module", params=REFERENCES)
def yarn_model(request, make_scene):
    """(model, reference): the one-yarn model of `paper_scene` (two adjacent warp yarns) in
    each reference state."""
    return build_model(paper_scene(make_scene, request.param)), request.param


def yarn_states(model, reference):
    """(yarn, phase, r, anchors, F_T, g) of every yarn, each at its own seeded state."""
    for k, yarn in enumerate(model.yarns):
        phase = (-1.0) ** k
        r, anchors, F_T, g = perturbed_state(yarn, phase, reference, seed=100 + k)
        yield yarn, phase, r, anchors, F_T, g


def test_energies_match_the_formulas_of_model_md(yarn_model):
    # Each term of V = E_stretch + E_bend + sum E_contact - W_load - W_gravity + sum H
    # (docs/model.md sections 2-4) against the same formula written independently
    # (tests/independent.py, yarn_energies), in every regime. Tolerance: the worst-conditioned
    # operation is l - l0 at strains ~ 1e-2 (condition ~ 1e2), summed over N = 16 terms:
    # 1e2 x 16 x eps ~ 4e-13 of the term; 1e-11 relative leaves a factor 20 (contact:
    # brentq to 4 eps in R).
    model, reference = yarn_model
    out = np.zeros(6)
    for yarn, phase, r, anchors, F_T, g in yarn_states(model, reference):
        assembly.energies(r, yarn, P, anchors, F_T, out)
        expected = yarn_energies(model.scene, r, phase, P, anchors, F_T)
        for name, index in ((name, registry.index(name)) for name in
                            ("stretch", "bending", "contact", "friction", "gravity", "load")):
            assert expected[name] != 0.0, name  # every term is exercised
            assert out[index] == pytest.approx(expected[name], rel=1e-11, abs=0), name


@pytest.mark.parametrize("term", TERM_NAMES)
def test_gradient_is_the_derivative_of_the_energy(yarn_model, term):
    # dE/dr_i = (E(r + h e_i) - E(r - h e_i)) / 2h + O(h^2 K/ell) + O(eps S/h)
    # (module docstring: h = 1e-6 l0, tolerance 10 x (rounding + truncation)).
    model, reference = yarn_model
    for yarn, _, r, anchors, F_T, _ in yarn_states(model, reference):
        energy, grad, _, K, ell, n = term_functions(yarn, anchors, F_T)[term]
        expected = fd_gradient(energy, r, H_GRAD)
        S = n * abs(energy(r)) + np.sum(np.abs(expected) * np.abs(r))
        tolerance = 10 * (EPS * S / H_GRAD + H_GRAD ** 2 * K / (6 * ell))
        assert np.abs(expected).max() > 1e3 * tolerance  # a test of something
        assert np.abs(grad(r) - expected).max() <= tolerance


@pytest.mark.parametrize("term", TERM_NAMES)
def test_hessian_is_the_derivative_of_the_gradient(yarn_model, term):
    # d2E/dr_i dr_j = (g_i(r + h e_j) - g_i(r - h e_j)) / 2h + O(h^2 K/ell^2) + O(eps K r/h),
    # the banded Hessian compared as the dense matrix it stores (entries outside the
    # band must then be 0 in the differences too). h = 1e-5 l0 (module docstring).
    model, reference = yarn_model
    for yarn, _, r, anchors, F_T, _ in yarn_states(model, reference):
        _, grad, hess, K, ell, _ = term_functions(yarn, anchors, F_T)[term]
        expected = fd_jacobian(grad, r, H_HESS)
        if K == 0:  # gravity and load: linear energies, constant gradients
            assert not hess(r).any() and not expected.any()
            continue
        tolerance = 10 * (EPS * K * np.abs(r).max() / H_HESS + H_HESS ** 2 * K / (6 * ell ** 2))
        assert np.abs(hess(r) - expected).max() <= tolerance
        assert np.abs(expected).max() > 1e3 * tolerance


def test_friction_regimes_and_contact_stiffness_are_exercised(yarn_model):
    # The states above really have both friction regimes and both contact regimes:
    # the Huber Hessian is k_t exactly where |s| k_t < F_T (sticking) and 0 where
    # sliding (H is linear there), and the contact Hessian is dR/dg > 0 on closed and
    # 0 on open crossings.
    model, reference = yarn_model
    for yarn, _, r, anchors, F_T, g in yarn_states(model, reference):
        functions = term_functions(yarn, anchors, F_T)
        nodes = yarn.crossing_node
        friction_diag = np.diag(functions["friction"][2](r))[2 * nodes]
        contact_diag = np.diag(functions["contact"][2](r))[2 * nodes + 1]
        regimes = [s for _, s in CROSSING_STATES]
        for j, regime in enumerate(regimes):
            assert friction_diag[j] == (yarn.stick_stiffness if regime == "stick" else 0.0)
            assert (contact_diag[j] > 0) == (g[j] > 0)
            assert contact_diag[j] <= yarn.contact_law[0]


def test_friction_coupling_is_the_derivative_through_the_contact_force(yarn_model):
    # The coupled Jacobian (hessian(..., coupled=True)) is the derivative of the gradient
    # with F_T recomputed from R(g(z)) at every evaluation (contact_state): on a
    # sliding, closed crossing d(dH/ds)/dz = sign(s) alpha dR/dg dg/dz, with
    # dg/dz = -s_j. Whole matrix against central differences, h = 1e-5 l0, tolerance
    # as for the total Hessian (F_T(z) is as smooth as R(g)). The regimes do not change
    # within h (module constants), so the Jacobian is that of a smooth function.
    model, reference = yarn_model
    for yarn, _, r, anchors, F_T, g in yarn_states(model, reference):
        c = yarn.crossing_node.size

        def coupled_gradient(pos):
            R, limit, tangent = np.zeros(c), np.zeros(c), np.zeros(c)
            assembly.contact_state(pos, yarn, R, limit, tangent)
            out = np.zeros_like(pos)
            assembly.gradient(pos, yarn, P, anchors, limit, out)
            return out

        R, limit, tangent = np.zeros(c), np.zeros(c), np.zeros(c)
        assembly.contact_state(r, yarn, R, limit, tangent)
        band = zeros_band(r.size)
        assembly.hessian(r, yarn, anchors, limit, tangent, True, band)
        expected = fd_jacobian(coupled_gradient, r, H_HESS)
        _, _, _, K, ell, _ = term_functions(yarn, anchors, limit)["total"]
        tolerance = 10 * (EPS * K * np.abs(r).max() / H_HESS + H_HESS ** 2 * K / (6 * ell ** 2))
        assert np.abs(dense(band) - expected).max() <= tolerance
        # the coupling entries themselves (x row, z column of a sliding closed crossing)
        nodes, sides = yarn.crossing_node, yarn.crossing_side
        for j, (_, regime) in enumerate(CROSSING_STATES):
            if regime.startswith("slide") and g[j] > 0:
                slip = r[nodes[j], 0] - anchors[j]
                coupling = np.sign(slip) * ALPHA * tangent[j] * (-sides[j])
                uncoupled = zeros_band(r.size)
                assembly.hessian(r, yarn, anchors, limit, tangent, False, uncoupled)
                entry = expected[2 * nodes[j], 2 * nodes[j] + 1]
                assert abs(coupling) > 1e3 * tolerance
                assert abs(entry - dense(uncoupled)[2 * nodes[j], 2 * nodes[j] + 1] - coupling) \
                    <= tolerance


# --------------------------------------------------------------------------
# The series contact law (docs/model.md section 3, paper eqs. 4-9).

K_VALUES = (1e-4, 1e-3, 1e-2, 0.2, 1.0, 10.0)
"""Kawabata K [m/N] over the range asked of the law."""
G_VALUES = np.geomspace(1e-9, 1e-2, 36)
"""Closures [m] from far below C to far beyond it (saturated Kawabata, weft spring only)."""


def law_for(K):
    law = paper_law()
    law[2] = K / half_wave_arc_length(L / CROSSINGS, A_WA)
    law[4] = K / half_wave_arc_length(L / N_WA, A_WE)
    return law


@pytest.mark.parametrize("K", K_VALUES)
def test_contact_force_inverts_the_closure(K):
    # g(R(g)) = g with g(R) = R/k_we + sum_m C_m (1 - exp(-a_m R)) evaluated here, not by
    # dynfab. Tolerance 8 eps g: Newton stops when its step is <= 4e-16 R, leaving
    # |g - g(R)| <= 4e-16 R/T <= 4e-16 g (R/T = R/k + sum C a R exp(-aR) <= g since
    # x exp(-x) <= 1 - exp(-x)); evaluating g(R), a sum of three positive terms,
    # rounds to 3 eps g; both evaluations: ~8 eps g.
    law = law_for(K)
    for g in G_VALUES:
        R = contact.force_from_closure(g, law)
        assert R > 0
        assert abs(closure_of_force(R, law) - g) <= 8 * EPS * g
        assert abs(contact.closure_from_force(R, law) - g) <= 8 * EPS * g


@pytest.mark.parametrize("K", K_VALUES)
def test_contact_energy_derivative_is_the_force(K):
    # dE/dg = R for E(g) = energy_of_force(R(g)): central difference with h = 1e-6 g.
    # Truncation h^2/6 |R''|, R'' = dT/dg = T^3 sum C a^2 exp(-aR) computed here.
    # Rounding: R(g) is exact for a closure within 8 eps g of g, which moves E by
    # dE/dg x 8 eps g = 8 eps g R, and evaluating E adds a few eps E <= 4 eps g R
    # (E <= g R: the springs' force never exceeds R): 2 x 12 eps g R / (2h).
    law = law_for(K)
    k, c1, a1, c2, a2 = law
    for g in G_VALUES:
        h = 1e-6 * g
        R = contact.force_from_closure(g, law)
        T = contact.tangent(R, law)
        R2 = T ** 3 * (c1 * a1 ** 2 * math.exp(-a1 * R) + c2 * a2 ** 2 * math.exp(-a2 * R))
        E = contact.energy_of_force(R, law)
        assert E == pytest.approx(contact_energy(R, law), rel=1e-13)  # formula of
        # docs/model.md section 3
        plus, minus = g + h, g - h
        derivative = (contact.energy_of_force(contact.force_from_closure(plus, law), law)
                      - contact.energy_of_force(contact.force_from_closure(minus, law), law)) \
            / (plus - minus)
        tolerance = 10 * (h ** 2 / 6 * R2 + 24 * EPS * g * R / (2 * h))
        assert abs(derivative - R) <= tolerance


@pytest.mark.parametrize("K", K_VALUES)
def test_contact_tangent_is_the_derivative_of_the_force(K):
    # T = dR/dg = 1/(1/k_we + sum_m C_m a_m exp(-a_m R)), central difference with h = 1e-4 g.
    # Truncation h^2/6 |R'''|, R''' = 3 T^5 S2^2 - T^4 S3, S_n = sum C a^n exp(-aR);
    # rounding: R carries 8 eps g of closure error, i.e. 8 eps g T of force, so
    # 2 x 8 eps g T / (2h). And 0 < T <= k_we: the weft spring in series bounds it.
    law = law_for(K)
    k, c1, a1, c2, a2 = law
    for g in G_VALUES:
        h = 1e-4 * g
        R = contact.force_from_closure(g, law)
        T = contact.tangent(R, law)
        S2 = c1 * a1 ** 2 * math.exp(-a1 * R) + c2 * a2 ** 2 * math.exp(-a2 * R)
        S3 = c1 * a1 ** 3 * math.exp(-a1 * R) + c2 * a2 ** 3 * math.exp(-a2 * R)
        R3 = abs(3 * T ** 5 * S2 ** 2) + abs(T ** 4 * S3)
        plus, minus = g + h, g - h
        derivative = (contact.force_from_closure(plus, law)
                      - contact.force_from_closure(minus, law)) / (plus - minus)
        tolerance = 10 * (h ** 2 / 6 * R3 + 16 * EPS * g * T / (2 * h))
        assert abs(derivative - T) <= tolerance
        assert 0 < T <= k


@pytest.mark.parametrize("K", K_VALUES)
def test_contact_is_unilateral_and_monotonic(K):
    # R = 0 for g <= 0 (open, docs/model.md section 3); R strictly increasing in g: on a grid whose
    # spacing (1 % of g) is far above R's rounding (8 eps relative), R(g) increases.
    law = law_for(K)
    for g in (0.0, -0.0, -1e-12, -1e-3, -np.inf):
        assert contact.force_from_closure(g, law) == 0.0
    grid = np.concatenate([np.geomspace(1e-12, 1e-2, 2000), [2e-2]])
    R = np.array([contact.force_from_closure(g, law) for g in grid])
    assert np.all(np.diff(R) > 0)


# --------------------------------------------------------------------------
# Lc and k_we (paper eqs. 4, 6-7).


@pytest.mark.parametrize("ratio", (0.0, 1e-3, 0.08, 0.25, 1.0, 3.0, 10.0))
@pytest.mark.parametrize("p", (6.25e-3, 0.025, 1.0))
def test_half_wave_arc_length_is_the_elliptic_integral(p, ratio):
    # Lc = (2p/pi) sqrt(1+m) E(m/(1+m)), m = (A pi/p)^2 (derived in half_wave_arc_length
    # above), for amplitude/half-period ratios up to 10 (slopes A pi/p up to 31, both
    # sides of the code's switch at 10; the paper's is 0.25). 1e-14 relative: both sides are accurate to a few eps (ellipe's
    # series to ~1e-16; the mean of 256 positive terms to ~16 eps at worst).
    A = ratio * p
    assert geometry.half_wave_arc_length(p, A) == pytest.approx(half_wave_arc_length(p, A),
                                                                 rel=1e-14, abs=0)


def test_model_contact_law_uses_eq4_and_the_arc_lengths(make_scene):
    # k_we by hand (eq. 4) for the paper values, EI_we = 1.47e-7 N m^2, L_we = 0.1 m,
    # N_wa = 16, P_we = 0: Lp = 0.1/16 = 6.25e-3 m, Lp^3 = 2.44140625e-7 m^3,
    # pi^4/2 = 48.704545..., so k_we = 48.704545 x 1.47e-7 / 2.44140625e-7 = 29.3255 N/m.
    # And a_m = K_m / Lc_m with the elliptic Lc. Both to 1e-14 (a few roundings).
    scene = make_scene(
        geometry=dict(length=0.1, segments=224, crossings=16, amplitude=0.5e-3),
        warp=dict(EA=13.72, EI=1.47e-7, kawabata_C=0.2e-3, kawabata_K=0.2),
        weft=dict(EI=1.47e-7, amplitude=0.5e-3, kawabata_C=0.2e-3, kawabata_K=0.2),
        load=dict(control="displacement", values=[1e-3]))
    law = build_model(scene).yarns[0].contact_law
    assert law[0] == pytest.approx(29.3255, rel=1e-5)  # the hand value, to its 6 digits
    assert law[0] == pytest.approx((math.pi ** 4 / 2) * 1.47e-7 / (0.1 / 16) ** 3, rel=1e-14)
    lc = half_wave_arc_length(0.1 / 16, 0.5e-3)
    assert law[1:] == pytest.approx([0.2e-3, 0.2 / lc, 0.2e-3, 0.2 / lc], rel=1e-14)
    # with weft tension P_we = 3 Pcr_we (alpha_we = 3): k_we (1 + 3/16^2)
    tensioned = build_model(with_key(scene, "weft.tension", 3 * math.pi ** 2 * 1.47e-7 / 0.1 ** 2))
    assert tensioned.yarns[0].contact_law[0] == pytest.approx(law[0] * (1 + 3 / 256), rel=1e-14)


@pytest.mark.parametrize("alpha_we", (0.0, 3.0, -0.9))
def test_eq4_is_eq2_at_the_crossings(alpha_we):
    # Eq. 2 (weft under alternating unit forces R = 1, N_wa harmonics) evaluated at the
    # crossings y = (2k-1) L_we/(2 N_wa) has |w| = 2 L^3/(pi^4 EI N (N^2 + alpha)) (eq. 3),
    # so R/|w| is eq. 4's k_we. The double sum cancels heavily (terms up to 1/(1 + alpha)
    # against a result ~ 1/N^3): its rounding is bounded by 4 eps sum |terms| / |sum|.
    n_wa, l_we, ei = 16, 0.1, 1.47e-7
    n = np.arange(1, n_wa + 1)[:, None]
    m = np.arange(1, n_wa // 2 + 1)[None, :]
    terms = ((np.sin(n * np.pi / n_wa * (2 * m - 1.5)) - np.sin((2 * m - 0.5) * n * np.pi / n_wa))
             / (n ** 2 * (n ** 2 + alpha_we)))
    k_we = geometry.weft_stiffness(ei, l_we, n_wa, alpha_we * math.pi ** 2 * ei / l_we ** 2)
    for k in range(1, n_wa + 1):
        y = (2 * k - 1) * l_we / (2 * n_wa)
        mode = np.sin(n * np.pi * y / l_we)
        double_sum = np.sum(terms * mode)
        rounding = 4 * EPS * np.sum(np.abs(terms * mode)) / abs(double_sum)
        w = 2 * l_we ** 3 / (math.pi ** 4 * ei) * double_sum
        assert 1 / abs(w) == pytest.approx(k_we, rel=rounding)


def test_secant_friction_stiffness_majorises_the_huber_potential():
    """Newton uses F_T/|s0| on a sliding crossing after a shortened step (dynfab/solvers/static.py).

    Claim (friction.add_hessian): q(s) = H(s0) + H'(s0)(s - s0) + 1/2 (F_T/|s0|)(s - s0)^2
    lies above H(s) for every s, because |s| <= s^2/(2|s0|) + |s0|/2 and the Huber
    potential is the stick-clipped |s|. Checked on a grid to rounding (16 eps of the scale).
    """
    from dynfab.linalg.banded import zeros_band

    k_t, F_T = 3.07e4, 6e-3
    rng = np.random.default_rng(27)
    for s0 in np.concatenate([rng.uniform(1.01, 50, 20), -rng.uniform(1.01, 50, 20)]) * F_T / k_t:
        pos = np.array([[s0, 0.0], [0.0, 0.0]])
        band = zeros_band(4)
        friction.add_hessian(pos, np.array([0]), np.zeros(1), np.array([F_T]), k_t, band, True)
        curvature = band[0, 5]
        assert curvature == pytest.approx(F_T / abs(s0), rel=1e-15)
        s = np.linspace(-3 * abs(s0), 3 * abs(s0), 2001)
        h0 = friction.huber(s0, F_T, k_t)
        slope = friction.huber_derivative(s0, F_T, k_t)
        model = h0 + slope * (s - s0) + 0.5 * curvature * (s - s0) ** 2
        exact = np.array([friction.huber(v, F_T, k_t) for v in s])
        assert np.all(model >= exact - 16 * EPS * (F_T * abs(s0) * 3))
