"""Element energies of the spatial fabric (dynfab.model.terms.spatial, docs/model.md section 11):
each gradient and Hessian against central finite differences, second order shown; stencils with
a repeated node; invariance under rigid in-plane motions; the vertical-plane reduction to the
planar bending; the friction return map; analytic values.

Finite-difference tolerances (one rule, stated once here; see `fd_tolerance`):

- A central difference of f with step h errs by h^2/6 |f'''| (truncation) plus the rounding
  of the two evaluations divided by 2h. Steps are taken "as rounded" (the divisor is
  (x + h) - (x - h) in floating point), so the rounding of x + h does not count.
- Truncation: every term here varies over a length ell (the shortest segment or chord, or
  the slip |S| of a sliding crossing), so |f'''| <= C |f'| / ell^2 with C of order 1; the
  estimate is h^2/6 max|f'| / ell^2.
- Rounding: f is computed from coordinates of size |X_i| (each rounded to eps |X_i|) and
  from angles and lengths within a stencil of size ell_max, so one evaluation errs by about
  eps (|f| + sum_i |f'_i| (|X_i| + ell_max)); divided by h.
- h = 2e-9 m, near the optimum (eps r ell^2)^(1/3) for r = 3e-3 m, ell = 1e-4 m. Asserted with
  a factor 10 over the sum of the two estimates (C, sums of roundings); they come to about
  1e-9 of the largest entry, where a wrong sign, factor or missing term is 1e-3 to 1.
- Second order: at h = 4e-6 and 2e-6 m the truncation is 1e-7 to 1e-5 of the entries and the
  rounding 1e-12, so the error of the difference falls by 4 (to within the next order,
  (h / ell)^2 < 1e-3) when h halves; a wrong derivative leaves an error that does not fall.
"""

import math

import numpy as np
import pytest

from dynfab.model.terms import bending, spatial
from dynfab.model.terms.contact import CLOSED, NATURAL, OPEN

EPS = np.finfo(float).eps
L = 1e-3
"""The stencil scale: segment length [m]."""
H_FD = 2e-9
"""The finite-difference step [m] (module docstring)."""
H_ORDER = (4e-6, 2e-6)
"""The two steps [m] of the second-order check."""

# Parameters of the right size for a fabric with 1 mm segments.
EA = 2.0e4                  # [N]
K_STRETCH = EA / L          # [N/m]
KB, KL = 1e-2, 2e-2         # EI / lbar, EI_lateral / lbar [N m]
RHO = 1e-3                  # torsion radius [m]
STICK, LIMIT = 1e3, 0.05    # k_t [N/m], F_T [N]: slip at the limit F_T / k_t = 5e-5 m
SHEAR_K = 5e-3              # [N m/rad]
K_LATERAL = 1e4             # [N/m]
WIDTH = 0.8 * L             # [m]
COMPACTION = (1e-5, 0.4 * L, 0.45 * L)
"""Gutowski's compaction (A [N], s_a, s_core [m]): at d = 0.5 L a force of 0.014 N."""


# --- Finite differences -------------------------------------------------------------------


def fd_derivative(func, X, h):
    """Central differences of func(X) (scalar or array) w.r.t. every entry of X, stacked on the
    last axis: (X.size,) for a scalar, (n, X.size) for an (n,) array, and so on."""
    columns = []
    for i in range(X.size):
        Xp, Xm = X.copy(), X.copy()
        Xp.flat[i] += h
        Xm.flat[i] -= h
        step = Xp.flat[i] - Xm.flat[i]
        columns.append((np.asarray(func(Xp)) - np.asarray(func(Xm))) / step)
    return np.stack(columns, axis=-1)


def fd_tolerance(f, df, X, h, ell):
    """10 x (truncation + rounding) of a central difference of f (value(s) f, derivative df
    over X) with step h, for a term varying over the length ell (module docstring)."""
    f, df = np.atleast_1d(np.asarray(f, float)), np.atleast_2d(df)
    size = np.ptp(X.reshape(-1, 3), axis=0).max()
    truncation = h * h / 6.0 * np.abs(df).max() / ell ** 2
    rounding = EPS * (np.abs(f).max()
                      + (np.abs(df) * (np.abs(X.ravel()) + size)).sum(axis=-1).max()) / h
    return 10.0 * (truncation + rounding)


def check_fd(func, derivative, value, X, ell, h=H_FD):
    """Assert `derivative` (of func at X, whose value is `value`) against central differences."""
    fd = fd_derivative(func, X, h)
    tol = fd_tolerance(value, derivative, X, h, ell)
    error = np.abs(fd - derivative).max()
    assert error <= tol, (error, tol, np.abs(derivative).max())


def fd_error(func, derivative, X, h):
    return np.linalg.norm(fd_derivative(func, X, h) - derivative)


# --- Stencils -----------------------------------------------------------------------------


def segment(length, psi, theta):
    """A vector [m] of the given length, in-plane direction psi and elevation theta."""
    return length * np.array([math.cos(theta) * math.cos(psi), math.cos(theta) * math.sin(psi),
                              math.sin(theta)])


