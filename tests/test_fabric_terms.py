"""The fabric's new terms against central finite differences (docs/model.md section 10):
the two-node crossing contact, the isotropic 2D Huber friction in stick and in slip,
and the whole assembly (stretch and bending on each yarn's own chain, the crossing
blocks, the load), plus Kawabata's wall without a core spring.

Finite-difference tolerances follow tests/test_terms.py's rule: a central difference
with step h (taken as rounded) errs by h^2/6 |f'''| (truncation, bounded by K/ell for a
gradient, K/ell^2 for a Hessian, K the stiffness bound and ell the length over which it
varies) plus the rounding of the two evaluations over 2h (eps S/h for energies, S the
sum of |term| and |dE/dr_i| |r_i|; eps K r/h for gradients); asserted with a factor 10
over their sum. A wrong sign, index or factor is O(1) of the derivative.
"""

import math

import numpy as np
import pytest

from dynfab.model.fabric import assembly, contact, friction
from dynfab.model.fabric.model import FabricModel
from dynfab.model.structure import Structure, chain_count, uniform
from dynfab.model.terms import friction as gralen
from dynfab.model.terms.contact import closure_from_force
from independent import fabric_scene, fd_gradient, fd_jacobian, without_core_spring

EPS = np.finfo(float).eps

L, N = 0.1, 8
WARP = dict(length=L, segments=N, amplitude=0.5e-3, EA=13.72, EI=1.47e-7, kawabata_C=0.2e-3,
            kawabata_K=0.2)
WEFT = dict(length=0.08, segments=8, amplitude=0.4e-3, EA=10.0, EI=2e-7, kawabata_C=0.15e-3,
            kawabata_K=0.3)
FRICTION = dict(alpha=0.2, beta=1e3, contact_length=2e-3, fiber_radius=1e-3)
L0 = L / N
"""The geometry scale [m]."""
H_GRAD, H_HESS = 1e-6 * L0, 1e-5 * L0

# Crossing c's state: (closure g / (C_wa + C_we), slip regime). Closed crossings inside the
# Kawabata range (0.05, 0.5) and past it (3, where the core spring k_c takes over), one open;
# slips of 0.4 F_T/k_t (stick) or 2.5 F_T/k_t (slide) in different directions, so the
# stick/slip kink is >= 0.6 F_T/k_t >= 2e-6 m away, beyond the largest FD step (1.25e-7 m).
CROSSING_STATES = ((0.5, "stick"), (3.0, "slide"), (-0.25, "open"), (0.05, "slide"))
SLIP = {"stick": 0.4, "slide": 2.5, "open": 1.0}
P = np.array([0.3, -0.2, 0.1, 0.05])
"""End forces of the 2 warps and 2 wefts [N] (the load term)."""


def two_by_two_fabric(core_stiffness=1e5, boundary="clamped", planes=None) -> Structure:
    """The structure of the 2 x 2 test fabric, every term on (gravity on the patch only: the
    cell refuses it); `core_stiffness` k_c [N/m], inf: none (`independent.without_core_spring`)."""
    tables = dict(friction=FRICTION, load=dict(control="force", values=[0.1]))
    if boundary == "clamped":
        tables["gravity"] = dict(g=9.81)
    if np.isfinite(core_stiffness):
        tables["contact"] = dict(core_stiffness=core_stiffness)
    geometry = dict(boundary=boundary) if planes is None else dict(boundary=boundary, planes=planes)
    scene = fabric_scene(WARP, WEFT, 2, 2, geometry=geometry, **tables)
    model = (FabricModel.from_scene(scene) if np.isfinite(core_stiffness)
             else without_core_spring(scene))
    return model.structure


def stick_stiffness(fabric) -> float:
    """k_t [N/m], one for every crossing of the test fabric."""
    return float(uniform(fabric.tie_friction_law)[friction.STICK])


