"""Element energies of the spatial fabric, with exact local gradients and Hessians
(docs/model.md section 11).

Nodes move in x, y, z (the fabric's plane is x-y, e_z its normal). Every element reads a
small stencil of node positions X (m, 3) [m] and fills a local gradient g (3m,) and Hessian
H (3m, 3m) over the flattened stencil dofs, node-major (dof 3 i + coordinate), overwriting
them. Stencil slots may name the same node (a chain end uses the node itself as its missing
neighbour): every derivative treats each slot as independent, and the caller sums slots.
`*_energy` gives the energy alone (line searches); `*_derivatives(..., g, H)` fills g, H and
returns the energy.

Every element is a function E(u) of a few differences of slots, u_k = X[p_k] - X[m_k] (one
coordinate each), so dE/dX = sum_k dE/du_k (e_{p_k} - e_{m_k}) and
d2E/dX2 = sum_kl d2E/du_k du_l (e_{p_k} - e_{m_k})(e_{p_l} - e_{m_l})^T (`_scatter_*`).

Building blocks (vector e (3,), r = |e_xy| > 0):

    wrap(a) in (-pi, pi],  a - wrap(a) a multiple of 2 pi (derivative 1 off the cut);
    psi(e) = atan2(e_y, e_x)   (in-plane direction)
        dpsi/de = (-e_y, e_x, 0) / r^2,
        d2psi/de_xy^2 = [[2 e_x e_y, e_y^2 - e_x^2], [e_y^2 - e_x^2, -2 e_x e_y]] / r^4, 0 in z;
    theta(e) = atan2(e_z, r)   (elevation), by the chain rule through (r, e_z):
        dtheta/d(r, z) = (-z, r) / |e|^2,
        d2theta/d(r, z)^2 = [[2 r z, z^2 - r^2], [z^2 - r^2, -2 r z]] / |e|^4,
        dr/de_xy = n = e_xy / r,  d2r/de_xy^2 = (I - n n^T) / r.

Elements:

(a) Stretch, X = (x0, x1), e = x1 - x0, l = |e|, n = e / l, k = EA / l0 [N/m]:
        E = 1/2 k (l - l0)^2,  dE/de = k (l - l0) n,
        d2E/de2 = k n n^T + k (1 - l0 / l)(I - n n^T).
(b) Bending in two planes, X = (x_prev, x, x_next), e1 = x - x_prev, e2 = x_next - x:
        E = 1/2 kb (theta(e2) - theta(e1) - theta0)^2
          + 1/2 kl (wrap(psi(e2) - psi(e1)) - psi0)^2,
    kb = EI / lbar, kl = EI_lateral / lbar [N m]; each part a spring on an angle
    a(e1, e2) = f(e2) - f(e1): dE = k (a - a0) da, d2E = k da da^T + k (a - a0) d2a. Needs
    |e_xy| > 0 for both segments (the caller refuses a vertical segment). In a vertical
    plane it is the planar bending (docs/model.md section 2) and the lateral part is 0.
(c) Crossing kinematics, X = (a_prev, a, a_next, b_prev, b, b_next) (a on the warp, b on
    the weft): c_a = (a_next - a_prev)_xy, c_b = (b_next - b_prev)_xy, alpha = psi(c_a),
    beta = psi(c_b), d = (x_b - x_a)_xy and
        q = (s_x, s_y, phi) = (R(-alpha) d, wrap(beta - alpha)),
    the relative in-plane displacement in the warp's frame and the in-plane angle from the
    warp to the weft: invariant under rigid in-plane motions and z translations.
    ds/dalpha = (s_y, -s_x), d2s/dalpha2 = -s, ds/dd = R(-alpha),
    d2s/(dd dalpha) = dR(-alpha)/dalpha, chained through alpha = psi(c_a), beta = psi(c_b).
(d) Crossing friction and rotation spring: with D = diag(1, 1, rho) and the anchor
    (slip anchor [m, m], rotation anchor [rad]),
        S = (q0 - anchor0, q1 - anchor1, rho wrap(q2 - anchor2)),
        E = Huber(S) + 1/2 shear_k wrap(q2 - phi_rest)^2,
        Huber(S) = 1/2 k_t |S|^2 if k_t |S| < F_T, else F_T |S| - F_T^2 / (2 k_t);
    Huber = 0 where F_T <= 0 (an open crossing): (4.4) on the three-component slip.
        dE = J^T (D dHuber + shear_k w e_2),  w = wrap(q2 - phi_rest),
        d2E = J^T (D d2Huber D + shear_k e_2 e_2^T) J + sum_m (D dHuber + shear_k w e_2)_m K_m,
    J = dq/dX, K_m = d2q_m/dX2; d2Huber = k_t I sticking, (F_T / |S|)(I - S S^T / |S|^2)
    sliding, or towards (F_T / |S|) I by the weight `secant` (the curvature of the quadratic
    touching Huber at S from above). The return map (4.3) moves the anchor radially in S where k_t |S| > F_T:
    S <- (1 - m) S, m = 1 - F_T / (k_t |S|), dissipating F_T m |S|.
(e) Lateral contact of neighbouring yarns, X = (A_prev, A_next, A, B): c = (A_next -
    A_prev)_xy, d = sign cross2(c, (B - A)_xy) / |c| (the signed distance from B to the line
    through A along c), E = E_lat(d) for d < width, else 0 (the unilateral law, `branch`
    NATURAL); held by the static solver's active set (`branch`, docs/model.md 11.5), CLOSED
    gives E_lat(d) at every d and OPEN 0. E_lat is the linear 1/2 k (width - d)^2 without a
    compaction law (`compaction` 0), else Gutowski's (`compaction_law`, docs/model.md 11.5);
        dE = E_lat' dd,  d2E = E_lat'' dd dd^T + E_lat' d2d,
    with f = cross2(c, v), v = (B - A)_xy: dd/dc = sign ((v_y, -v_x) / |c| - f c / |c|^3),
    dd/dv = sign (-c_y, c_x) / |c|,
    d2d/dc2 = -sign ((df/dc c^T + c df/dc^T) / |c|^3 + f (I / |c|^3 - 3 c c^T / |c|^5)),
    d2d/(dc_i dv_j) = sign (M_ij / |c| - c_i (df/dv)_j / |c|^3), M = [[0, 1], [-1, 0]],
    d2d/dv2 = 0.
"""