def stretch_stencil(rng):
    """(X (2, 3), l0): a segment 5 % longer or shorter than l0 = L, any direction."""
    e = segment(L * (1.0 + rng.choice([-0.05, 0.05])), rng.uniform(-np.pi, np.pi),
                rng.uniform(-1.0, 1.0))
    x0 = rng.uniform(-L, L, 3)
    return np.ascontiguousarray([x0, x0 + e]), L


def bend_stencil(rng):
    """X (3, 3): segments of 0.8 to 1.2 L at elevations within 0.4 rad, turning in plane by up
    to 0.6 rad; the shortest in-plane length is >= 0.7 L."""
    psi = rng.uniform(-np.pi, np.pi)
    e1 = segment(rng.uniform(0.8, 1.2) * L, psi, rng.uniform(-0.4, 0.4))
    e2 = segment(rng.uniform(0.8, 1.2) * L, psi + rng.uniform(-0.6, 0.6), rng.uniform(-0.4, 0.4))
    x = rng.uniform(-L, L, 3)
    return np.ascontiguousarray([x - e1, x, x + e2])


def crossing_stencil(rng):
    """X (6, 3): a warp node a with neighbours about L away along alpha, a weft node b within
    0.3 L of a in plane (0.2 L above it) with neighbours along alpha + pi/2 +- 0.3 (so phi is
    far from the cut at +-pi); chords >= 1.4 L."""
    alpha = rng.uniform(-np.pi, np.pi)
    beta = alpha + np.pi / 2 + rng.uniform(-0.3, 0.3)
    a = rng.uniform(-L, L, 3)
    b = a + np.array([*rng.uniform(-0.3 * L, 0.3 * L, 2), 0.2 * L])

    def chain(x, angle):
        return [x - segment(rng.uniform(0.8, 1.2) * L, angle + rng.uniform(-0.1, 0.1),
                            rng.uniform(-0.2, 0.2)),
                x,
                x + segment(rng.uniform(0.8, 1.2) * L, angle + rng.uniform(-0.1, 0.1),
                            rng.uniform(-0.2, 0.2))]
    return np.ascontiguousarray(chain(a, alpha) + chain(b, beta))


def anchor_for(X, slip, rho=RHO):
    """The anchor (3,) that makes S = `slip` (3,) [m] at X."""
    q = np.empty(3)
    spatial.crossing_coordinates(X, q)
    return np.array([q[0] - slip[0], q[1] - slip[1], q[2] - slip[2] / rho])


def slip_of_size(rng, size):
    """A slip S (3,) [m] of norm `size` in a random direction."""
    v = rng.normal(size=3)
    return size * v / np.linalg.norm(v)


def lateral_stencil(rng, distance, sign):
    """X (4, 3) = (A_prev, A_next, A, B): chord of 1.6 to 2.4 L along a random direction, B at
    signed distance `distance` from the line through A (on the side `sign`), 0.2 L above it."""
    gamma = rng.uniform(-np.pi, np.pi)
    t = np.array([math.cos(gamma), math.sin(gamma), 0.0])
    nrm = np.array([-t[1], t[0], 0.0])
    A = rng.uniform(-L, L, 3)
    A_prev = A - rng.uniform(0.8, 1.2) * L * t + [0.0, 0.0, 0.1 * L]
    A_next = A + rng.uniform(0.8, 1.2) * L * t - [0.0, 0.0, 0.1 * L]
    B = A + sign * distance * nrm + rng.uniform(-0.5, 0.5) * L * t + [0.0, 0.0, 0.2 * L]
    return np.ascontiguousarray([A_prev, A_next, A, B])


# --- Elements as (energy(X), derivatives(X) -> (E, g, H)) ----------------------------------


def stretch_element(l0):
    def derivatives(X):
        g, H = np.empty(6), np.empty((6, 6))
        return spatial.stretch_derivatives(X, K_STRETCH, l0, g, H), g, H
    return (lambda X: spatial.stretch_energy(X, K_STRETCH, l0)), derivatives


def bend_element(theta0, psi0, kb=KB, kl=KL):
    def derivatives(X):
        g, H = np.empty(9), np.empty((9, 9))
        return spatial.bend_derivatives(X, kb, theta0, kl, psi0, g, H), g, H
    return (lambda X: spatial.bend_energy(X, kb, theta0, kl, psi0)), derivatives


def crossing_element(anchor, limit, shear_k, phi_rest, secant=False):
    def derivatives(X):
        g, H = np.empty(18), np.empty((18, 18))
        E = spatial.crossing_derivatives(X, anchor, RHO, limit, STICK, shear_k, phi_rest,
                                         secant, g, H)
        return E, g, H
    return (lambda X: spatial.crossing_energy(X, anchor, RHO, limit, STICK, shear_k, phi_rest),
            derivatives)


def lateral_element(sign, branch=NATURAL, compaction=(0.0, 0.0, 0.0)):
    def derivatives(X):
        g, H = np.empty(12), np.empty((12, 12))
        E = spatial.lateral_derivatives(X, sign, WIDTH, K_LATERAL, g, H, branch, *compaction)
        return E, g, H
    return ((lambda X: spatial.lateral_energy(X, sign, WIDTH, K_LATERAL, branch, *compaction)),
            derivatives)