def perturbed_state(fabric, seed=7):
    """(positions, anchors, F_T, g): every node moved by up to 0.05 l0, then each crossing
    put at its CROSSING_STATES closure (both nodes moved in z) and slip (by its anchor)."""
    rng = np.random.default_rng(seed)
    r = fabric.rest_position + rng.uniform(-0.05, 0.05, fabric.rest_position.shape) * L0
    law = uniform(fabric.tie_contact_law)
    wall = law[1] + law[3]
    c = fabric.tie_a.size
    g = np.array([s * wall for s, _ in CROSSING_STATES])
    a, b, sigma = fabric.tie_a, fabric.tie_b, fabric.tie_side
    mean = 0.5 * (r[a, 1] + r[b, 1])
    # g = gap_offset - sigma (z_a - z_b): set z_a - z_b = sigma (gap_offset - g)
    r[a, 1] = mean + 0.5 * sigma * (fabric.tie_gap_offset - g)
    r[b, 1] = mean - 0.5 * sigma * (fabric.tie_gap_offset - g)
    R = np.array([contact.force(gc, law) for gc in g])
    limit = np.zeros(c)
    gralen.tie_limits(R, fabric.tie_friction_law, -1.0, limit)  # each tie's own R_0
    anchors = np.zeros((c, 2))
    px, py = assembly.planes(r, fabric)  # where the planes move (periodic cell)
    for i, (_, regime) in enumerate(CROSSING_STATES):
        angle = 0.4 + 1.7 * i
        size = SLIP[regime] * max(limit[i], 1e-3) / stick_stiffness(fabric)
        anchors[i, 0] = r[a[i], 0] - px[i] - size * math.cos(angle)
        anchors[i, 1] = r[b[i], 0] - py[i] - size * math.sin(angle)
    return r, anchors, limit, g


def contact_length_scale(R, law):
    """ell [m] with |dT/dg| <= K/ell and |d2T/dg2| <= K/ell^2 near force R, K = k_c.

    T = dR/dg = 1/(1/k_c + sum C a e^-aR); with Q = sum C a^2 e^-aR, dT/dg = T^3 Q and
    d2T/dg2 = 3 T^5 Q^2 - T^4 sum C a^3 e^-aR. The FD steps (<= 1.25e-7 m) are below 1 %
    of every closed closure here, so the values at R bound them to that.
    """
    k_c = law[0]
    e = np.exp(-law[[2, 4]] * R)
    C, a = law[[1, 3]], law[[2, 4]]
    T = 1.0 / (1.0 / k_c + np.sum(C * a * e))
    Q = np.sum(C * a ** 2 * e)
    first = T ** 3 * Q
    second = 3 * T ** 5 * Q ** 2 + T ** 4 * np.sum(C * a ** 3 * e)
    return 0.5 * min(k_c / first, math.sqrt(k_c / second))  # 0.5: the 1 % drift, generously


def term_functions(fabric, anchors, limit):
    """name -> (energy(r), gradient(r), dense Hessian(r), K [N/m], ell [m]).

    K: contact k_c (the tangent bound, docs/model.md section 10); friction k_t; the whole model adds
    the stretch springs 2 EA/l0 and bending 16 EI/(lbar l0^2) (tests/test_terms.py).
    The friction term's gradient is the assembly's (`assembly.gradient`, which computes it
    for the whole model): the whole model's minus the whole model's with F_T = 0, where the
    Huber term vanishes; its energy and Hessian are `dynfab.model.fabric.friction`'s own.
    ell: contact, from the law at each closed crossing's force (`contact_length_scale`);
    friction, the
    sliding branch F|s| has derivatives of order n bounded by about F/|s|^(n-1) <= k_t/|s|^(n-2)
    (k_t |s| >= F), so ell = min |s| / 3 over the sliding crossings (the sticking branch
    is quadratic); the whole model the smallest of these and l0.
    """
    law = uniform(fabric.tie_contact_law)
    a, b = fabric.tie_a, fabric.tie_b
    n_dof = fabric.rest_position.size
    kt = stick_stiffness(fabric)
    px, py = fabric.tie_plane.T.copy()  # the planes as woven (planes "fixed")
    zero = np.zeros_like(limit)

    def contact_energy(r):
        return contact.energy(r, fabric)

    def contact_grad(r):
        out = np.zeros_like(r)
        contact.add_gradient(r, fabric, out)
        return out

    def contact_hess(r):
        t = np.zeros(a.size)
        contact.tangents(r, fabric, t)
        H = np.zeros((n_dof, n_dof))
        for c in range(a.size):
            za, zb = 2 * a[c] + 1, 2 * b[c] + 1
            H[za, za] += t[c]
            H[zb, zb] += t[c]
            H[za, zb] -= t[c]
            H[zb, za] -= t[c]
        return H

    def friction_energy(r):
        return friction.energy(r, anchors, fabric, px, py, limit)

    def friction_grad(r):
        with_friction, without = np.zeros_like(r), np.zeros_like(r)
        assembly.gradient(r, fabric, P, anchors, limit, with_friction)
        assembly.gradient(r, fabric, P, anchors, zero, without)
        return with_friction - without

    def friction_hess(r):
        h = np.zeros((a.size, 3))
        friction.hessians(r, anchors, fabric, px, py, limit, h)
        H = np.zeros((n_dof, n_dof))
        for c in range(a.size):
            xa, yb = 2 * a[c], 2 * b[c]
            H[xa, xa] += h[c, 0]
            H[yb, yb] += h[c, 2]
            H[xa, yb] += h[c, 1]
            H[yb, xa] += h[c, 1]
        return H

    pattern = assembly.Pattern(fabric)
    terms = np.zeros(len(assembly.TERMS))

    def total_energy(r):
        return assembly.total_energy(r, fabric, P, anchors, limit, terms)

    def total_grad(r):
        out = np.zeros_like(r)
        assembly.gradient(r, fabric, P, anchors, limit, out)
        return out

    def total_hess(r):
        values = np.zeros(pattern.size)
        assembly.hessian_values(r, fabric, anchors, limit, values)
        return pattern.full_matrix(values)

    k_c = law[0]
    ell_contact = min(contact_length_scale(contact.force(g, law), law) for g, _ in
                      ((s * (law[1] + law[3]), 0) for s, _ in CROSSING_STATES) if g > 0)
    slips = np.array([SLIP[s] * max(F, 1e-3) / kt for (_, s), F in zip(CROSSING_STATES, limit)])
    ell_friction = slips[[s == "slide" for _, s in CROSSING_STATES]].min() / 3.0
    K_yarn = max(2 * WARP["EA"] / L0, 16 * WARP["EI"] / L0 ** 3,
                 2 * WEFT["EA"] / (WEFT["length"] / 8), 16 * WEFT["EI"] / (WEFT["length"] / 8) ** 3)
    return {
        "contact": (contact_energy, contact_grad, contact_hess, k_c, ell_contact),
        "friction": (friction_energy, friction_grad, friction_hess, kt, ell_friction),
        "whole": (total_energy, total_grad, total_hess, max(k_c, kt, K_yarn),
                  min(ell_contact, ell_friction, L0)),
    }


