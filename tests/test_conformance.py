"""Every term of V on the numba twin (`dynfab.model.terms`, the static reference): gradient against
central differences of the energy, banded Hessian against central differences of the
gradient (docs/model.md sections 2-4). The terms are the registry's with one-yarn entry points
(`dynfab.model.terms.registry`, `Term.yarn`; the spatial ones are checked in
tests/test_spatial_terms.py), so a term added there is checked here once its numba calls are in
`numba_term` and its stiffness bound in `bounds`. (The dynamic solver's Warp kernels, one layer for
any structure, are checked against this reference term by term: tests/test_kernels_structure.py.)

The state: a small paper fabric (N = 16, 4 crossings, two adjacent yarns) with friction,
gravity and the force load on, its nodes moved at random by up to 0.05 l0, and its crossings
placed in every regime: contact closed inside the Kawabata range and past it, and open;
friction sticking and sliding both ways. Friction's Huber potential is piecewise, with F_T
frozen (the anchors and R_j of the state):
each crossing's slip is >= 0.6 F_T / k_t (>= 5e-7 m) from its stick/slip kink and each
closure >= 1.6e-5 m from g = 0, far beyond the largest difference step (6.25e-8 m), so no
difference crosses a kink (asserted in `test_state_keeps_every_regime_under_the_steps`).

Tolerances: a central difference of f with step h errs by h^2/6 |f'''| (truncation) plus
the rounding of the two evaluations over 2h; steps are taken as rounded ((x + h) - (x - h)
in floating point). Gradient from energies, h = 1e-6 l0: rounding <= eps S / h with
S = n |E| + sum_i |dE/dr_i| |r_i| (n additions in the energy sum; a rounding of eps |r_i| in
a coordinate moves E by |dE/dr_i| eps |r_i|), truncation <= h^2 K / (6 ell), K the term's
stiffness bound and ell the length over which it varies. Hessian from gradients, h = 1e-5 l0
(near the optimum (eps r ell^2)^(1/3) for a gradient rounding eps K r): rounding
<= eps K r / h, r the largest coordinate; truncation <= h^2 K / (6 ell^2). Asserted with a
factor 10 over the sum (sums of many roundings, derivative bounds by their scale); the
estimates are 1e-9 to 1e-8 of the gradient or of K, and a wrong factor, sign or missing
entry is O(1).
"""

import importlib

import numpy as np
import pytest

from dynfab.model import assembly
from dynfab.linalg.banded import zeros_band
from dynfab.model.builders import build_model
from dynfab.model.terms import contact, friction, registry
from independent import PAPER_FRICTION, PAPER_WARP, PAPER_WEFT, dense, make_scene

EPS = np.finfo(float).eps
L, N, CROSSINGS, P = 0.1, 16, 4, 0.5
"""Length [m], segments, crossings, end load [N] of the test fabric."""
L0 = L / N
"""The geometry scale: the projected segment length [m]."""
H_GRAD, H_HESS = 1e-6 * L0, 1e-5 * L0

CROSSING_STATES = ((0.5, "stick"), (3.0, "slide+"), (-0.25, "open"), (0.05, "slide-"))
"""Crossing j's (closure g_j / (C_wa + C_we), friction regime)."""
SLIP = {"stick": 0.4, "slide+": 2.5, "slide-": -2.5, "open": 1.0}
"""Slip / (F_T / k_t) of each regime (1e-6 m where F_T = 0: an open crossing)."""
TWINS = ("numba",)


@pytest.fixture(scope="module")
def model():
    """The test fabric with every term on."""
    return build_model(make_scene(
        geometry=dict(length=L, segments=N, crossings=CROSSINGS, amplitude=0.5e-3,
                      reference="as_woven", yarns=2),
        warp=dict(PAPER_WARP, linear_density=3e-5), weft=dict(PAPER_WEFT, count=16),
        friction=PAPER_FRICTION, gravity=dict(g=9.81), load=dict(control="force", values=[P])))