# The crossing's friction states: |S| in units of F_T / k_t (kinks >= 0.6 F_T / k_t = 3e-5 m
# from every state, beyond any FD step's effect on S, <= 3 x 4e-6 m).
CROSSING_STATES = {
    "stick": (0.4, LIMIT, SHEAR_K),
    "slide": (2.5, LIMIT, SHEAR_K),
    "slide, no spring": (2.5, LIMIT, 0.0),
    "open": (1.0, 0.0, SHEAR_K),
}


def make_case(name, seed):
    """(X, energy, derivatives, ell [m]) of a named element state."""
    rng = np.random.default_rng(seed)
    if name == "stretch":
        X, l0 = stretch_stencil(rng)
        return (X, *stretch_element(l0), L)
    if name == "bend":
        X = bend_stencil(rng)
        return (X, *bend_element(rng.uniform(-0.2, 0.2), rng.uniform(-0.2, 0.2)), 0.7 * L)
    if name.startswith("crossing"):
        scale, limit, shear_k = CROSSING_STATES[name.split(": ")[1]]
        X = crossing_stencil(rng)
        anchor = anchor_for(X, slip_of_size(rng, scale * LIMIT / STICK))
        q = np.empty(3)
        spatial.crossing_coordinates(X, q)
        # |d| <= 0.4 L and chords >= 1.4 L; a sliding Huber varies over |S|.
        ell = min(0.3 * L, scale * LIMIT / STICK) if limit > 0.0 else 0.3 * L
        return (X, *crossing_element(anchor, limit, shear_k, q[2] + rng.uniform(-0.2, 0.2)), ell)
    if name.startswith("lateral"):
        sign = rng.choice([-1.0, 1.0])
        if name == "lateral: held closed, apart":  # w - d < 0: the static solver's active set
            return (lateral_stencil(rng, 1.2 * L, sign), *lateral_element(sign, CLOSED), L)
        if name.startswith("lateral compaction"):  # Gutowski's law (docs/model.md 11.5)
            distance, branch = {"lateral compaction": (0.5 * L, NATURAL),
                                "lateral compaction: the core": (0.42 * L, NATURAL),
                                "lateral compaction: held closed, apart": (1.2 * L, CLOSED)}[name]
            # FD steps (<= 1.2e-5 m on d) stay clear of the law's kinks at w and s_core; the
            # law varies over v sqrt(s s_a) / 2 ~ 0.03 L (sigma ~ v^-4, v = sqrt(s / s_a) - 1)
            return (lateral_stencil(rng, distance, sign),
                    *lateral_element(sign, branch, COMPACTION), 0.03 * L)
        return (lateral_stencil(rng, 0.5 * L, sign), *lateral_element(sign), L)
    raise KeyError(name)


CASES = ["stretch", "bend", *(f"crossing: {s}" for s in CROSSING_STATES), "lateral",
         "lateral: held closed, apart", "lateral compaction", "lateral compaction: the core",
         "lateral compaction: held closed, apart"]


# --- Building blocks ----------------------------------------------------------------------


def test_wrap_lands_in_the_half_open_interval_by_whole_turns():
    assert spatial.wrap(0.0) == 0.0
    assert spatial.wrap(np.pi) == np.pi
    assert spatial.wrap(-np.pi) == np.pi
    assert spatial.wrap(1.0) == 1.0        # inside: returned unchanged, bit for bit
    for a in (1.5 * np.pi, -1.5 * np.pi, 7.0, -7.0, 100.0, -1e3):
        w = spatial.wrap(a)
        assert -np.pi < w <= np.pi
        turns = (a - w) / (2.0 * np.pi)
        # a - w is a whole number of turns up to the rounding of a (eps |a|).
        assert abs(turns - round(turns)) <= 4.0 * EPS * abs(a)


def test_direction_and_elevation_analytic_values():
    e = np.array([-3.0, 4.0, 12.0]) * 1e-4
    assert spatial.direction(e) == pytest.approx(math.pi - math.atan(4.0 / 3.0), rel=4 * EPS)
    assert spatial.elevation(e) == pytest.approx(math.atan(12.0 / 5.0), rel=4 * EPS)
    g = np.empty(3)
    spatial.direction_gradient(e, g)     # (-e_y, e_x, 0) / r^2, r = 5e-4
    np.testing.assert_allclose(g, [-4e-4 / 25e-8, -3e-4 / 25e-8, 0.0], rtol=4 * EPS)


@pytest.mark.parametrize("block", ["direction", "elevation"])
def test_building_block_derivatives_match_finite_differences(block):
    value = getattr(spatial, block)
    gradient = getattr(spatial, f"{block}_gradient")
    hessian = getattr(spatial, f"{block}_hessian")
    rng = np.random.default_rng(1)
    for _ in range(5):
        e = segment(L * rng.uniform(0.5, 1.5), rng.uniform(-np.pi, np.pi), rng.uniform(-1.0, 1.0))
        if abs(spatial.direction(e)) > 3.0:
            continue                       # keep the FD of psi off its cut at +-pi
        g, H = np.empty(3), np.empty((3, 3))
        gradient(e, g)
        hessian(e, H)

        def grad_of(x):
            out = np.empty(3)
            gradient(x, out)
            return out
        ell = 0.5 * L * math.cos(1.0)       # the shortest |e_xy| drawn
        check_fd(value, g, value(e), e, ell)
        check_fd(grad_of, H, g, e, ell)
        np.testing.assert_array_equal(H, H.T)