@pytest.fixture(scope="module")
def state():
    fabric = two_by_two_fabric()
    r, anchors, limit, g = perturbed_state(fabric)
    return fabric, r, anchors, limit, g


@pytest.fixture(scope="module", params=["periodic", "affine"])
def periodic_state(request):
    """The periodic cell (docs/model.md section 10): wrap springs at node 0, planes moving with the
    end nodes; or the clamped patch with planes "affine" (moving, no wrap). Every node
    perturbed (ends too: the FD runs over every dof)."""
    if request.param == "periodic":
        fabric = two_by_two_fabric(boundary="periodic")
    else:
        fabric = two_by_two_fabric(planes="affine")
    r, anchors, limit, g = perturbed_state(fabric)
    return fabric, r, anchors, limit, g


def periodic_terms(fabric, anchors, limit):
    """name -> (energy, gradient, dense Hessian, K, ell) of the periodic cell's own pieces.

    "wrap": the bending springs across the wrap alone (K = 16 EI/(lbar l^2) with l >= 0.85
    l0, as bending in tests/test_terms.py; ell = l0). "moving planes": the friction term
    with X_j, Y_k following the end nodes, isolated as the whole model minus the whole
    model with F_T = 0 (the Huber term vanishes there), K = k_t, ell as friction above.
    """
    pattern = assembly.Pattern(fabric)
    yarns = chain_count(fabric)
    n_dof = fabric.rest_position.size

    def wrap_energy(r):
        return sum(0.5 * fabric.wrap_stiffness[y]
                   * (assembly.wrap_angle(r, fabric, y) - fabric.wrap_rest_angle[y]) ** 2
                   for y in range(yarns))

    def wrap_grad(r):
        out = np.zeros_like(r)
        for y in range(yarns):
            assembly._add_wrap_gradient(r, fabric, y, out)
        return out

    def wrap_hess(r):
        H = np.zeros((n_dof, n_dof))
        for y in range(yarns):
            dofs, block = assembly.wrap_hessian(r, fabric, y)
            H[np.ix_(dofs, dofs)] += block
        return H

    zero = np.zeros_like(limit)
    terms = np.zeros(len(assembly.TERMS))

    def plane_energy(r):
        return (assembly.total_energy(r, fabric, P, anchors, limit, terms)
                - assembly.total_energy(r, fabric, P, anchors, zero, terms))

    def plane_grad(r):
        a, b = np.zeros_like(r), np.zeros_like(r)
        assembly.gradient(r, fabric, P, anchors, limit, a)
        assembly.gradient(r, fabric, P, anchors, zero, b)
        return a - b

    def plane_hess(r):
        a, b = np.zeros(pattern.size), np.zeros(pattern.size)
        assembly.hessian_values(r, fabric, anchors, limit, a)
        assembly.hessian_values(r, fabric, anchors, zero, b)
        return pattern.full_matrix(a - b)

    l_min = 0.85 * min(L0, WEFT["length"] / WEFT["segments"])
    K_wrap = 16 * max(WARP["EI"], WEFT["EI"]) / (0.5 * l_min) / l_min ** 2
    friction_entry = term_functions(fabric, anchors, limit)["friction"]
    return {"wrap": (wrap_energy, wrap_grad, wrap_hess, K_wrap, l_min),
            "moving planes": (plane_energy, plane_grad, plane_hess, *friction_entry[3:])}