import numba
import numpy as np

from dynfab.model.terms import huber as huber_law
from dynfab.model.terms.contact import CLOSED, NATURAL, OPEN

TWO_PI = 2.0 * np.pi


# --- Scattering derivatives w.r.t. slot differences onto the stencil's dofs ---------------


@numba.njit(cache=True)
def _scatter_gradient(gu, plus, minus, g):
    """g += sum_k gu_k (e_{plus_k} - e_{minus_k})."""
    for k in range(gu.size):
        g[plus[k]] += gu[k]
        g[minus[k]] -= gu[k]


@numba.njit(cache=True)
def _scatter_hessian(Hu, plus, minus, H):
    """H += sum_kl Hu_kl (e_{plus_k} - e_{minus_k})(e_{plus_l} - e_{minus_l})^T."""
    n = Hu.shape[0]
    for k in range(n):
        pk, mk = plus[k], minus[k]
        for l in range(n):
            h = Hu[k, l]
            if h == 0.0:
                continue
            pl, ml = plus[l], minus[l]
            H[pk, pl] += h
            H[pk, ml] -= h
            H[mk, pl] -= h
            H[mk, ml] += h


@numba.njit(cache=True)
def _difference(X, plus, minus, u):
    """u_k = X.flat[plus_k] - X.flat[minus_k] [m]."""
    for k in range(u.size):
        p, m = plus[k], minus[k]
        u[k] = X[p // 3, p % 3] - X[m // 3, m % 3]


# --- Building blocks ----------------------------------------------------------------------


@numba.njit(cache=True)
def wrap(angle):
    """The angle [rad] in (-pi, pi] that differs from `angle` by a multiple of 2 pi."""
    return angle - TWO_PI * np.ceil((angle - np.pi) / TWO_PI)


@numba.njit(cache=True)
def direction(e):
    """psi(e) = atan2(e_y, e_x) [rad]: the in-plane direction of e (reads e[0], e[1])."""
    return np.arctan2(e[1], e[0])


@numba.njit(cache=True)
def direction_gradient(e, out):
    """dpsi/de = (-e_y, e_x, 0) / r^2 [1/m] into out (2,) or (3,)."""
    r2 = e[0] * e[0] + e[1] * e[1]
    out[0] = -e[1] / r2
    out[1] = e[0] / r2
    for i in range(2, out.size):
        out[i] = 0.0


@numba.njit(cache=True)
def direction_hessian(e, out):
    """d2psi/de2 [1/m^2] into out (2, 2) or (3, 3): the xy block
    [[2 e_x e_y, e_y^2 - e_x^2], [e_y^2 - e_x^2, -2 e_x e_y]] / r^4, zero in z."""
    out[:, :] = 0.0
    r4 = (e[0] * e[0] + e[1] * e[1]) ** 2
    hxx = 2.0 * e[0] * e[1] / r4
    hxy = (e[1] * e[1] - e[0] * e[0]) / r4
    out[0, 0] = hxx
    out[0, 1] = hxy
    out[1, 0] = hxy
    out[1, 1] = -hxx


@numba.njit(cache=True)
def elevation(e):
    """theta(e) = atan2(e_z, |e_xy|) [rad]: the elevation of e (3,) over the fabric's plane."""
    return np.arctan2(e[2], np.sqrt(e[0] * e[0] + e[1] * e[1]))


@numba.njit(cache=True)
def elevation_gradient(e, out):
    """dtheta/de [1/m] into out (3,): (-z n_x, -z n_y, r) / |e|^2, n = e_xy / r."""
    r = np.sqrt(e[0] * e[0] + e[1] * e[1])
    z = e[2]
    rr = r * r + z * z
    out[0] = -z * (e[0] / r) / rr
    out[1] = -z * (e[1] / r) / rr
    out[2] = r / rr


@numba.njit(cache=True)
def elevation_hessian(e, out):
    """d2theta/de2 [1/m^2] into out (3, 3), by the chain rule through (r, z):
    xy block T_rr n n^T + T_r (I - n n^T) / r, xz column T_rz n, zz T_zz."""
    r = np.sqrt(e[0] * e[0] + e[1] * e[1])
    z = e[2]
    rr = r * r + z * z
    rr2 = rr * rr
    t_r = -z / rr
    t_rr = 2.0 * r * z / rr2
    t_rz = (z * z - r * r) / rr2
    t_zz = -2.0 * r * z / rr2
    n0, n1 = e[0] / r, e[1] / r
    out[0, 0] = t_rr * n0 * n0 + t_r * (1.0 - n0 * n0) / r
    out[1, 1] = t_rr * n1 * n1 + t_r * (1.0 - n1 * n1) / r
    out[0, 1] = out[1, 0] = (t_rr - t_r / r) * n0 * n1
    out[0, 2] = out[2, 0] = t_rz * n0
    out[1, 2] = out[2, 1] = t_rz * n1
    out[2, 2] = t_zz


# --- (a) Stretch --------------------------------------------------------------------------

_STRETCH_PLUS = (3, 4, 5)
_STRETCH_MINUS = (0, 1, 2)


@numba.njit(cache=True)
def stretch_energy(X, k, l0):
    """E = 1/2 k (|x1 - x0| - l0)^2 [J]; X (2, 3) [m], k = EA / l0 [N/m], l0 [m]."""
    dx, dy, dz = X[1, 0] - X[0, 0], X[1, 1] - X[0, 1], X[1, 2] - X[0, 2]
    ext = np.sqrt(dx * dx + dy * dy + dz * dz) - l0
    return 0.5 * k * ext * ext


@numba.njit(cache=True)
def stretch_derivatives(X, k, l0, g, H):
    """Fill g (6,) [N] and H (6, 6) [N/m] of `stretch_energy`; return E [J]."""
    e = np.empty(3)
    _difference(X, _STRETCH_PLUS, _STRETCH_MINUS, e)
    length = np.sqrt(e[0] * e[0] + e[1] * e[1] + e[2] * e[2])
    ext = length - l0
    n = e / length
    gu = k * ext * n
    Hu = np.empty((3, 3))
    transverse = k * (1.0 - l0 / length)
    for i in range(3):
        for j in range(3):
            Hu[i, j] = (k - transverse) * n[i] * n[j]
        Hu[i, i] += transverse
    g[:] = 0.0
    H[:, :] = 0.0
    _scatter_gradient(gu, _STRETCH_PLUS, _STRETCH_MINUS, g)
    _scatter_hessian(Hu, _STRETCH_PLUS, _STRETCH_MINUS, H)
    return 0.5 * k * ext * ext


# --- (b) Bending in two planes ------------------------------------------------------------

_BEND_PLUS = (3, 4, 5, 6, 7, 8)     # u = (e1, e2) = (x - x_prev, x_next - x)
_BEND_MINUS = (0, 1, 2, 3, 4, 5)


@numba.njit(cache=True)
def _segments(X):
    e1 = np.empty(3)
    e2 = np.empty(3)
    for i in range(3):
        e1[i] = X[1, i] - X[0, i]
        e2[i] = X[2, i] - X[1, i]
    return e1, e2


@numba.njit(cache=True)
def bend_turnings(X):
    """(theta(e2) - theta(e1), wrap(psi(e2) - psi(e1))) [rad] of X (3, 3): the out-of-plane
    and the lateral turning at the middle node."""
    e1, e2 = _segments(X)
    return elevation(e2) - elevation(e1), wrap(direction(e2) - direction(e1))


@numba.njit(cache=True)
def bend_energy(X, kb, theta0, kl, psi0):
    """E = 1/2 kb (dtheta - theta0)^2 + 1/2 kl (dpsi - psi0)^2 [J] (docs/model.md section 11);
    kb, kl [N m], theta0, psi0 [rad]."""
    out_of_plane, lateral = bend_turnings(X)
    a = out_of_plane - theta0
    b = lateral - psi0
    return 0.5 * kb * a * a + 0.5 * kl * b * b


@numba.njit(cache=True)
def _add_turning_spring(k, excess, g1, H1, g2, H2, gu, Hu):
    """gu, Hu += the derivatives of 1/2 k excess^2 over u = (e1, e2), where the angle is
    f(e2) - f(e1) with df/de = g1 at e1, g2 at e2 and d2f/de2 = H1, H2."""
    da = np.empty(6)
    for i in range(3):
        da[i] = -g1[i]
        da[3 + i] = g2[i]
    for i in range(6):
        gu[i] += k * excess * da[i]
        for j in range(6):
            Hu[i, j] += k * da[i] * da[j]
    for i in range(3):
        for j in range(3):
            Hu[i, j] -= k * excess * H1[i, j]
            Hu[3 + i, 3 + j] += k * excess * H2[i, j]


@numba.njit(cache=True)
def bend_gradient(X, kb, theta0, kl, psi0, g):
    """Fill g (9,) [N] of `bend_energy` alone (`bend_derivatives` without its Hessian);
    return E [J]."""
    e1, e2 = _segments(X)
    g1, g2, gu = np.empty(3), np.empty(3), np.empty(6)
    a = elevation(e2) - elevation(e1) - theta0
    b = wrap(direction(e2) - direction(e1)) - psi0
    elevation_gradient(e1, g1)
    elevation_gradient(e2, g2)
    for i in range(3):  # d(1/2 k excess^2)/du = k excess (-df/de at e1, df/de at e2)
        gu[i], gu[3 + i] = -kb * a * g1[i], kb * a * g2[i]
    direction_gradient(e1, g1)
    direction_gradient(e2, g2)
    for i in range(3):
        gu[i] -= kl * b * g1[i]
        gu[3 + i] += kl * b * g2[i]
    g[:] = 0.0
    _scatter_gradient(gu, _BEND_PLUS, _BEND_MINUS, g)
    return 0.5 * kb * a * a + 0.5 * kl * b * b


@numba.njit(cache=True)
def bend_derivatives(X, kb, theta0, kl, psi0, g, H):
    """Fill g (9,) [N] and H (9, 9) [N/m] of `bend_energy`; return E [J]."""
    e1, e2 = _segments(X)
    gu = np.zeros(6)
    Hu = np.zeros((6, 6))
    g1, g2 = np.empty(3), np.empty(3)
    H1, H2 = np.empty((3, 3)), np.empty((3, 3))
    a = elevation(e2) - elevation(e1) - theta0
    elevation_gradient(e1, g1)
    elevation_gradient(e2, g2)
    elevation_hessian(e1, H1)
    elevation_hessian(e2, H2)
    _add_turning_spring(kb, a, g1, H1, g2, H2, gu, Hu)
    b = wrap(direction(e2) - direction(e1)) - psi0
    direction_gradient(e1, g1)
    direction_gradient(e2, g2)
    direction_hessian(e1, H1)
    direction_hessian(e2, H2)
    _add_turning_spring(kl, b, g1, H1, g2, H2, gu, Hu)
    g[:] = 0.0
    H[:, :] = 0.0
    _scatter_gradient(gu, _BEND_PLUS, _BEND_MINUS, g)
    _scatter_hessian(Hu, _BEND_PLUS, _BEND_MINUS, H)
    return 0.5 * kb * a * a + 0.5 * kl * b * b


# --- (c) Crossing kinematics --------------------------------------------------------------

# u = (d_x, d_y, c_a,x, c_a,y, c_b,x, c_b,y): d = b - a, c_a = a_next - a_prev,
# c_b = b_next - b_prev over the slots (a_prev, a, a_next, b_prev, b, b_next).
_CROSS_PLUS = (12, 13, 6, 7, 15, 16)
_CROSS_MINUS = (3, 4, 0, 1, 9, 10)


@numba.njit(cache=True)
def crossing_coordinates(X, q):
    """q = (s_x [m], s_y [m], phi [rad]) of the crossing stencil X (6, 3) into q (3,)."""
    alpha = np.arctan2(X[2, 1] - X[0, 1], X[2, 0] - X[0, 0])
    beta = np.arctan2(X[5, 1] - X[3, 1], X[5, 0] - X[3, 0])
    dx, dy = X[4, 0] - X[1, 0], X[4, 1] - X[1, 1]
    c, s = np.cos(alpha), np.sin(alpha)
    q[0] = c * dx + s * dy
    q[1] = -s * dx + c * dy
    q[2] = wrap(beta - alpha)


@numba.njit(cache=True)
def crossing_kinematics(X, q, J, K):
    """Fill q (3,), J = dq/dX (3, 18) and K = d2q/dX2 (3, 18, 18) of the crossing stencil
    X (6, 3) = (a_prev, a, a_next, b_prev, b, b_next) (docs/model.md section 11)."""
    u = np.empty(6)
    _difference(X, _CROSS_PLUS, _CROSS_MINUS, u)
    ca, cb = u[2:4], u[4:6]
    alpha, beta = direction(ca), direction(cb)
    ga, gb = np.empty(2), np.empty(2)
    Ha, Hb = np.empty((2, 2)), np.empty((2, 2))
    direction_gradient(ca, ga)
    direction_gradient(cb, gb)
    direction_hessian(ca, Ha)
    direction_hessian(cb, Hb)
    c, s = np.cos(alpha), np.sin(alpha)
    sx = c * u[0] + s * u[1]
    sy = -s * u[0] + c * u[1]
    q[0], q[1], q[2] = sx, sy, wrap(beta - alpha)
    # Derivatives over u: q_m = f_m(d, alpha(c_a), beta(c_b)).
    Ju = np.zeros((3, 6))
    Ku = np.zeros((3, 6, 6))
    # ds/dd = R(-alpha); ds/dalpha = (s_y, -s_x); d2s/(dd dalpha) = dR(-alpha)/dalpha;
    # d2s/dalpha2 = -s.
    ds_dd = ((c, s), (-s, c))
    ds_dalpha = (sy, -sx)
    d2s_dd_dalpha = ((-s, c), (-c, -s))
    for m in range(2):
        for i in range(2):
            Ju[m, i] = ds_dd[m][i]
            Ju[m, 2 + i] = ds_dalpha[m] * ga[i]
            for j in range(2):
                cross = d2s_dd_dalpha[m][i] * ga[j]
                Ku[m, i, 2 + j] = cross
                Ku[m, 2 + j, i] = cross
                Ku[m, 2 + i, 2 + j] = -(sx if m == 0 else sy) * ga[i] * ga[j] \
                    + ds_dalpha[m] * Ha[i, j]
    for i in range(2):
        Ju[2, 2 + i] = -ga[i]
        Ju[2, 4 + i] = gb[i]
        for j in range(2):
            Ku[2, 2 + i, 2 + j] = -Ha[i, j]
            Ku[2, 4 + i, 4 + j] = Hb[i, j]
    J[:, :] = 0.0
    K[:, :, :] = 0.0
    for m in range(3):
        _scatter_gradient(Ju[m], _CROSS_PLUS, _CROSS_MINUS, J[m])
        _scatter_hessian(Ku[m], _CROSS_PLUS, _CROSS_MINUS, K[m])


# --- (d) Crossing friction (Huber on the three-component slip) and rotation spring --------


@numba.njit(cache=True)
def _norm3(S):
    return np.sqrt(S[0] * S[0] + S[1] * S[1] + S[2] * S[2])


@numba.njit(cache=True)
def huber3(S, limit, stick):
    """Huber(S) [J] of the slip S (3,) [m] (`dynfab.model.terms.huber.energy`): 1/2 k_t |S|^2
    while k_t |S| < F_T, else F_T |S| - F_T^2 / (2 k_t); 0 where F_T <= 0. limit = F_T [N],
    stick = k_t [N/m]."""
    return huber_law.energy(_norm3(S), limit, stick)


@numba.njit(cache=True)
def huber3_gradient(S, limit, stick, out):
    """dHuber/dS [N] into out (3,): k_t S sticking, F_T S / |S| sliding, 0 open."""
    scale = huber_law.force_per_slip(_norm3(S), limit, stick)
    for i in range(3):
        out[i] = scale * S[i]


@numba.njit(cache=True)
def huber3_hessian(S, limit, stick, secant, out):
    """d2Huber/dS2 [N/m] into out (3, 3): k_t I sticking; (F_T / |S|)(I - (1 - secant) S S^T /
    |S|^2) sliding, `secant` in [0, 1] the weight of the secant (F_T / |S|) I (True: 1); 0
    open."""
    out[:, :] = 0.0
    if not limit > 0.0:
        return
    n = _norm3(S)
    if not huber_law.slides(n, limit, stick):
        for i in range(3):
            out[i, i] = stick
        return
    scale = limit / n
    for i in range(3):
        out[i, i] = scale
        if secant < 1.0:
            for j in range(3):
                out[i, j] -= (1.0 - secant) * scale * S[i] * S[j] / (n * n)


@numba.njit(cache=True)
def _slip(q, anchor, rho, S):
    S[0] = q[0] - anchor[0]
    S[1] = q[1] - anchor[1]
    S[2] = rho * wrap(q[2] - anchor[2])


@numba.njit(cache=True)
def crossing_slip(X, anchor, rho):
    """S = (s_x - anchor0, s_y - anchor1, rho wrap(phi - anchor2)) [m] of the crossing
    stencil X (6, 3); anchor (3,) [m, m, rad], rho the torsion radius [m]."""
    q = np.empty(3)
    crossing_coordinates(X, q)
    S = np.empty(3)
    _slip(q, anchor, rho, S)
    return S


@numba.njit(cache=True)
def crossing_energy(X, anchor, rho, limit, stick, shear_k, phi_rest):
    """E = Huber(S) + 1/2 shear_k wrap(phi - phi_rest)^2 [J] (docs/model.md section 11);
    limit = F_T [N], stick = k_t [N/m], shear_k [N m/rad], phi_rest [rad]."""
    q = np.empty(3)
    crossing_coordinates(X, q)
    S = np.empty(3)
    _slip(q, anchor, rho, S)
    w = wrap(q[2] - phi_rest)
    return huber3(S, limit, stick) + 0.5 * shear_k * w * w


@numba.njit(cache=True)
def crossing_derivatives(X, anchor, rho, limit, stick, shear_k, phi_rest, secant, g, H):
    """Fill g (18,) [N] and H (18, 18) [N/m] of `crossing_energy`; return E [J].
    H = J^T A J + sum_m f_m K_m with f = D dHuber + shear_k w e_2 (dE/dq) and
    A = D d2Huber D + shear_k e_2 e_2^T (d2E/dq2); `secant`: see `huber3_hessian`."""
    q = np.empty(3)
    J = np.empty((3, 18))
    K = np.empty((3, 18, 18))
    crossing_kinematics(X, q, J, K)
    S = np.empty(3)
    _slip(q, anchor, rho, S)
    w = wrap(q[2] - phi_rest)
    f = np.empty(3)
    A = np.empty((3, 3))
    huber3_gradient(S, limit, stick, f)
    huber3_hessian(S, limit, stick, secant, A)
    for m in range(3):
        A[m, 2] *= rho
        A[2, m] *= rho
    f[2] = rho * f[2] + shear_k * w
    A[2, 2] += shear_k
    for i in range(18):
        g[i] = f[0] * J[0, i] + f[1] * J[1, i] + f[2] * J[2, i]
    AJ = np.zeros((3, 18))
    for m in range(3):
        for n in range(3):
            if A[m, n] != 0.0:
                for j in range(18):
                    AJ[m, j] += A[m, n] * J[n, j]
    for i in range(18):
        for j in range(18):
            h = f[0] * K[0, i, j] + f[1] * K[1, i, j] + f[2] * K[2, i, j]
            for m in range(3):
                h += J[m, i] * AJ[m, j]
            H[i, j] = h
    return huber3(S, limit, stick) + 0.5 * shear_k * w * w


@numba.njit(cache=True)
def crossing_return_map(X, anchor, rho, limit, stick):
    """Return-map the anchor (3,) in place ((4.3) on the three-component slip); return
    (energy lost [J], sliding).

    Where k_t |S| > F_T (F_T <= 0 counting as 0) the anchor moves radially in S,
    anchor[0:2] += m S[0:2], anchor[2] += m S[2] / rho with m = 1 - F_T / (k_t |S|), so that
    k_t |S| = F_T afterwards; the energy lost is F_T m |S|. An open crossing (F_T <= 0) with
    any slip slides losslessly: its anchor follows the nodes (S = 0), as (4.3) does at F_T = 0.
    """
    S = crossing_slip(X, anchor, rho)
    n = _norm3(S)
    f_t = max(limit, 0.0)
    if not huber_law.moves(n, limit, stick):
        return 0.0, False
    m = 1.0 - f_t / (stick * n)
    anchor[0] += m * S[0]
    anchor[1] += m * S[1]
    anchor[2] += m * S[2] / rho
    return f_t * m * n, True


# --- (e) Lateral contact of neighbouring yarns --------------------------------------------


@numba.njit(cache=True)
def _gutowski(s, width, compaction, packed):
    """(E, dE/ds, d2E/ds2) of Gutowski's compaction at centreline distance s > packed [m]:
    E = A (Phi(w) - Phi(s)), dE/ds = -A sigma(s), with (u = sqrt(s), v = u / sqrt(s_a) - 1)

        sigma(s) = (sqrt(w / s) - 1) / v^4,
        Phi(s) = 2 sqrt(s_a) (sqrt(s_a) / (2 v^2) - (sqrt(w) - sqrt(s_a)) / (3 v^3)),

    Phi' = sigma (docs/model.md (11.6)); A = `compaction` [N], s_a = `packed` [m]."""
    rw, rs, ra = np.sqrt(width), np.sqrt(s), np.sqrt(packed)
    v, vw = rs / ra - 1.0, rw / ra - 1.0
    phi = 2.0 * ra * (ra / (2.0 * v * v) - (rw - ra) / (3.0 * v * v * v))
    phi_w = 2.0 * ra * (ra / (2.0 * vw * vw) - (rw - ra) / (3.0 * vw * vw * vw))
    excess = rw / rs - 1.0
    v4 = v * v * v * v
    dsigma = -rw / (2.0 * s * rs) / v4 - 4.0 * excess / (v4 * v * 2.0 * rs * ra)
    return compaction * (phi_w - phi), -compaction * excess / v4, -compaction * dsigma


@numba.njit(cache=True)
def compaction_law(d, width, k, compaction, packed, core_from):
    """(E [J], dE/dd [N], d2E/dd2 [N/m]) of the lateral contact's law at centreline distance
    d [m] (docs/model.md 11.5): 1/2 k (width - d)^2 without a compaction law (`compaction`
    0); else Gutowski's (`_gutowski`) down to `core_from` [m], where its stiffness reaches
    the yarns' core k, and the core's spring k below it (continuous to the second
    derivative)."""
    if not compaction > 0.0:
        gap = width - d
        return 0.5 * k * gap * gap, -k * gap, k
    if d >= core_from:
        return _gutowski(d, width, compaction, packed)
    e, e1, e2 = _gutowski(core_from, width, compaction, packed)
    x = d - core_from
    return e + e1 * x + 0.5 * k * x * x, e1 + k * x, k


# u = (c_x, c_y, v_x, v_y): c = A_next - A_prev, v = B - A over the slots (A_prev, A_next, A, B).
_LATERAL_PLUS = (3, 4, 9, 10)
_LATERAL_MINUS = (0, 1, 6, 7)


@numba.njit(cache=True)
def lateral_distance(X, sign):
    """d = sign cross2(c, v) / |c| [m]: the signed distance from B to the line through A along
    c = (A_next - A_prev)_xy, v = (B - A)_xy; X (4, 3) = (A_prev, A_next, A, B), sign +-1."""
    cx, cy = X[1, 0] - X[0, 0], X[1, 1] - X[0, 1]
    vx, vy = X[3, 0] - X[2, 0], X[3, 1] - X[2, 1]
    return sign * (cx * vy - cy * vx) / np.sqrt(cx * cx + cy * cy)


@numba.njit(cache=True)
def lateral_pressing(gap, branch):
    """Whether a lateral contact with w - d = `gap` [m] carries its spring on `branch`
    (NATURAL, OPEN or CLOSED of `dynfab.model.terms.contact`; module docstring (e))."""
    if branch == OPEN:
        return False
    return branch == CLOSED or gap > 0.0


@numba.njit(cache=True)
def lateral_energy(X, sign, width, k, branch=NATURAL, compaction=0.0, packed=0.0,
                   core_from=0.0):
    """E = E_lat(d) where `lateral_pressing`, else 0 [J] (`compaction_law`); width [m],
    k [N/m]."""
    d = lateral_distance(X, sign)
    if not lateral_pressing(width - d, branch):
        return 0.0
    return compaction_law(d, width, k, compaction, packed, core_from)[0]


@numba.njit(cache=True)
def _lateral_distance_derivatives(u, sign, gd, Hd):
    """d, and its gradient gd (4,) and Hessian Hd (4, 4) over u = (c, v) (module docstring)."""
    cx, cy, vx, vy = u[0], u[1], u[2], u[3]
    n2 = cx * cx + cy * cy
    n = np.sqrt(n2)
    n3 = n2 * n
    f = cx * vy - cy * vx
    df_dc = (vy, -vx)
    df_dv = (-cy, cx)
    c = (cx, cy)
    cross = ((0.0, 1.0), (-1.0, 0.0))
    Hd[:, :] = 0.0
    for i in range(2):
        gd[i] = sign * (df_dc[i] / n - f * c[i] / n3)
        gd[2 + i] = sign * df_dv[i] / n
        for j in range(2):
            h = -(df_dc[i] * c[j] + c[i] * df_dc[j]) / n3 + 3.0 * f * c[i] * c[j] / (n3 * n2)
            if i == j:
                h -= f / n3
            Hd[i, j] = sign * h
            m = sign * (cross[i][j] / n - c[i] * df_dv[j] / n3)
            Hd[i, 2 + j] = m
            Hd[2 + j, i] = m
    return sign * f / n


@numba.njit(cache=True)
def lateral_derivatives(X, sign, width, k, g, H, branch=NATURAL, compaction=0.0, packed=0.0,
                        core_from=0.0):
    """Fill g (12,) [N] and H (12, 12) [N/m] of `lateral_energy`; return E [J]
    (all zero where not `lateral_pressing`)."""
    g[:] = 0.0
    H[:, :] = 0.0
    u = np.empty(4)
    _difference(X, _LATERAL_PLUS, _LATERAL_MINUS, u)
    gd = np.empty(4)
    Hd = np.empty((4, 4))
    d = _lateral_distance_derivatives(u, sign, gd, Hd)
    if not lateral_pressing(width - d, branch):
        return 0.0
    energy, e1, e2 = compaction_law(d, width, k, compaction, packed, core_from)
    gu = e1 * gd
    Hu = np.empty((4, 4))
    for i in range(4):
        for j in range(4):
            Hu[i, j] = e2 * gd[i] * gd[j] + e1 * Hd[i, j]
    _scatter_gradient(gu, _LATERAL_PLUS, _LATERAL_MINUS, g)
    _scatter_hessian(Hu, _LATERAL_PLUS, _LATERAL_MINUS, H)
    return energy
