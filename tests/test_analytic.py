"""The model against closed forms (docs/model.md sections 2, 6 and 9).

- A straight yarn under an end force: springs in series, geometrically exact.
- Timoshenko's beam under tension and a lateral point force (paper eq. 1): the
  model's linearised lateral response converges to it at second order in the
  mesh size, on the stretched beam (docs/model.md section 9: EI (1 + e) over L (1 + e)).
"""

import math

import numpy as np
import pytest

from dynfab.model import assembly
from dynfab.linalg.banded import constrain, lu_factor, lu_solve, zeros_band
from dynfab.model.yarn import initial_state
from dynfab.model.builders import build_model
from dynfab.solvers.static import StaticSolver

EPS = np.finfo(float).eps
L, EA, EI = 0.1, 13.72, 1.47e-7
"""Paper warp values (docs/model.md section 7) [m, N, N m^2]."""
PCR = math.pi ** 2 * EI / L ** 2
"""Euler load of the unstretched pinned yarn [N], 1.45e-4 N."""
TOLERANCE = 1e-11
"""The static solver's residual [N] (docs/model.md section 6; the scene default)."""


def rod_scene(make_scene, segments, control, value, EA=EA):
    """A straight plain rod (crossings = 0, amplitude 0): node 0 pinned, z_N fixed."""
    return make_scene(
        geometry=dict(length=L, segments=segments, crossings=0, amplitude=0.0),
        warp=dict(EA=EA, EI=EI, kawabata_C=0.2e-3, kawabata_K=0.2),
        load=dict(control=control, values=[value]),
        static=dict(tolerance=TOLERANCE),
    )


def solve(model, value):
    """The relaxed record of one static load step from the as-woven state."""
    _, record = StaticSolver(model).step(initial_state(model), value)
    assert record["residual"][0] <= TOLERANCE
    return record


# --------------------------------------------------------------------------
# Springs in series.


@pytest.mark.parametrize("P", (0.1, 5.0, -0.5 * PCR))
def test_straight_yarn_stretches_as_springs_in_series(make_scene, P):
    # Each spring k = EA/l0 carries P: k (l - l0) = P, l = l0 (1 + P/EA) exactly (the
    # stretch is geometrically exact), so x_i = x0_i (1 + P/EA) and u = P L / EA, at
    # any strain (5 N: 36 %) and in compression below buckling (z stays exactly 0: a
    # straight chain has no lateral force). Tolerance: a residual r on the free x dofs
    # moves x_i by (K^-1 r)_i, |K^-1|_inf = sum_j min(i, j)/k <= N(N+1)/(2k) for the
    # chain pinned at node 0; plus the rounding of coordinates ~ L: 8 eps L.
    N = 10
    model = build_model(rod_scene(make_scene, N, "force", P))
    record = solve(model, P)
    k = EA / (L / N)
    tolerance = N * (N + 1) / (2 * k) * TOLERANCE + 8 * EPS * L
    assert abs(record["end_displacement"][0] - P * L / EA) <= tolerance
    positions = record["positions"][0]
    x0 = np.arange(N + 1) * L / N
    assert np.abs(positions[:, 0] - x0 * (1 + P / EA)).max() <= tolerance
    assert not positions[:, 1].any()


@pytest.mark.parametrize("u", (1e-4, 0.02))
def test_straight_yarn_reaction_under_displacement_control(make_scene, u):
    # Displacement control: x_N = L + u, reaction P = EA u / L (the mean tension of the
    # series). Each free node's residual is the difference of its two tensions, so the
    # end tension differs from the mean by <= N r; plus rounding of k (l - l0): 8 k eps L.
    N = 10
    model = build_model(rod_scene(make_scene, N, "displacement", u))
    record = solve(model, u)
    k = EA / (L / N)
    assert record["end_displacement"][0] == pytest.approx(u, rel=0, abs=4 * EPS * L)
    assert abs(record["end_force"][0] - EA * u / L) <= N * TOLERANCE + 8 * k * EPS * L


# --------------------------------------------------------------------------
# Timoshenko's beam (paper eq. 1).


def timoshenko_series(x, c, length, ei, P, terms=20000):
    """Eq. 1 per unit F: w(x) = 2 L^3/(pi^4 EI) sum_k sin(k pi c/L) sin(k pi x/L) / (k^2 (k^2 + P/Pcr))."""
    k = np.arange(1, terms + 1)[:, None]
    pcr = math.pi ** 2 * ei / length ** 2
    x = np.asarray(x, float)[None, :]
    return 2 * length ** 3 / (math.pi ** 4 * ei) * np.sum(
        np.sin(k * math.pi * c / length) * np.sin(k * math.pi * x / length)
        / (k ** 2 * (k ** 2 + P / pcr)), axis=0)