@pytest.mark.parametrize("term", ["wrap", "moving planes"])
def test_periodic_cell_terms_against_finite_differences(periodic_state, term):
    # As the gradient and Hessian tests above (same steps and tolerance rule), on the
    # periodic cell's own pieces: the wrap spring's chain rule over four nodes, and the
    # slip's dependence on the end nodes that carry the moving planes (also on the patch
    # with planes "affine", their mean displacement).
    fabric, r, anchors, limit, _ = periodic_state
    if term == "wrap" and not fabric.wrap_stiffness.any():
        pytest.skip("a clamped patch has no wrap springs")
    assert fabric.tie_plane_weight[:, 0].min() > 0
    assert fabric.plane_nodes_a.size == 2 and fabric.plane_nodes_b.size == 2
    energy, grad, hess, K, ell = periodic_terms(fabric, anchors, limit)[term]
    expected = fd_gradient(energy, r, H_GRAD)
    S = r.size * abs(energy(r)) + np.sum(np.abs(expected) * np.abs(r))
    tolerance = 10 * (EPS * S / H_GRAD + H_GRAD ** 2 * K / (6 * ell))
    assert np.abs(expected).max() > 1e3 * tolerance
    assert np.abs(grad(r) - expected).max() <= tolerance
    h = min(H_HESS, 0.01 * ell)
    expected = fd_jacobian(grad, r, h)
    tolerance = 10 * (EPS * K * np.abs(r).max() / h + h ** 2 * K / (6 * ell ** 2))
    assert np.abs(expected).max() > 1e3 * tolerance
    assert np.abs(hess(r) - expected).max() <= tolerance
    if term == "moving planes":  # the end nodes are in it: x_N of warp 0 feels the slips
        end = 2 * (fabric.chain_start[1] - 1)  # (k_t w / n_wa, split over the warps' ends)
        assert np.abs(expected[end]).max() > 100 * tolerance


@pytest.mark.parametrize("term", ["contact", "friction", "whole"])
def test_gradient_is_the_derivative_of_the_energy(state, term):
    # dE/dr_i = (E(r + h e_i) - E(r - h e_i)) / 2h + O(h^2 K/ell) + O(eps S/h) (module
    # docstring: h = 1e-6 l0, tolerance 10 x (rounding + truncation)).
    fabric, r, anchors, limit, _ = state
    energy, grad, _, K, ell = term_functions(fabric, anchors, limit)[term]
    expected = fd_gradient(energy, r, H_GRAD)
    S = r.size * abs(energy(r)) + np.sum(np.abs(expected) * np.abs(r))
    tolerance = 10 * (EPS * S / H_GRAD + H_GRAD ** 2 * K / (6 * ell))
    assert np.abs(expected).max() > 1e3 * tolerance  # a test of something
    assert np.abs(grad(r) - expected).max() <= tolerance


@pytest.mark.parametrize("term", ["contact", "friction", "whole"])
def test_hessian_is_the_derivative_of_the_gradient(state, term):
    # d2E/dr_i dr_j = (g_i(r + h e_j) - g_i(r - h e_j)) / 2h + O(h^2 K/ell^2) + O(eps K r/h),
    # the whole matrix (entries the pattern lacks must be 0 in the differences too);
    # h = 1e-5 l0 (module docstring), or 0.01 ell where the slip scale ell is shorter (the
    # sliding Huber branch varies over |s|, a few micrometres here).
    fabric, r, anchors, limit, _ = state
    _, grad, hess, K, ell = term_functions(fabric, anchors, limit)[term]
    h = min(H_HESS, 0.01 * ell)
    expected = fd_jacobian(grad, r, h)
    tolerance = 10 * (EPS * K * np.abs(r).max() / h + h ** 2 * K / (6 * ell ** 2))
    assert np.abs(expected).max() > 1e3 * tolerance
    assert np.abs(hess(r) - expected).max() <= tolerance