def test_huber3_values_and_derivatives():
    S = np.array([3.0, 4.0, 12.0]) * 1e-5          # |S| = 1.3e-4 m
    # Sliding at F_T = 0.05 N, k_t = 1e3 N/m (k_t |S| = 0.13 N > F_T).
    assert spatial.huber3(S, LIMIT, STICK) == pytest.approx(
        LIMIT * 1.3e-4 - LIMIT ** 2 / (2 * STICK), rel=1e-14)
    g = np.empty(3)
    spatial.huber3_gradient(S, LIMIT, STICK, g)
    np.testing.assert_allclose(g, LIMIT * S / 1.3e-4, rtol=1e-14)
    H = np.empty((3, 3))
    spatial.huber3_hessian(S, LIMIT, STICK, True, H)
    np.testing.assert_allclose(H, LIMIT / 1.3e-4 * np.eye(3), rtol=1e-14)
    spatial.huber3_hessian(S, LIMIT, STICK, False, H)
    np.testing.assert_allclose(H @ S, 0.0, atol=1e-14 * LIMIT)      # no stiffness along S
    # Sticking at F_T = 1 N.
    assert spatial.huber3(S, 1.0, STICK) == pytest.approx(0.5 * STICK * 1.69e-8, rel=1e-14)
    spatial.huber3_hessian(S, 1.0, STICK, False, H)
    np.testing.assert_array_equal(H, STICK * np.eye(3))
    # Open: identically zero.
    assert spatial.huber3(S, 0.0, STICK) == 0.0
    spatial.huber3_gradient(S, 0.0, STICK, g)
    spatial.huber3_hessian(S, -1.0, STICK, True, H)
    assert not g.any() and not H.any()


def test_a_secant_weight_blends_the_sliding_curvature_with_its_secant():
    """Newton's blend (dynfab.solvers.newton_sparse): weight w gives (1 - w) d2H + w (F_T / |s|) I
    on a sliding crossing, in the plane (dynfab.model.fabric.friction) and in space; a sticking
    crossing keeps k_t I whatever w."""
    from dynfab.model.fabric import friction as planar
    S = np.array([3.0, 4.0, 12.0]) * 1e-5          # sliding: k_t |S| = 0.13 N > F_T
    exact, secant, blend = np.empty((3, 3)), np.empty((3, 3)), np.empty((3, 3))
    spatial.huber3_hessian(S, LIMIT, STICK, 0.0, exact)
    spatial.huber3_hessian(S, LIMIT, STICK, 1.0, secant)
    spatial.huber3_hessian(S, LIMIT, STICK, 0.25, blend)
    np.testing.assert_allclose(blend, 0.75 * exact + 0.25 * secant, rtol=1e-14,
                               atol=1e-14 * LIMIT / 1.3e-4)
    sx, sy = 2.0 * S[:2]                           # |s| = 1e-4 m: k_t |s| = 0.1 N > F_T
    exact2 = np.array(planar.huber_hessian(sx, sy, LIMIT, STICK, 0.0))
    secant2 = np.array(planar.huber_hessian(sx, sy, LIMIT, STICK, 1.0))
    blend2 = np.array(planar.huber_hessian(sx, sy, LIMIT, STICK, 0.25))
    np.testing.assert_allclose(blend2, 0.75 * exact2 + 0.25 * secant2, rtol=1e-14,
                               atol=1e-14 * LIMIT / 1e-4)
    assert np.array_equal(secant2, [LIMIT / np.hypot(sx, sy), 0.0, LIMIT / np.hypot(sx, sy)])
    spatial.huber3_hessian(S, 1.0, STICK, 0.25, blend)   # sticking at F_T = 1 N
    np.testing.assert_array_equal(blend, STICK * np.eye(3))


@pytest.mark.parametrize("scale", [0.4, 2.5])
def test_huber3_derivatives_match_finite_differences(scale):
    S = slip_of_size(np.random.default_rng(2), scale * LIMIT / STICK)
    g, H = np.empty(3), np.empty((3, 3))
    spatial.huber3_gradient(S, LIMIT, STICK, g)
    spatial.huber3_hessian(S, LIMIT, STICK, False, H)

    def grad_of(s):
        out = np.empty(3)
        spatial.huber3_gradient(s, LIMIT, STICK, out)
        return out
    h = 1e-11          # the optimum for |S| ~ 1e-4 m (module docstring's rule with r = ell = |S|)
    check_fd(lambda s: spatial.huber3(s, LIMIT, STICK), g, spatial.huber3(S, LIMIT, STICK), S,
             ell=np.linalg.norm(S), h=h)
    check_fd(grad_of, H, g, S, ell=np.linalg.norm(S), h=h)