def perturbed_state(yarn, seed):
    """(positions (N+1, 2) [m], anchors (C,) [m], R (C,) [N], F_T (C,) [N]) in every regime."""
    rng = np.random.default_rng(seed)
    r = yarn.rest_position + rng.uniform(-0.05, 0.05, yarn.rest_position.shape) * L0
    law, nodes, sides = yarn.contact_law, yarn.crossing_node, yarn.crossing_side
    g = np.array([f for f, _ in CROSSING_STATES]) * (law[1] + law[3]) * rng.uniform(0.8, 1.0, 4)
    r[nodes, 1] = sides * (yarn.gap_offset - g)  # g_j = c_j - s_j z_{n_j} (docs/model.md section 3)
    R = np.array([contact.force_from_closure(gj, law) for gj in g])
    F_T = np.array([friction.limit(Rj, yarn.friction_alpha, yarn.friction_constant,
                                   yarn.friction_onset) for Rj in R])
    scale = np.where(F_T > 0, F_T / yarn.stick_stiffness, 1e-6)
    anchors = r[nodes, 0] - np.array([SLIP[s] for _, s in CROSSING_STATES]) * scale
    return r, anchors, R, F_T


@pytest.fixture(scope="module")
def states(model):
    """(yarn index, yarn, positions, anchors, R, F_T) of every yarn, each at its own seed."""
    return [(k, yarn, *perturbed_state(yarn, seed=100 + k)) for k, yarn in enumerate(model.yarns)]


# --------------------------------------------------------------------------
# The twin: (energies (M,), gradients (M, N+1, 2), dense Hessians (M, 2N+2, 2N+2)) of one term
# at a batch of M positions, with the anchors and F_T of the state frozen.


def numba_term(yarn, anchors, F_T, name):
    """(energy(r), add_gradient(r, grad), add_hessian(r, band)) of `dynfab.model.terms.<name>`: the
    registry's uniform entry points, with P, the anchors and F_T frozen."""
    module = importlib.import_module(f"dynfab.model.terms.{name}")
    frozen = assembly.Frozen(P, anchors, F_T, np.zeros(F_T.size), None, False, False)
    return (lambda r: module.yarn_energy(r, yarn, frozen),
            lambda r, g: module.add_yarn_gradient(r, yarn, frozen, g),
            lambda r, b: module.add_yarn_hessian(r, yarn, frozen, b))


def numba_twin(model, k, positions, anchors, R, F_T, name):
    """`dynfab.model.terms.<name>` of yarn k at each position, F_T given (frozen)."""
    energy, add_gradient, add_hessian = numba_term(model.yarns[k], anchors, F_T, name)
    energies, grads, hessians = [], [], []
    for r in positions:
        grad, band = np.zeros_like(r), zeros_band(r.size)
        add_gradient(r, grad)
        add_hessian(r, band)
        energies.append(energy(r))
        grads.append(grad)
        hessians.append(dense(band))
    return np.array(energies), np.array(grads), np.array(hessians)


TWIN = {"numba": numba_twin}


# --------------------------------------------------------------------------
# Central differences, every coordinate in one batch.


def shifted(r, h):
    """(positions (2 r.size, ...): r + h e_m at 2m and r - h e_m at 2m + 1, steps as rounded)."""
    batch = np.repeat(r[None], 2 * r.size, axis=0)
    flat = batch.reshape(2 * r.size, r.size)
    m = np.arange(r.size)
    flat[2 * m, m] += h
    flat[2 * m + 1, m] -= h
    return batch, flat[2 * m, m] - flat[2 * m + 1, m]


