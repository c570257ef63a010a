"""The shear force of a specimen from its clamp force, as Cao et al. (Composites A 39 (2008)
1037-1053) normalise it (docs/model.md section 11.7).

Picture frame (side L, frame angle theta, fabric side L_f): the shear force along a bar
F_s = F / (2 cos theta) (eq. 3) and its normalisation F_s L / L_f^2 [N/m] (eq. 10).

Bias extension (W x H, H >= 2 W): Harrison et al.'s normalisation (Composites A 35 (2004)
915-931), which Cao et al. use, follows from the power balance of the three zones under the
kinematics of eq. 13. With zone A of area W (H - 3 W / 2) shearing at gamma, the four zones
B of area W^2 at gamma / 2, zone C not at all, a shear power per unit area T(gamma) gamma-dot
and, as for the frame, T = F_sh cos gamma (eq. 3 and 10 make F_sh = T / cos gamma there:
F d-dot = T L^2 gamma-dot with d-dot = L sin theta gamma-dot):

    F d-dot = W (H - 3W/2) T(gamma) gamma-dot + W^2 T(gamma / 2) gamma-dot / 2,
    d-dot = (H - W) / 2 (cos(gamma/2) - sin(gamma/2)) gamma-dot          (eq. 13 differentiated)

so that

    F_sh(gamma) = [(H/W - 1) F (cos(gamma/2) - sin(gamma/2)) - W F_sh(gamma/2) cos(gamma/2)]
                  / ((2 H - 3 W) cos gamma).                                         (11.3)

F_sh(gamma/2) is the same normalisation at half the angle: the recursion runs down the
measured curve F(gamma), read by linear interpolation between the path's points, until the
angle is below `SMALLEST_ANGLE`, where F_sh = F / (2 W) (11.3 at gamma = 0). The curve's value
at d = 0 is its limit d -> 0+, extrapolated linearly from its first two loaded points
(`_start_force`), not a step-0 point's force: a specimen's clamp reaction at d = 0 (the woven
state's, docs/model.md section 10) is not shear resistance, and where friction yields at once
the curve jumps above it (as on the Cao 115 x 230 mm specimen: docs/results.md, "The
normalised shear force's start"). Read from d = 0, that jump ran up the recursion,
whose factor on F_sh(gamma/2), -W cos(gamma/2) / ((2 H - 3 W) cos gamma), is -1 at
H = 2 W: undamped, the normalised force alternated from step to step. The path must be
in increasing d (a curve, not a cycle).
"""

from __future__ import annotations

import math

import numpy as np

from dynfab.model.specimen_layout import frame_angle, nominal_shear_angle

SMALLEST_ANGLE = 1e-9
"""Angle [rad] below which the recursion (11.3) stops at its gamma -> 0 limit F / (2 W)."""


def frame_shear_force(force: float, side: float, d: float) -> float:
    """F_s = F / (2 cos theta) [N] (Cao et al. eq. 3), theta the frame angle at d."""
    return force / (2.0 * math.cos(frame_angle(side, d)))


def frame_normalised_shear_force(force: float, side: float, fabric_side: float,
                                 d: float) -> float:
    """F_s L / L_f^2 [N/m] (Cao et al. eq. 10)."""
    return frame_shear_force(force, side, d) * side / fabric_side ** 2


def bias_normalised_shear_force(d, force, width: float, height: float) -> np.ndarray:
    """Harrison's F_sh [N/m] (11.3) at every point of a bias-extension path: d (k,) [m] the
    clamp displacements in increasing order, force (k,) [N] the clamp force there."""
    d = np.asarray(d, float)
    force = np.asarray(force, float)
    if d.size and np.any(np.diff(d) <= 0.0):
        raise ValueError("the bias normalisation needs the path in increasing d")
    angles = np.array([nominal_shear_angle("bias_extension", x, width=width, height=height)
                       for x in d])
    loaded = angles > 0.0
    curve_angles = np.concatenate([[0.0], angles[loaded]])
    curve_forces = np.concatenate([[_start_force(angles[loaded], force[loaded])],
                                   force[loaded]])

    def force_at(gamma: float) -> float:
        return float(np.interp(gamma, curve_angles, curve_forces))

    return np.array([_harrison(gamma, force_at, width, height) for gamma in angles])


def _start_force(angles: np.ndarray, force: np.ndarray) -> float:
    """F at gamma -> 0+ [N]: the line through the first two loaded points at gamma = 0 (0
    where it crosses zero before: a curve that rises from the origin), the one point's force
    where there is one, 0 without (module docstring)."""
    if angles.size < 2:
        return float(force[0]) if angles.size else 0.0
    slope = (force[1] - force[0]) / (angles[1] - angles[0])
    start = float(force[0] - slope * angles[0])
    return start if start * force[0] > 0.0 else 0.0


def _harrison(gamma: float, force_at, width: float, height: float) -> float:
    """(11.3) at gamma, F(angle) = force_at(angle), unrolled from the smallest angle up."""
    halvings = [gamma]
    while halvings[-1] > SMALLEST_ANGLE:
        halvings.append(0.5 * halvings[-1])
    value = force_at(halvings[-1]) / (2.0 * width)
    for angle in reversed(halvings[:-1]):
        half = 0.5 * angle
        value = (((height / width - 1.0) * force_at(angle) * (math.cos(half) - math.sin(half))
                  - width * value * math.cos(half))
                 / ((2.0 * height - 3.0 * width) * math.cos(angle)))
    return value