# --- Every element: derivatives against finite differences --------------------------------


@pytest.mark.parametrize("name", CASES)
@pytest.mark.parametrize("seed", [10, 11, 12])
def test_element_derivatives_match_finite_differences(name, seed):
    X, energy, derivatives, ell = make_case(name, seed)
    E, g, H = derivatives(X)
    assert E == energy(X)          # the same operations: a line search sees the same energy
    check_fd(energy, g, E, X, ell)
    check_fd(lambda Y: derivatives(Y)[1], H, g, X, ell)
    np.testing.assert_allclose(H, H.T, rtol=0, atol=1e-13 * np.abs(H).max())


@pytest.mark.parametrize("name", CASES)
def test_element_finite_differences_converge_at_second_order(name):
    X, energy, derivatives, ell = make_case(name, 20)
    E, g, H = derivatives(X)
    for func, derivative in ((energy, g), (lambda Y: derivatives(Y)[1], H)):
        errors = [fd_error(func, derivative, X, h) for h in H_ORDER]
        assert 3.6 < errors[0] / errors[1] < 4.4, errors


def test_crossing_kinematics_derivatives_match_finite_differences():
    for seed in (30, 31, 32):
        X = crossing_stencil(np.random.default_rng(seed))
        q, J, K = np.empty(3), np.empty((3, 18)), np.empty((3, 18, 18))
        spatial.crossing_kinematics(X, q, J, K)
        q_only = np.empty(3)
        spatial.crossing_coordinates(X, q_only)
        np.testing.assert_array_equal(q, q_only)

        def q_of(Y):
            out = np.empty(3)
            spatial.crossing_coordinates(Y, out)
            return out

        def J_of(Y):
            q2, J2, K2 = np.empty(3), np.empty((3, 18)), np.empty((3, 18, 18))
            spatial.crossing_kinematics(Y, q2, J2, K2)
            return J2
        for m in range(3):   # per component: s [m] and phi [rad] have different scales
            check_fd(lambda Y: q_of(Y)[m], J[m], q[m], X, 0.3 * L)
            check_fd(lambda Y: J_of(Y)[m], K[m], J[m], X, 0.3 * L)
        second_order = [fd_error(J_of, K, X, h) for h in H_ORDER]
        assert 3.6 < second_order[0] / second_order[1] < 4.4


def test_crossing_kinematics_analytic_values():
    """Warp along +y (alpha = pi/2), weft at beta0: s = R(-pi/2) d = (d_y, -d_x), phi = beta0 -
    pi/2."""
    l, dx, dy, beta0 = L, 2e-4, -1e-4, 2.5
    a, b = np.array([0.0, 0.0, 0.0]), np.array([dx, dy, 3e-4])
    t = np.array([math.cos(beta0), math.sin(beta0), 0.0])
    X = np.ascontiguousarray([a - [0, l, 0], a, a + [0, l, 0], b - l * t, b, b + l * t])
    q = np.empty(3)
    spatial.crossing_coordinates(X, q)
    np.testing.assert_allclose(q, [dy, -dx, beta0 - np.pi / 2], rtol=1e-14, atol=1e-20)


def test_secant_crossing_hessian_drops_only_the_radial_softening():
    """With `secant`, H differs from the exact one by J^T D (F_T / |S|^3) S S^T D J."""
    rng = np.random.default_rng(40)
    X = crossing_stencil(rng)
    S = slip_of_size(rng, 2.5 * LIMIT / STICK)
    anchor = anchor_for(X, S)
    exact = crossing_element(anchor, LIMIT, SHEAR_K, 1.0)[1](X)[2]
    secant = crossing_element(anchor, LIMIT, SHEAR_K, 1.0, secant=True)[1](X)[2]
    q, J, K = np.empty(3), np.empty((3, 18)), np.empty((3, 18, 18))
    spatial.crossing_kinematics(X, q, J, K)
    DS = np.diag([1.0, 1.0, RHO]) @ spatial.crossing_slip(X, anchor, RHO)
    n = np.linalg.norm(S)
    expected = LIMIT / n ** 3 * np.outer(J.T @ DS, J.T @ DS)
    np.testing.assert_allclose(secant - exact, expected, atol=1e-12 * np.abs(exact).max())


# --- Repeated nodes ------------------------------------------------------------------------


def check_repeated_nodes(X_nodes, slots, energy, derivatives, ell):
    """The slot derivatives summed onto unique nodes are the derivatives of the energy of the
    nodes (X_nodes (n, 3); slots: the node of each stencil slot)."""
    P = np.zeros((3 * len(slots), X_nodes.size))
    for s, node in enumerate(slots):
        P[3 * s:3 * s + 3, 3 * node:3 * node + 3] = np.eye(3)

    def stencil(Y):
        return np.ascontiguousarray(Y[slots])

    def node_gradient(Y):
        return P.T @ derivatives(stencil(Y))[1]
    E, g, H = derivatives(stencil(X_nodes))
    check_fd(lambda Y: energy(stencil(Y)), P.T @ g, E, X_nodes, ell)
    check_fd(node_gradient, P.T @ H @ P, P.T @ g, X_nodes, ell)