def bounds(yarn, name):
    """(K [N/m], ell [m], n): the term's stiffness bound, the length over which its stiffness
    varies and its additions in the energy sum (docs/model.md sections 2-4). Stretch 2 EA/l0 (two
    springs a node); bending (EI/lbar) |dphi/dr|^2 <= 6/l^2 with l >= 0.85 l0 here, plus the moment
    term: 16 EI/(lbar l0^2); contact k_we (the tangent's bound), with |dT/dg| <= k_we^3
    sum C a^2 = K / ell; friction k_t, piecewise quadratic (ell = inf away from its kinks);
    gravity and the load are linear."""
    law = yarn.contact_law
    return {
        "stretch": (2 * yarn.stretch_stiffness.max(), L0, N),
        "bending": (16 * yarn.bend_stiffness.max() / L0 ** 2, L0, N),
        "contact": (law[0], 1.0 / (law[0] ** 2 * (law[1] * law[2] ** 2 + law[3] * law[4] ** 2)),
                    CROSSINGS),
        "friction": (yarn.stick_stiffness, np.inf, CROSSINGS),
        "gravity": (0.0, np.inf, N + 1),
        "load": (0.0, np.inf, 1),
    }[name]


def test_state_keeps_every_regime_under_the_steps(states):
    # No central difference crosses a kink of the piecewise terms: each closure is farther
    # from g = 0, and each slip from its stick/slip switch k_t |s| = F_T, than any step.
    for _, yarn, r, anchors, R, F_T in states:
        nodes, k_t = yarn.crossing_node, yarn.stick_stiffness
        closure = yarn.gap_offset - yarn.crossing_side * r[nodes, 1]
        slip = r[nodes, 0] - anchors
        assert np.abs(closure).min() > 100 * H_HESS
        assert np.abs(np.abs(slip) - F_T / k_t).min() > 5 * H_HESS
        sticking = k_t * np.abs(slip) <= F_T
        assert sticking.any() and (~sticking & (F_T > 0)).any() and (R == 0).any()
        assert (np.sign(slip[~sticking & (F_T > 0)]) == [1, -1]).all()  # sliding both ways


@pytest.mark.parametrize("twin", TWINS)
@pytest.mark.parametrize("name", [t.name for t in registry.TERMS if t.yarn])
def test_gradient_and_hessian_are_the_derivatives(model, states, name, twin):
    # dE/dr_i and d2E/dr_i dr_j against central differences (module docstring: h, tolerance
    # 10 x (rounding + truncation)); the banded Hessian compared as the dense matrix it
    # stores, so entries outside the band must be 0 in the differences too.
    evaluate = TWIN[twin]
    for k, yarn, r, anchors, R, F_T in states:
        K, ell, n = bounds(yarn, name)
        (energy,), (grad,), (hessian,) = evaluate(model, k, r[None], anchors, R, F_T, name)
        batch, steps = shifted(r, H_GRAD)
        energies = evaluate(model, k, batch, anchors, R, F_T, name)[0]
        expected = ((energies[0::2] - energies[1::2]) / steps).reshape(r.shape)
        S = n * abs(energy) + np.sum(np.abs(expected) * np.abs(r))
        tolerance = 10 * (EPS * S / H_GRAD + H_GRAD ** 2 * K / (6 * ell))
        assert np.abs(expected).max() > 1e3 * tolerance  # a test of something
        assert np.abs(grad - expected).max() <= tolerance

        batch, steps = shifted(r, H_HESS)
        grads = evaluate(model, k, batch, anchors, R, F_T, name)[1].reshape(len(batch), -1)
        jacobian = ((grads[0::2] - grads[1::2]) / steps[:, None]).T
        if K == 0:  # gravity and the load: linear energies, constant gradients
            assert not hessian.any() and not jacobian.any()
            continue
        tolerance = 10 * (EPS * K * np.abs(r).max() / H_HESS + H_HESS ** 2 * K / (6 * ell ** 2))
        assert np.abs(jacobian).max() > 1e3 * tolerance
        assert np.abs(hessian - jacobian).max() <= tolerance
