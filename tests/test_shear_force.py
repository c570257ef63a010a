"""Cao et al.'s normalised shear forces (dynfab.model.shear_force, docs/model.md section 11.7)
against the power balance they come from.

A fabric whose shear power per unit area is T(gamma) gamma-dot (here T = a gamma + b gamma^3,
made up) takes, on a picture frame of side L, the corner force F = T L^2 dgamma/dd, and on a
bias specimen F = (A_A T(gamma) + A_B T(gamma / 2) / 2) dgamma/dd with the zone areas
A_A = W (H - 3 W / 2), A_B = W^2, gamma(d) by eq. 13 (the derivative taken by central
differences, so that the test shares no trigonometry with the code). The normalisation must
give back F_sh = T / cos(gamma): exactly for the frame (to rounding), and for the bias specimen
up to the linear interpolation of F between the path's points at gamma / 2, an error of second
order in the spacing (checked: halving it quarters the error).
"""

from __future__ import annotations

import numpy as np
import pytest

from dynfab.model.shear_force import bias_normalised_shear_force, frame_normalised_shear_force
from dynfab.model.specimen_layout import frame_angle, nominal_shear_angle


def torque(gamma):
    """T(gamma) [N/m], the made-up fabric's shear power per unit area and shear rate."""
    return 2.0 * gamma + 15.0 * gamma ** 3


def rate(angle_of_d, d, h=1e-7):
    """dgamma/dd [rad/m] by central differences."""
    return (angle_of_d(d + h) - angle_of_d(d - h)) / (2.0 * h)


def bias_path(width, height, points):
    d = np.linspace(0.0, 0.3 * (height - width), points)
    gamma = lambda x: nominal_shear_angle("bias_extension", x, width=width, height=height)  # noqa: E731
    areas = width * (height - 1.5 * width), width ** 2
    force = np.array([(areas[0] * torque(gamma(x)) + areas[1] * torque(gamma(x) / 2) / 2)
                      * rate(gamma, x) if x > 0 else 0.0 for x in d])
    expected = np.array([torque(gamma(x)) / np.cos(gamma(x)) for x in d])
    return d, force, expected


@pytest.mark.parametrize("width, height", [(0.06, 0.12), (0.115, 0.23), (0.15, 0.45)])
def test_harrison_recovers_the_shear_force_to_second_order(width, height):
    errors = []
    for points in (101, 201):
        d, force, expected = bias_path(width, height, points)
        computed = bias_normalised_shear_force(d[1:], force[1:], width, height)
        errors.append(np.max(np.abs(computed - expected[1:])) / np.max(expected))
    assert errors[1] < 1e-3
    assert 3.0 < errors[0] / errors[1] < 5.0, errors


def test_the_frame_normalisation_is_the_power_balance():
    side = 0.15
    gamma = lambda x: np.pi / 2 - 2 * frame_angle(side, x)  # noqa: E731
    for d in (0.005, 0.02, 0.05):
        force = torque(gamma(d)) * side ** 2 * rate(gamma, d)
        normalised = frame_normalised_shear_force(force, side, side, d)
        assert normalised * np.cos(gamma(d)) == pytest.approx(torque(gamma(d)), rel=1e-7)


def test_the_bias_normalisation_refuses_a_path_that_turns_back():
    with pytest.raises(ValueError, match="increasing d"):
        bias_normalised_shear_force([0.001, 0.002, 0.0015], [1.0, 2.0, 1.5], 0.06, 0.12)


@pytest.mark.parametrize("width, height", [(0.115, 0.23), (0.15, 0.45)])
def test_a_friction_plateau_over_a_reaction_at_d_0_is_normalised_as_its_curve(width, height):
    # A rigid-plastic fabric (T = c as soon as gamma > 0, a friction that yields at once) with
    # a clamp reaction r at d = 0 that is not shear (the woven state's, docs/model.md section
    # 10): F jumps from r at d = 0 to its plateau at d -> 0+. The normalisation reads the
    # curve from its limit d -> 0+ (module docstring), so every loaded step gives back
    # c / cos(gamma) to the interpolation's second order; read from r, the jump would run up
    # the recursion (undamped at H = 2 W).
    c, r = 1.0, 0.1 * width
    gamma = lambda x: nominal_shear_angle("bias_extension", x, width=width, height=height)  # noqa: E731
    areas = width * (height - 1.5 * width), width ** 2
    d = np.linspace(0.0, 0.3 * (height - width), 101)
    force = np.array([(areas[0] * c + areas[1] * c / 2) * rate(gamma, x) if x > 0 else r
                      for x in d])
    computed = bias_normalised_shear_force(d, force, width, height)
    expected = np.array([c / np.cos(gamma(x)) for x in d[1:]])
    assert np.max(np.abs(computed[1:] - expected)) < 1e-3 * c