def timoshenko_closed_form(x, c, length, ei, P):
    """The sum of eq. 1 per unit F, in closed form (P > 0), mu = sqrt(P/EI):

        w(x) = [(L-c) x/L - sinh(mu (L-c)) sinh(mu x) / (mu sinh(mu L))] / P,   x <= c,

    and the mirror image (x -> L-x, c -> L-c) for x >= c. Derivation: EI w'''' - P w''
    = delta(x - c), w = w'' = 0 at both ends. With phi = EI w'' - P w, phi'' = delta and
    phi = 0 at the ends: phi is the string's Green's function -(L-c) x/L (x <= c). Then
    w'' - mu^2 w = phi/EI has the particular solution -phi/P, and the sinh terms, zero at
    the ends, make w, w', w'' continuous at c, with the jump [w'''] = 1/EI. Its sine
    coefficients are eq. 1's.
    """
    mu = math.sqrt(P / ei)
    x = np.asarray(x, float)
    left = (length - c) * x / length - np.sinh(mu * (length - c)) * np.sinh(mu * x) \
        / (mu * np.sinh(mu * length))
    right = c * (length - x) / length - np.sinh(mu * c) * np.sinh(mu * (length - x)) \
        / (mu * np.sinh(mu * length))
    return np.where(x <= c, left, right) / P


def linearised_deflection(model, P, node):
    """dw/dF (N+1,) [m/N] of the yarn stretched straight by P, under a lateral force at `node`.

    The model has no lateral point force: solve the stretched state under P with the
    static solver, then K w = e_z(node) with the model's banded Hessian K at that
    state, pinned (node 0) and z_N fixed: exactly the linearised response.
    """
    positions = solve(model, P)["positions"][0]
    n = positions.size
    band = zeros_band(n)
    assembly.hessian(positions, model.yarns[0], np.zeros(0), np.zeros(0), np.zeros(0), False, band)
    rhs = np.zeros(n)
    rhs[2 * node + 1] = 1.0
    constrain(band, rhs, model.fixed_dofs())
    assert lu_factor(band) == -1  # stable under tension: positive definite
    lu_solve(band, rhs)
    return rhs[1::2]


def test_timoshenko_closed_form_is_the_series():
    # The closed form above against eq. 1 summed to K = 20000 terms: the tail is at most
    # 2 L^3/(pi^4 EI) sum_{k>K} 1/k^4 <= 2 L^3/(pi^4 EI) / (3 K^3); rounding of 20000 terms
    # of size <= the first ~ 1e-12 of the result.
    x = np.linspace(0, L, 41)
    for c in (L / 2, L / 4, 0.37 * L):
        for ratio in (0.5, 5.0, 50.0):
            P = ratio * PCR
            series = timoshenko_series(x, c, L, EI, P)
            tail = 2 * L ** 3 / (math.pi ** 4 * EI) / (3 * 20000 ** 3)
            closed = timoshenko_closed_form(x, c, L, EI, P)
            assert np.abs(series - closed).max() <= tail + 1e-12 * np.abs(closed).max()


MESHES = (16, 32, 64, 128)


@pytest.mark.parametrize("load_point", (0.5, 0.25))
@pytest.mark.parametrize("ea, ratio", [
    (EA, 5.0),            # the paper's yarn: strain P/EA = 5e-5
    (EA, 1.0),
    (100 * 5.0 * PCR, 5.0),   # a soft yarn, strain 1e-2: the stretched EI and L matter
])
def test_timoshenko_beam_converges_at_second_order(make_scene, ea, ratio, load_point):
    # Linearised deflection per unit lateral force at c (a node on every mesh) against
    # eq. 1 on the stretched beam: Ls = L (1 + e), EIs = EI (1 + e), e = P/EA, x and c
    # scaled by (1 + e) (docs/model.md section 9), P/Pcr of order 1-10 so the tension matters.
    # The model is then the central-difference discretisation of EIs w'''' - P w'' = F delta
    # (bending (EI/l0)/l^2 = EIs/l^3, string P/l): second order in l = Ls/N. The error at
    # the load point and the max error over nodes, relative to the peak, on N = 16..128;
    # order from the log-log fit. Solver residual (1e-11 N) and rounding enter at ~1e-12,
    # far below the smallest error (~1e-4).
    P = ratio * PCR
    e = P / ea
    Ls, EIs = L * (1 + e), EI * (1 + e)
    errors = []
    for N in MESHES:
        model = build_model(rod_scene(make_scene, N, "force", P, EA=ea))
        node = round(load_point * N)
        w = linearised_deflection(model, P, node)
        x = np.arange(N + 1) * (Ls / N)
        exact = timoshenko_closed_form(x, x[node], Ls, EIs, P)
        errors.append((abs(w[node] - exact[node]) / exact[node],
                       np.abs(w - exact).max() / exact.max()))
    errors = np.array(errors)
    h = Ls / np.array(MESHES)
    for column in range(2):
        order = np.polyfit(np.log(h), np.log(errors[:, column]), 1)[0]
        assert 1.8 < order < 2.2, (order, errors[:, column])
