"""The sparse Newton's per-crossing secant weights (docs/model.md 11.10,
`dynfab.solvers.newton_sparse.kinked` and `next_secant_weights`): which crossings a step takes
across their Huber kink, from the geometry of the slip's path against the stick disk
|S| <= F_T / k_t, and how the weights follow."""

from __future__ import annotations

import numpy as np
import pytest

from dynfab.solvers.newton_sparse import KINK_TURN, SECANT_FLOOR, SECANT_GROWTH, kinked, \
    next_secant_weights

LIMIT, STICK = 1.0, 1e3  # F_T [N], k_t [N/m]: the stick radius is 1 mm
RADIUS = LIMIT / STICK


def turned_to(degrees: float, length: float = 2 * RADIUS) -> list[float]:
    angle = np.radians(degrees)
    return [length * np.cos(angle), length * np.sin(angle), 0.0]


CASES = [  # (name, S before [m], S after [m], F_T [N], kinked)
    ("sliding, through zero", [2e-3, 0, 0], [-2e-3, 0, 0], LIMIT, True),
    ("sliding, passing 0.5 mm from zero", [2e-3, 5e-4, 0], [-2e-3, 5e-4, 0], LIMIT, True),
    ("sliding, outward", [2e-3, 0, 0], [3e-3, 0, 0], LIMIT, False),
    ("sliding, back to the disk's edge", [2e-3, 0, 0], [1.01e-3, 0, 0], LIMIT, False),
    ("sliding, into the disk", [2e-3, 0, 0], [0.99e-3, 0, 0], LIMIT, True),
    ("sliding, turned 45 degrees", [2e-3, 0, 0], turned_to(45), LIMIT, False),
    ("sliding, turned 70 degrees", [2e-3, 0, 0], turned_to(70), LIMIT, True),
    ("sliding in rotation, reversed", [0, 0, 2e-3], [0, 0, -2e-3], LIMIT, True),
    ("sticking, through zero", [5e-4, 0, 0], [-5e-4, 0, 0], LIMIT, False),
    ("open (F_T = 0)", [2e-3, 0, 0], [-2e-3, 0, 0], 0.0, False),
]


def test_a_step_is_kinked_where_a_sliding_slip_crosses_the_stick_disk_or_turns():
    """Each case's answer is geometry: a sliding slip (|S| above the stick radius) whose
    straight path comes within the radius of zero, or whose direction turns by more than
    acos(KINK_TURN) = 60 degrees; a sticking or open crossing never (its exact block is its
    energy's curvature along the whole step, or zero)."""
    assert np.degrees(np.arccos(KINK_TURN)) == pytest.approx(60.0)
    before = np.array([c[1] for c in CASES], float)
    after = np.array([c[2] for c in CASES], float)
    limit = np.array([c[3] for c in CASES])
    found = kinked(before, after, limit, np.full(len(CASES), STICK))
    for (name, *_, expected), got in zip(CASES, found):
        assert bool(got) == expected, name


def test_kinked_crossings_get_the_secant_and_the_others_return_to_the_exact_hessian():
    weights = np.array([0.0, 0.25, 1.0, 1.5 * SECANT_FLOOR * SECANT_GROWTH, 0.5])
    kinks = np.array([True, False, False, False, True])
    after_short = next_secant_weights(weights, True, kinks)
    assert after_short.tolist() == [1.0, 0.25, 1.0, weights[3], 1.0]
    after_full = next_secant_weights(weights, False, kinks)
    assert after_full.tolist() == [0.0, 0.25 / SECANT_GROWTH, 1.0 / SECANT_GROWTH,
                                   1.5 * SECANT_FLOOR, 0.5]
    below_floor = next_secant_weights(np.array([0.9 * SECANT_FLOOR * SECANT_GROWTH]), False,
                                      np.array([False]))
    assert below_floor.tolist() == [0.0]


def test_a_shortened_step_with_no_kinked_crossing_raises_every_weight():
    """The line search cut the step but no crossing's slip explains it (a contact or bending
    nonlinearity): every crossing's secant weight grows, as the one weight for all did."""
    weights = np.array([0.0, 0.1, 0.5])
    got = next_secant_weights(weights, True, np.zeros(3, bool))
    assert got.tolist() == [1.0, 0.1 * SECANT_GROWTH, 1.0]