@pytest.mark.parametrize("state", list(CROSSING_STATES))
def test_crossing_at_chain_ends_with_repeated_nodes(state):
    """a_prev = a (the warp starts at a) and b_next = b (the weft ends at b)."""
    scale, limit, shear_k = CROSSING_STATES[state]
    rng = np.random.default_rng(50)
    X = crossing_stencil(rng)
    nodes = X[[1, 2, 3, 4]]                       # a, a_next, b_prev, b
    slots = [0, 0, 1, 2, 3, 3]
    anchor = anchor_for(np.ascontiguousarray(nodes[slots]),
                        slip_of_size(rng, scale * LIMIT / STICK))
    energy, derivatives = crossing_element(anchor, limit, shear_k, 1.2)
    check_repeated_nodes(nodes, slots, energy, derivatives, min(0.3 * L, scale * LIMIT / STICK))


def test_lateral_at_a_chain_end_with_a_repeated_node():
    """A_prev = A (yarn k's chain starts at its crossing node)."""
    X = lateral_stencil(np.random.default_rng(51), 0.5 * L, 1.0)
    nodes = X[[2, 1, 3]]                           # A, A_next, B
    check_repeated_nodes(nodes, [0, 1, 0, 2], *lateral_element(1.0), L)
    assert spatial.lateral_energy(np.ascontiguousarray(nodes[[0, 1, 0, 2]]), 1.0, WIDTH,
                                  K_LATERAL) > 0.0


# --- Invariance under rigid in-plane motions -----------------------------------------------


def rigid_motion(X, angle, shift):
    """X rotated by `angle` about e_z and shifted by `shift` (3,)."""
    c, s = math.cos(angle), math.sin(angle)
    R = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    return np.ascontiguousarray(X @ R.T + shift), R


INVARIANCE_CASES = [*CASES, "bend, psi0 = 0"]


@pytest.mark.parametrize("name", INVARIANCE_CASES)
def test_rigid_in_plane_motion_changes_no_energy_and_turns_the_forces(name):
    """E(R X + t) = E(X), g(R X + t) = R g(X) per node, H -> R H R^T; R about e_z, t with a z
    part. Both sides round the same differences of coordinates (|X| <= 3e-3 m, each rounded
    to eps |X|), so they differ by at most eps |X| times the derivative one order up, summed
    over the dofs, and the rounding of the value itself: tolerance 10 x that."""
    rng = np.random.default_rng(60)
    if name == "bend, psi0 = 0":
        X, energy, derivatives, ell = (bend_stencil(rng), *bend_element(0.1, 0.0), 0.7 * L)
    else:
        X, energy, derivatives, ell = make_case(name, 60)
    E, g, H = derivatives(X)
    moved, R = rigid_motion(X, rng.uniform(-np.pi, np.pi), rng.uniform(-L, L, 3))
    E2, g2, H2 = derivatives(moved)
    r = max(np.abs(X).max(), np.abs(moved).max())
    P = np.kron(np.eye(X.shape[0]), R)
    assert abs(E2 - E) <= 10 * EPS * (abs(E) + r * np.abs(g).sum())
    assert abs(energy(moved) - E) <= 10 * EPS * (abs(E) + r * np.abs(g).sum())
    g_rounding = np.abs(g).max() + r * np.abs(H).sum(axis=1).max()
    assert np.abs(g2 - P @ g).max() <= 10 * EPS * g_rounding
    # d2E/dX2 varies over ell: its rounding is eps r |H| / ell per entry, summed over dofs.
    assert np.abs(H2 - P @ H @ P.T).max() <= 10 * EPS * np.abs(H).max() * (1 + X.size * r / ell)


def test_crossing_coordinates_and_anchor_are_invariant_under_rigid_motions():
    rng = np.random.default_rng(61)
    X = crossing_stencil(rng)
    anchor = anchor_for(X, slip_of_size(rng, 2.5 * LIMIT / STICK))
    moved, _ = rigid_motion(X, 2.0, np.array([3e-4, -2e-4, 5e-4]))
    lifted = np.ascontiguousarray(X + [0.0, 0.0, 7e-4])
    for Y in (moved, lifted):
        q, qY = np.empty(3), np.empty(3)
        spatial.crossing_coordinates(X, q)
        spatial.crossing_coordinates(Y, qY)
        # s: the rounding of d (eps 3e-3 m) and of alpha (eps pi, times |d| <= 0.4 L); phi: eps pi.
        np.testing.assert_allclose(qY, q, rtol=0, atol=10 * EPS * 3e-3)
        a1, a2 = anchor.copy(), anchor.copy()
        lost1, sliding1 = spatial.crossing_return_map(X, a1, RHO, LIMIT, STICK)
        lost2, sliding2 = spatial.crossing_return_map(Y, a2, RHO, LIMIT, STICK)
        assert sliding1 and sliding2
        np.testing.assert_allclose(a2, a1, rtol=0, atol=10 * EPS * 3e-3 / RHO)
        assert lost2 == pytest.approx(lost1, rel=1e-10)