def test_states_exercise_every_regime(state):
    # The FD checks above cover what they claim: the Huber block is k_t I exactly where
    # k_t |s| < F_T (sticking), rank one (zero along the slip) where sliding, zero where
    # open (F_T = 0); the contact tangent is > 0 and <= k_c on closed crossings, 0 on the
    # open one.
    fabric, r, anchors, limit, g = state
    kt = stick_stiffness(fabric)
    h = np.zeros((limit.size, 3))
    px, py = fabric.tie_plane.T.copy()
    friction.hessians(r, anchors, fabric, px, py, limit, h)
    t = np.zeros(limit.size)
    contact.tangents(r, fabric, t)
    for c, (_, regime) in enumerate(CROSSING_STATES):
        block = np.array([[h[c, 0], h[c, 1]], [h[c, 1], h[c, 2]]])
        if regime == "stick":
            assert np.array_equal(block, kt * np.eye(2))
        elif regime == "slide":
            # (F/|s|)(I - s s^T/|s|^2): eigenvalues 0 and F/|s| (to rounding of F/|s|)
            w = np.linalg.eigvalsh(block)
            s_norm = SLIP["slide"] * limit[c] / kt
            assert abs(w[0]) <= 8 * EPS * w[1]
            assert w[1] == pytest.approx(limit[c] / s_norm, rel=1e-12)
        else:
            assert not block.any()
        assert (t[c] > 0) == (g[c] > 0) and t[c] <= fabric.tie_contact_law[c, 0]


def test_contact_pushes_the_two_nodes_apart_by_sigma_r(state):
    # docs/model.md section 10: the force on the warp node is +sigma R in z, on the weft node -sigma
    # R, R from the series law at g: -grad equals that to the rounding of R.
    fabric, r, _, _, g = state
    grad = np.zeros_like(r)
    contact.add_gradient(r, fabric, grad)
    for c in range(g.size):
        law = fabric.tie_contact_law[c]
        R = contact.force(g[c], law)
        assert (R > 0) == (g[c] > 0)
        if R > 0:  # the series law holds at R (Newton's stopping rule: a few eps of g)
            assert closure_from_force(R, law) == pytest.approx(g[c], rel=1e-14)
        assert -grad[fabric.tie_a[c], 1] == pytest.approx(fabric.tie_side[c] * R, rel=4 * EPS)
        assert -grad[fabric.tie_b[c], 1] == pytest.approx(-fabric.tie_side[c] * R, rel=4 * EPS)


def test_without_a_core_spring_kawabata_is_a_hard_wall():
    # k_c = inf (docs/model.md section 10): the closure C_wa + C_we is the wall. Just below it the
    # force solves C_wa (1 - e^-a_wa R) + C_we (1 - e^-a_we R) = g (to the rounding of g) and is
    # large but finite; at and beyond it the energy is +inf, so a line search rejects it.
    fabric = two_by_two_fabric(core_stiffness=np.inf)
    law = uniform(fabric.tie_contact_law)
    wall = law[1] + law[3]
    assert contact.wall(law) == wall
    for fraction in (0.5, 1 - 1e-6, 1 - 1e-12):
        g = fraction * wall
        R = contact.force(g, law)
        assert np.isfinite(R) and R > 0
        assert closure_from_force(R, law) == pytest.approx(g, rel=1e-14)
        assert np.isfinite(contact.crossing_energy(g, law))
    for g in (wall, 1.01 * wall):
        assert contact.crossing_energy(g, law) == np.inf
    r, anchors, limit, _ = perturbed_state(two_by_two_fabric())  # crossing 1 sits past the wall
    assert assembly.total_energy(r, fabric, P, anchors, limit, np.zeros(len(assembly.TERMS))) == np.inf


def test_the_slips_the_newton_watches_are_the_huber_terms_slips(state):
    """`assembly.crossing_slips` (what `dynfab.solvers.newton_sparse.kinked` reads) gives each
    crossing's (s_x, s_y) as the Huber term sees it: sticking crossings within the stick
    radius F_T / k_t, sliding ones beyond it by their CROSSING_STATES factor."""
    fabric, r, anchors, limit, _ = state
    kt = stick_stiffness(fabric)
    slips = np.zeros((limit.size, 3))
    assembly.crossing_slips(r, fabric, anchors, slips)
    px, py = fabric.tie_plane.T.copy()
    for c, (_, regime) in enumerate(CROSSING_STATES):
        assert tuple(slips[c, :2]) == friction.slip(r, anchors, fabric, px, py, c)
        assert slips[c, 2] == 0.0
        if regime == "stick":
            assert kt * np.linalg.norm(slips[c]) < limit[c]
        elif regime == "slide":
            assert np.linalg.norm(slips[c]) == pytest.approx(SLIP["slide"] * limit[c] / kt,
                                                             rel=1e-12)
