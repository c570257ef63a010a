"""The one Huber stick-slip law (docs/model.md sections 4, 10.8, 11.4; `dynfab.model.terms.huber`)
and the three slips that use it: the paper yarn's 1-D slip, the planar fabric's 2-D slip, the
spatial fabric's three-component slip must give one energy, one force and one branch for one
slip size."""

import numpy as np
import pytest

from dynfab.model.fabric import friction as planar
from dynfab.model.terms import friction as paper
from dynfab.model.terms import huber
from dynfab.model.terms import spatial

LIMIT, STICK = 0.02, 400.0  # F_T [N], k_t [N/m]: the boundary is at |S| = 5e-5 m
BOUNDARY = LIMIT / STICK


def _slips(size):
    """One slip of size `size` [m] in each dimension, along a direction that is not an axis."""
    d2 = np.array([0.6, -0.8])
    d3 = np.array([2.0, -1.0, 2.0]) / 3.0
    return -size, size * d2, size * d3


@pytest.mark.parametrize("size", [0.0, 0.3 * BOUNDARY, BOUNDARY, 1.7 * BOUNDARY, 40 * BOUNDARY])
@pytest.mark.parametrize("limit", [LIMIT, 0.0])
def test_the_three_slips_share_one_energy_force_and_branch(size, limit):
    s1, s2, s3 = _slips(size)
    energy = huber.energy(size, limit, STICK)
    assert paper.huber(s1, limit, STICK) == energy
    assert planar.huber(s2[0], s2[1], limit, STICK) == pytest.approx(energy, rel=1e-15)
    assert spatial.huber3(s3, limit, STICK) == pytest.approx(energy, rel=1e-15)

    g = huber.force_per_slip(size, limit, STICK)
    assert paper.huber_derivative(s1, limit, STICK) == g * s1
    np.testing.assert_allclose(planar.huber_gradient(s2[0], s2[1], limit, STICK), g * s2,
                               rtol=1e-15, atol=0.0)
    out = np.empty(3)
    spatial.huber3_gradient(s3, limit, STICK, out)
    np.testing.assert_allclose(out, g * s3, rtol=1e-15, atol=0.0)

    slides = huber.slides(size, limit, STICK)
    assert paper.is_sliding(s1, limit, STICK) == slides
    assert planar.is_sliding(s2[0], s2[1], limit, STICK) == slides


def test_the_boundary_takes_the_softer_sliding_branch_and_is_continuous():
    """At k_t |S| = F_T the energy and the force have one value from both sides (|S| F_T and
    F_T); the curvature is the sliding branch's, the softer (docs/model.md section 6)."""
    assert huber.slides(BOUNDARY, LIMIT, STICK)
    assert not huber.slides(np.nextafter(BOUNDARY, 0.0), LIMIT, STICK)
    below, above = np.nextafter(BOUNDARY, 0.0), np.nextafter(BOUNDARY, 1.0)
    for f in (huber.energy, lambda n, F, k: huber.force_per_slip(n, F, k) * n):
        assert f(below, LIMIT, STICK) == pytest.approx(f(above, LIMIT, STICK), rel=1e-12)
    h = np.empty((3, 3))
    spatial.huber3_hessian(_slips(BOUNDARY)[2], LIMIT, STICK, False, h)
    assert np.trace(h) == pytest.approx(2 * LIMIT / BOUNDARY, rel=1e-12)  # (F_T/n)(I - e e^T)


@pytest.mark.parametrize("size", [0.3 * BOUNDARY, 1.7 * BOUNDARY, 40 * BOUNDARY])
def test_the_force_is_the_energy_derivative(size):
    """Central differences of H(n) against g n: error O(h^2) on a smooth branch, so h = 1e-4 n
    leaves ~1e-8 relative (and the rounding of H / h ~ 1e-16 / 1e-4)."""
    h = 1e-4 * size
    numeric = (huber.energy(size + h, LIMIT, STICK) - huber.energy(size - h, LIMIT, STICK)) / (2 * h)
    assert numeric == pytest.approx(huber.force_per_slip(size, LIMIT, STICK) * size, rel=1e-7)


def test_the_return_map_moves_only_past_the_boundary_and_an_open_anchor_follows():
    assert not huber.moves(BOUNDARY, LIMIT, STICK)
    assert huber.moves(np.nextafter(BOUNDARY, 1.0), LIMIT, STICK)
    assert not huber.moves(0.0, 0.0, STICK)
    assert huber.moves(1e-12, 0.0, STICK)
    pos = np.array([[3e-4, 0.0]])
    anchors, sliding, force = np.zeros(1), np.zeros(1, bool), np.zeros(1)
    lost = paper.return_map(pos, np.array([0]), anchors, np.array([-0.01]), STICK, sliding, force)
    assert anchors[0] == pos[0, 0] and force[0] == 0.0 and lost == 0.0