# --- The vertical-plane reduction ----------------------------------------------------------


@pytest.mark.parametrize("seed", [70, 71, 72])
def test_bending_in_a_vertical_plane_is_the_planar_bending(seed):
    """A chain in the x-z plane with both segments pointing +x: the out-of-plane part is
    docs/model.md section 2's 1/2 kb (phi - theta0)^2 with the planar code's turning angle, the
    lateral part exactly 0, and the forces the planar forces (y part exactly 0).

    Both compute the same angle from the same doubles (ours as atan2(z2, x2) - atan2(z1, x1),
    since sqrt(x^2) = |x| exactly; theirs as atan2(a x b, a . b)), each to a few ulp of pi:
    angles agree within 16 eps pi, so E within kb |phi - theta0| 16 eps pi."""
    rng = np.random.default_rng(seed)
    e1 = L * np.array([rng.uniform(0.8, 1.2), 0.0, rng.uniform(-0.5, 0.5)])
    e2 = L * np.array([rng.uniform(0.8, 1.2), 0.0, rng.uniform(-0.5, 0.5)])
    x = np.array([rng.uniform(-L, L), 0.0, rng.uniform(-L, L)])
    X = np.ascontiguousarray([x - e1, x, x + e2])
    theta0 = rng.uniform(-0.3, 0.3)
    pos2d = np.ascontiguousarray(X[:, [0, 2]])
    phi = bending.turning_angle(pos2d, 1)
    out_of_plane, lateral = spatial.bend_turnings(X)
    assert lateral == 0.0
    assert abs(out_of_plane - phi) <= 16 * EPS * np.pi
    E = spatial.bend_energy(X, KB, theta0, KL, 0.0)
    planar = 0.5 * KB * (phi - theta0) ** 2
    assert abs(E - planar) <= KB * abs(phi - theta0) * 16 * EPS * np.pi + 4 * EPS * planar
    g, H = np.empty(9), np.empty((9, 9))
    spatial.bend_derivatives(X, KB, theta0, KL, 0.0, g, H)
    planar_grad = np.zeros((3, 2))
    bending.add_gradient(pos2d, np.array([0.0, KB, 0.0]), np.array([0.0, theta0, 0.0]),
                         planar_grad)
    g = g.reshape(3, 3)
    assert not g[:, 1].any()
    # The moment kb (phi - theta0) agrees within kb 16 eps pi; dphi/dr [1/m] is computed to a
    # few eps of 1/L.
    np.testing.assert_allclose(g[:, [0, 2]], planar_grad, rtol=0,
                               atol=KB / L * (16 * EPS * np.pi + 8 * EPS * abs(phi - theta0)) * 10)


# --- Analytic values -----------------------------------------------------------------------


def test_stretch_of_a_3_4_12_segment():
    X = np.ascontiguousarray([[1e-4, 2e-4, 0.0], [4e-4, 6e-4, 12e-4]])     # length 13e-4 m
    # The length rounds to a few eps of 13e-4 m; E to twice that relative to 3e-4 m.
    assert spatial.stretch_energy(X, K_STRETCH, L) == pytest.approx(
        0.5 * K_STRETCH * (13e-4 - L) ** 2, rel=2 * 8 * EPS * 13e-4 / 3e-4)


@pytest.mark.parametrize("angle", [0.3, -1.0, 2.5])
def test_straight_chain_bent_in_plane_by_a_known_angle(angle):
    """E = 1/2 kl angle^2 (theta0 = psi0 = 0; the elevations are exactly 0), in any in-plane
    orientation and place."""
    X = np.ascontiguousarray([[-0.9 * L, 0.0, 0.0], [0.0, 0.0, 0.0],
                              [1.1 * L * math.cos(angle), 1.1 * L * math.sin(angle), 0.0]])
    X, _ = rigid_motion(X, 0.7, np.array([2e-4, -1e-4, 3e-4]))
    # The turned directions round to eps pi each.
    assert spatial.bend_energy(X, KB, 0.0, KL, 0.0) == pytest.approx(
        0.5 * KL * angle ** 2, rel=0, abs=KL * abs(angle) * 8 * EPS * np.pi)


def test_chain_bent_out_of_plane_by_a_known_angle():
    """Segments along +x, the second raised by `angle`: E = 1/2 kb angle^2, lateral part 0."""
    angle = 0.4
    X = np.ascontiguousarray([[-L, 0.0, 0.0], [0.0, 0.0, 0.0],
                              [L * math.cos(angle), 0.0, L * math.sin(angle)]])
    assert spatial.bend_energy(X, KB, 0.0, KL, 0.0) == pytest.approx(
        0.5 * KB * angle ** 2, rel=16 * EPS)


