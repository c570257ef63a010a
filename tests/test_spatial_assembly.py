"""The spatial fabric's assembled energy, gradient and sparse Hessian (docs/model.md section
11) on a small picture frame: the derivatives against central differences of the assembled
energy (each element is checked alone in tests/test_spatial_terms.py; this checks the
gathering, the scattering and the pattern's order), the preload woven in, and a rigid motion
of the whole specimen changing no energy.
"""

from __future__ import annotations

import numpy as np
import pytest

from dynfab.model.fabric import contact, spatial
from dynfab.model.builders import build_model
from dynfab.scene import parse_scene_text
from dynfab.model.terms import contact as contact_law
from test_shear_specimens import FRAME, scene_text

SMALL_FRAME = FRAME.replace("side = 0.06", "side = 0.022")


@pytest.fixture(scope="module")
def specimen():
    return build_model(parse_scene_text(scene_text(SMALL_FRAME, [1e-3])))


def perturbed(structure, seed=0):
    """Positions moved off the as-woven state by up to 20 um, anchors and limits so that some
    crossings stick, some slide and some are open (F_T = 0)."""
    rng = np.random.default_rng(seed)
    pos = structure.rest_position + 2e-5 * rng.standard_normal(structure.rest_position.shape)
    ties = structure.tie_a.size
    anchors = np.column_stack([1e-6 * rng.standard_normal((ties, 2)),
                               structure.tie_rotation_law[:, spatial.PHI_REST]
                               + 1e-2 * rng.standard_normal(ties)])
    limit = np.where(np.arange(ties) % 3 == 0, 0.0, 1e-6 * (1 + np.arange(ties) % 2) * 1e3)
    return pos, anchors, limit


def energy(structure, pos, anchors, limit):
    return spatial.total_energy(pos, structure, np.zeros(structure.chain_start.size - 1),
                                anchors, limit, np.zeros(len(spatial.TERMS)))


def gradient(structure, pos, anchors, limit):
    grad = np.zeros_like(pos)
    spatial.gradient(pos, structure, np.zeros(structure.chain_start.size - 1), anchors, limit,
                     grad)
    return grad


def test_the_gradient_is_the_derivative_of_the_energy(specimen):
    """Central differences on 40 dofs, h = 1e-8 m: truncation h^2 |V'''| ~ 1e-16 k ~ 1e-9 N at
    k ~ 1e7 N/m, rounding eps V / h ~ 1e-10 N; 1e-7 of the largest force component leaves a
    margin and still fails on a term scattered to the wrong dof."""
    s = specimen.structure
    pos, anchors, limit = perturbed(s)
    grad = gradient(s, pos, anchors, limit).ravel()
    rng = np.random.default_rng(1)
    h = 1e-8
    for dof in rng.choice(pos.size, 40, replace=False):
        plus, minus = pos.copy().ravel(), pos.copy().ravel()
        plus[dof] += h
        minus[dof] -= h
        fd = (energy(s, plus.reshape(pos.shape), anchors, limit)
              - energy(s, minus.reshape(pos.shape), anchors, limit)) / (2 * h)
        assert fd == pytest.approx(grad[dof], abs=1e-7 * np.abs(grad).max() + 1e-9)


def test_the_sparse_hessian_is_the_derivative_of_the_gradient(specimen):
    """Every entry of the assembled Hessian (all dofs, `Pattern.full_matrix`) against central
    differences of the gradient, h = 1e-9 m: error h^2 |V''''| + eps |grad| / h, about 1e-6
    of the largest entry."""
    s = specimen.structure
    pos, anchors, limit = perturbed(s, seed=2)
    pattern = spatial.pattern_of(s)
    values = np.zeros(pattern.size)
    spatial.hessian_values(pos, s, anchors, limit, values)
    H = pattern.full_matrix(values)
    h = 1e-9
    scale = np.abs(H).max()
    rng = np.random.default_rng(3)
    for dof in rng.choice(pos.size, 30, replace=False):
        plus, minus = pos.copy().ravel(), pos.copy().ravel()
        plus[dof] += h
        minus[dof] -= h
        column = (gradient(s, plus.reshape(pos.shape), anchors, limit)
                  - gradient(s, minus.reshape(pos.shape), anchors, limit)).ravel() / (2 * h)
        np.testing.assert_allclose(H[:, dof], column, atol=1e-6 * scale)


def test_the_as_woven_state_carries_the_preload(specimen):
    """The closure offset solves the series law at R_p: every contact force of the as-woven
    state is the scene's preload (0.1 N), to the law's own solve (4e-16 relative steps)."""
    s = specimen.structure
    R = np.zeros(s.tie_a.size)
    contact.forces(s.rest_position, s, R)
    np.testing.assert_allclose(R, 0.1, rtol=1e-12)
    g = s.tie_gap_offset - s.tie_side * (s.rest_position[s.tie_a, 2] - s.rest_position[s.tie_b, 2])
    np.testing.assert_allclose(g, contact_law.closure_from_force(0.1, s.tie_contact_law[0]))


def test_a_rigid_motion_changes_no_energy_and_turns_the_forces(specimen):
    """An in-plane rotation by 0.7 rad and a translation in x, y, z of every node: each term's
    energy is unchanged, the anchors (in each crossing's own frame) too, and the forces turn
    with the rotation (to rounding: 1e-9 of the largest)."""
    s = specimen.structure
    pos, anchors, limit = perturbed(s, seed=4)
    angle = 0.7
    turn = np.array([[np.cos(angle), -np.sin(angle), 0.0], [np.sin(angle), np.cos(angle), 0.0],
                     [0.0, 0.0, 1.0]])
    moved = pos @ turn.T + np.array([0.3, -0.2, 1e-3])
    P = np.zeros(s.chain_start.size - 1)
    before = spatial.energy_vector(s, pos, P, anchors, limit)
    after = spatial.energy_vector(s, moved, P, anchors, limit)
    np.testing.assert_allclose(after, before, rtol=1e-9, atol=1e-12 * np.abs(before).sum())
    g0, g1 = gradient(s, pos, anchors, limit), gradient(s, moved, anchors, limit)
    np.testing.assert_allclose(g1, g0 @ turn.T, atol=1e-9 * np.abs(g0).max())


def test_each_crossings_secant_weight_blends_its_own_block(specimen):
    """The Hessian is linear in each crossing's secant weight, and a weight enters only its
    crossing's block: H(w_A + w_B) = H(w_A) + H(w_B) - H(0) for two disjoint sets of crossings,
    H(1/2) the mean of H(0) and H(1), one weight for all the same as that weight for each
    (sums of the same numbers in the same order: to rounding)."""
    s = specimen.structure
    pos, anchors, limit = perturbed(s, seed=3)
    ties = s.tie_a.size

    def hessian(secant):
        return spatial.sparse_hessian(s, pos, anchors, limit, secant).toarray()

    exact, full = hessian(0.0), hessian(1.0)
    scale = 1e-13 * np.abs(exact).max()  # rounding of the sums (stretch entries dominate)
    assert np.abs(full - exact).max() > 1e6 * scale  # some crossings slide: a real change
    first = (np.arange(ties) % 2 == 0).astype(float)
    half = hessian(first)
    assert min(np.abs(half - exact).max(), np.abs(half - full).max()) > 1e6 * scale
    assert np.allclose(half + hessian(1.0 - first) - exact, full, rtol=0, atol=scale)
    assert np.allclose(hessian(0.5), 0.5 * (exact + full), rtol=0, atol=scale)
    assert np.array_equal(hessian(0.3), hessian(np.full(ties, 0.3)))
