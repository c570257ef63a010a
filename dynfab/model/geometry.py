"""As-woven geometry of a warp yarn and its crossings (docs/model.md sections 1 and 3).

Plain numpy: these run once per scene, not in a solver loop.
"""

from __future__ import annotations

import math

import numpy as np


def as_woven_positions(length: float, segments: int, crossings: int, amplitude: float,
                       phase: float) -> np.ndarray:
    """Node positions (segments+1, 2) [m] of the as-woven warp (paper eq. 18, one mode).

    x0_i = i L / N,  z0_i = s_k A_wa sin(N_we pi x0_i / L).  A plain rod
    (crossings = 0) is straight.
    """
    x = np.arange(segments + 1) * (length / segments)
    z = phase * amplitude * np.sin(crossings * math.pi * x / length)  # 0 when crossings = 0
    positions = np.stack([x, z], axis=1)
    positions[-1, 0] = length  # exactly L, whatever the rounding of N * (L / N)
    return positions


def crossing_nodes(segments: int, crossings: int) -> np.ndarray:
    """Node index n_j = (2j - 1) N / (2 N_we) of crossing j = 1..N_we (paper eq. 16)."""
    j = np.arange(1, crossings + 1)
    return ((2 * j - 1) * segments) // (2 * crossings)


def crossing_sides(crossings: int, phase: float) -> np.ndarray:
    """Side s_j = s_k (-1)^(j+1) of the weft the warp lies on at crossing j (+1: above)."""
    j = np.arange(1, crossings + 1)
    return phase * np.where(j % 2 == 1, 1.0, -1.0)


def segment_lengths(positions: np.ndarray) -> np.ndarray:
    """Lengths |r_{i+1} - r_i| (N,) [m] of the segments of a chain (N+1, 2)."""
    return np.hypot(*np.diff(positions, axis=0).T)


def voronoi_lengths(rest_length: np.ndarray) -> np.ndarray:
    """lbar_i = (l0_{i-1} + l0_i)/2 at every node (N+1,) [m]; end nodes get half a segment."""
    lbar = np.empty(rest_length.size + 1)
    lbar[0], lbar[-1] = rest_length[0] / 2, rest_length[-1] / 2
    lbar[1:-1] = 0.5 * (rest_length[:-1] + rest_length[1:])
    return lbar


def turning_angles(positions: np.ndarray) -> np.ndarray:
    """Signed turning angle phi_i (N+1,) [rad] between segments i-1 and i; 0 at the ends.

    phi_i = atan2(e_{i-1} x e_i, e_{i-1} . e_i)  (docs/model.md section 2).
    """
    e = np.diff(positions, axis=0)
    a, b = e[:-1], e[1:]
    phi = np.zeros(positions.shape[0])
    phi[1:-1] = np.arctan2(a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0], np.sum(a * b, axis=1))
    return phi


def half_wave_arc_length(projected: float, amplitude: float) -> float:
    """Arc length Lc [m] of one half-wave of z = A sin(pi x / p), 0 <= x <= p
    (docs/model.md section 3).

    Lc = int_0^p sqrt(1 + (A pi / p)^2 cos^2(pi x / p)) dx.  The integrand is
    smooth and p-periodic, so the trapezoid rule over one period converges
    geometrically; 256 points reach machine precision for any slope A pi / p
    below about 10 (checked against the complete elliptic integral in the tests).
    """
    slope = amplitude * math.pi / projected
    n = 256 if slope < 10 else 4096
    t = np.arange(n) / n
    return projected * float(np.mean(np.sqrt(1.0 + (slope * np.cos(math.pi * t)) ** 2)))


def weft_stiffness(EI_we: float, length_we: float, count_we: int, tension_we: float) -> float:
    """k_we [N/m] of the weft at a crossing (paper eq. 4).

    k_we = (pi^4 / 2) EI_we / Lp_we^3 (1 + alpha_we / N_wa^2),
    Lp_we = L_we / N_wa, alpha_we = P_we / Pcr_we, Pcr_we = pi^2 EI_we / L_we^2.
    """
    half_period = length_we / count_we
    alpha = tension_we / (math.pi ** 2 * EI_we / length_we ** 2)
    return (math.pi ** 4 / 2) * EI_we / half_period ** 3 * (1.0 + alpha / count_we ** 2)


def tensioned_beam_stiffness(tension: float, EA: float, EI: float, length: float,
                             count: int) -> float:
    """k [N/m] of a straight weft under tension T pushed by alternating point forces at its
    `count` crossings (docs/model.md section 10): each half-span Lp/2 a guided-pinned
    beam-column, k = 2 T lam / (lam Lp/2 - tanh(lam Lp/2)), lam = sqrt(T / EI),
    Lp = length / count, Lp and EI at the stretched length (factor 1 + T/EA); 48 EI/Lp^3 at
    T = 0. Below lam Lp/2 = 1e-2 the series x - tanh x = x^3/3 - 2 x^5/15 + 17 x^7/315
    replaces the difference, which loses precision there (exact to x^6 ~ 1e-12).
    Paper eq. 4 (`weft_stiffness`) is its one-sine-mode value."""
    stretch = 1.0 + tension / EA
    lp, ei = length / count * stretch, EI * stretch
    x = math.sqrt(tension / ei) * lp / 2
    if x < 1e-2:
        return 16 * ei / lp ** 3 / (1 / 3 - 2 * x * x / 15 + 17 * x ** 4 / 315)
    return 2 * tension * (2 * x / lp) / (x - math.tanh(x))


def crimp(positions: np.ndarray) -> np.ndarray:
    """(arc length - projected length) / projected length [-] of each yarn (yarns, N+1, 2)."""
    segments = np.diff(positions, axis=-2)
    arc = np.hypot(segments[..., 0], segments[..., 1]).sum(axis=-1)
    projected = positions[..., -1, 0] - positions[..., 0, 0]
    return (arc - projected) / projected