@pytest.mark.parametrize("sign", [1.0, -1.0])
@pytest.mark.parametrize("distance", [0.5 * L, 0.79 * L, 1.2 * L])
def test_lateral_contact_at_a_known_distance(sign, distance):
    """B at distance d from the line through A (any chord direction, B offset along it and in
    z): E = 1/2 k (w - d)^2 for d < w, else 0, and nothing at all beyond."""
    X = lateral_stencil(np.random.default_rng(80), distance, sign)
    # d is a cross product over a square root of coordinates |X| <= 3 L: it errs by about
    # 10 eps 3 L; E = 1/2 k (w - d)^2 by twice that relative to w - d (tolerance: x 3).
    d_rounding = 100 * EPS * L
    assert spatial.lateral_distance(X, sign) == pytest.approx(distance, rel=0, abs=d_rounding)
    gap = max(WIDTH - distance, 0.0)
    E = spatial.lateral_energy(X, sign, WIDTH, K_LATERAL)
    assert E == pytest.approx(0.5 * K_LATERAL * gap ** 2, rel=0, abs=K_LATERAL * gap * d_rounding)
    g, H = np.full(12, np.nan), np.full((12, 12), np.nan)
    assert spatial.lateral_derivatives(X, sign, WIDTH, K_LATERAL, g, H) == E
    if distance >= WIDTH:
        assert E == 0.0 and not g.any() and not H.any()
    # The other side of the line: a negative distance, deep in contact.
    assert spatial.lateral_distance(X, -sign) == pytest.approx(-distance, rel=0, abs=d_rounding)


@pytest.mark.parametrize("distance", [0.5 * L, 1.2 * L])
def test_a_held_lateral_contact_takes_its_branch_not_its_gap(distance):
    """docs/model.md 11.5's active set: held CLOSED the contact is the spring 1/2 k (w - d)^2
    on both sides of d = w (it pulls where d > w); held OPEN it carries nothing where d < w;
    NATURAL is the unilateral law."""
    X = lateral_stencil(np.random.default_rng(81), distance, 1.0)
    gap = WIDTH - spatial.lateral_distance(X, 1.0)
    spring = 0.5 * K_LATERAL * gap ** 2
    energies = {branch: spatial.lateral_energy(X, 1.0, WIDTH, K_LATERAL, branch)
                for branch in (NATURAL, OPEN, CLOSED)}
    # numba's product may round differently from Python's: a few eps of the spring.
    assert energies[CLOSED] == pytest.approx(spring, rel=4 * EPS)
    assert energies[NATURAL] == (energies[CLOSED] if gap > 0.0 else 0.0)
    assert energies[OPEN] == 0.0
    g, H = np.empty(12), np.empty((12, 12))
    spatial.lateral_derivatives(X, 1.0, WIDTH, K_LATERAL, g, H, OPEN)
    assert not g.any() and not H.any()


# --- Friction return map -------------------------------------------------------------------


def test_return_map_puts_a_sliding_crossing_on_the_limit_surface():
    rng = np.random.default_rng(90)
    X = crossing_stencil(rng)
    anchor = anchor_for(X, slip_of_size(rng, 2.5 * LIMIT / STICK))
    before = spatial.crossing_slip(X, anchor, RHO)
    lost, sliding = spatial.crossing_return_map(X, anchor, RHO, LIMIT, STICK)
    after = spatial.crossing_slip(X, anchor, RHO)
    assert sliding
    # k_t |S| = F_T to the rounding of S (eps 3e-3 m against |S| = 5e-5 m: 1e-11 relative).
    assert STICK * np.linalg.norm(after) == pytest.approx(LIMIT, rel=1e-10)
    # Radial: S keeps its direction; the work of F_T over the distance the anchor moved in S.
    np.testing.assert_allclose(after / np.linalg.norm(after), before / np.linalg.norm(before),
                               rtol=0, atol=1e-10)
    assert lost == pytest.approx(LIMIT * np.linalg.norm(before - after), rel=1e-10)
    # On the limit surface a second map moves the anchor by rounding only (k_t |S| = F_T
    # within 1e-10, so m < 1e-10) and dissipates nothing to that order.
    again = anchor.copy()
    lost_again, _ = spatial.crossing_return_map(X, again, RHO, LIMIT, STICK)
    assert lost_again <= 1e-10 * lost
    np.testing.assert_allclose(again, anchor, rtol=0, atol=1e-10 * LIMIT / STICK / RHO)


def test_return_map_keeps_a_sticking_anchor():
    rng = np.random.default_rng(91)
    X = crossing_stencil(rng)
    anchor = anchor_for(X, slip_of_size(rng, 0.4 * LIMIT / STICK))
    kept = anchor.copy()
    assert spatial.crossing_return_map(X, anchor, RHO, LIMIT, STICK) == (0.0, False)
    np.testing.assert_array_equal(anchor, kept)


def test_return_map_of_an_open_crossing_follows_the_nodes_at_no_cost():
    """(4.3) at F_T = 0: the anchor moves onto the current state (S = 0), nothing dissipated,
    so a crossing that closes again starts sticking where it is."""
    rng = np.random.default_rng(92)
    X = crossing_stencil(rng)
    anchor = anchor_for(X, slip_of_size(rng, 3e-5))
    lost, sliding = spatial.crossing_return_map(X, anchor, RHO, 0.0, STICK)
    assert sliding and lost == 0.0
    np.testing.assert_allclose(spatial.crossing_slip(X, anchor, RHO), 0.0, atol=10 * EPS * 3e-3)
