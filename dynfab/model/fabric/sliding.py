"""The energy, gradient and sparse Hessian of a fabric whose crossings slide along the yarns
(docs/model.md 11.13), on the structure's dofs (`dynfab.model.builders.sliding`), planar or
spatial.

The elastic terms, the contact, the loads, the rotation spring and the lateral contacts are
the fixed crossings' own (`dynfab.model.fabric.assembly` in the plane,
`dynfab.model.fabric.spatial` in space: the base term set), evaluated at the physical
positions (`physical`: each dof where it is a coordinate, a sliding crossing's nodes where the
crossing is) with each segment's rest length and each spring's stiffness those of the
material in it now (`current`):

    E_s = 1/2 EA (l_s - L_s)^2 / L_s,      L_s = f_s (u_R - u_L),                  (11.13a)
    E_i = E_i(r; EI / lbar_i, EI_lateral / lbar_i),   lbar_i = (L_{i-1} + L_i) / 2,  (11.13b)

u_L, u_R the material coordinates of the segment's bay ends, f_s its share of the bay; the
dofs hold their slides delta = u - U from the woven U (`dynfab.model.builders.sliding`), so
L_s = base_s + f_s (delta_R - delta_L), each slide a crossing's dof or a chain end's constant, E_i a node's bending (in space, out of and in the
plane), inversely proportional to lbar_i. Their gradient on the dofs is the physical gradient
pulled back (`Structure.physical_source`) plus the material part dE/dL dL/du, with

    dE_s/dL = EA (L^2 - l^2) / (2 L^2),  d2E_s/dl dL = -EA l / L^2,  d2E_s/dL2 = EA l^2 / L^3,
    dE_i/dlbar = -E_i / lbar,  d2E_i/dr dlbar = -(dE_i/dr) / lbar,  d2E_i/dlbar2 = 2 E_i / lbar^2,

dL/du = (-f, +f) and dlbar/dL = 1/2, each linear in u; the Hessian adds those mixed and
material blocks (`_material_entries`, `_elastic_material_values`, `_friction_values`, in one
order; each node's mixed entries summed over its elements before they are emitted, so that
the sparse sum has few duplicates to merge). Friction acts on the
slip of the material through the crossing measured in space, and in space on the crossing's
rotation as a fixed crossing's (`dynfab.model.terms.spatial` (d)):

    S = (lambda_a (u_a - xi_a), lambda_b (u_b - xi_b), rho wrap(phi - phi_anchor)),   (11.13c)

lambda_k the mean stretch of the two segments at the crossing's node on yarn k at the step's
start (held through the step with the anchors: `with_stretches`), phi the in-plane angle
from the warp's chord to the weft's (0 in the plane, where S has two components): so
Gralen's F_T is a force in space, as the fixed crossing's, and the tension jumps by F_T across
a sliding crossing (its material balance, the jump of the Eshelby force W - lambda T =
-T (1 + (lambda - 1) / 2) per unit of u, is F_T lambda), a yarn pulled through crossings
carrying the sum of their limits. Huber's law (`dynfab.model.terms.spatial.huber3`, the one
law of every slip) on S; its block on the two material dofs and, in space, the in-plane
coordinates of the crossing's stencil. A bay whose material runs out (L <= 0: two crossings
meeting, or a yarn end reaching its last crossing before it leaves it) has energy +inf, which
the line searches refuse.

The anchors of a step (`with_stretches`): (xi_a, xi_b, lambda_a, lambda_b) per tie, and in
space phi_anchor after them (`ROTATION`); a state keeps (xi_a, xi_b[, phi_anchor])
(`state_anchors`).
"""

from __future__ import annotations

import numba
import numpy as np
import scipy.sparse

from dynfab.model.fabric import assembly, spatial
from dynfab.model.fabric.assembly import Pattern, kept_pattern, secant_weights
from dynfab.model.structure import Structure, dim
from dynfab.model.terms import bending
from dynfab.model.terms import huber as huber_law
from dynfab.model.terms import spatial as element

CONTACT, FRICTION, STRETCH = assembly.CONTACT, assembly.FRICTION, assembly.STRETCH
"""Indices of the energy vector, the same in both base term sets."""
STRETCHES = (2, 3)
"""The step anchors' columns of lambda_a, lambda_b (11.13c)."""
ROTATION = 4
"""The step anchors' column of phi_anchor [rad] (spatial)."""
STICK = 3
"""Column of k_t [N/m] in `tie_friction_law`."""
STENCIL_IN_PLANE = 12
"""The in-plane coordinates of a spatial crossing's stencil (6 nodes, x and y) its rotation
acts on."""


BASE = {2: assembly, 3: spatial}
"""The fixed crossings' term set (the base) of each dimension of the structure's nodes."""


def _base(s: Structure):
    """The base term set of the structure's kinematics (`BASE`)."""
    return BASE[dim(s)]


# ----------------------------------------------------------------------- kinematics


@numba.njit(cache=True)
def _plane_nodes(s, side):
    """The plane nodes whose mean displacement moves the planes of the ties' side `side`
    (0: node a's, 1: node b's; `Structure.plane_nodes_a`, `plane_nodes_b`)."""
    return s.plane_nodes_a if side == 0 else s.plane_nodes_b


@numba.njit(cache=True)
def _moving_planes(s, coordinate, weight):
    """Fill (coordinate, weight) (T, 2): the physical coordinate of each tie's node a (column
    0) and b (1) and its weight w [-] where the crossing holds that coordinate on a plane that
    moves (`Structure.tie_plane_weight`), else (-1, 0); returns whether any does."""
    d = s.rest_position.shape[1]
    moving = False
    for c in range(s.tie_a.size):
        for side in range(2):
            node = s.tie_a[c] if side == 0 else s.tie_b[c]
            w = s.tie_plane_weight[c, side]
            coordinate[c, side], weight[c, side] = -1, 0.0
            if node >= 0 and s.physical_source[d * node] < 0 and w != 0.0 \
                    and _plane_nodes(s, side).size > 0:
                coordinate[c, side], weight[c, side] = d * node, w
                moving = True
    return moving


def moving_planes(s: Structure) -> tuple[np.ndarray, np.ndarray] | None:
    """`_moving_planes`' (coordinate, weight), or None where no crossing's node is on a plane
    that moves."""
    if not (s.plane_nodes_a.size or s.plane_nodes_b.size):
        return None
    coordinate = np.empty((s.tie_a.size, 2), np.int64)
    weight = np.empty((s.tie_a.size, 2))
    return (coordinate, weight) if _moving_planes(s, coordinate, weight) else None


@numba.njit(cache=True)
def _physical(dofs, s, out):
    """out = the physical positions (n, dim) of the dofs (module docstring): each coordinate
    from the dof that holds it, or its as-woven value where a crossing holds it on its plane
    (`_move_with_planes` moves it where that plane moves)."""
    flat, rest, o = dofs.reshape(-1), s.rest_position.reshape(-1), out.reshape(-1)
    for d in range(o.size):
        source = s.physical_source[d]
        o[d] = flat[source] if source >= 0 else rest[d]


@numba.njit(cache=True)
def _move_with_planes(flat, rest, d, nodes_a, nodes_b, coordinate, weight, out):
    """out[coordinate] += w U for each crossing's node on a moving plane (X + w U, U the mean
    displacement of the plane nodes along their chains; docs/model.md section 10, 11.13)."""
    shift = np.zeros(2)
    for side in range(2):
        nodes = nodes_a if side == 0 else nodes_b
        for m in nodes:
            shift[side] += (flat[d * m] - rest[d * m]) / nodes.size
    o = out.reshape(-1)
    for c in range(coordinate.shape[0]):
        for side in range(2):
            if coordinate[c, side] >= 0:
                o[coordinate[c, side]] += weight[c, side] * shift[side]


@numba.njit(cache=True)
def _bay_end(flat, material, end, k, side):
    """The slide [m] of side 0 (left) or 1 (right) of segment k's bay
    (`Structure.segment_material`, `segment_material_end`; arrays, not the structure: a
    structure passed to a function called in a loop costs about 0.5 us a call)."""
    index = material[k, side]
    return flat[index] if index >= 0 else end[k, side]


@numba.njit(cache=True)
def _rest_lengths(dofs, s, out):
    """out = L_s = base_s + f_s (delta_R - delta_L) (n - Y,) [m] (11.13a)."""
    flat = dofs.reshape(-1)
    material, end = s.segment_material, s.segment_material_end
    for k in range(out.size):
        out[k] = s.segment_base[k] + s.segment_fraction[k] * (
            _bay_end(flat, material, end, k, 1) - _bay_end(flat, material, end, k, 0))


def physical(dofs, s: Structure) -> np.ndarray:
    """The physical positions (n, dim) [m] of the dofs."""
    out = np.empty(s.rest_position.shape)
    dofs = np.ascontiguousarray(dofs, float)
    _physical(dofs, s, out)
    planes = moving_planes(s)
    if planes is not None:
        _move_with_planes(dofs.reshape(-1), s.rest_position.reshape(-1), dim(s),
                          s.plane_nodes_a, s.plane_nodes_b, *planes, out)
    return out


def rest_lengths(dofs, s: Structure) -> np.ndarray:
    """Each segment's rest length now, L_s (n - Y,) [m] (11.13a)."""
    out = np.empty(s.rest_length.size)
    _rest_lengths(np.ascontiguousarray(dofs, float), s, out)
    return out


@numba.njit(cache=True)
def _material_now(dofs, s, L, stretch, bend, lateral):
    """Each segment's rest length L (11.13a) and stiffness EA / L, each node's bending
    stiffnesses EI / lbar and (in space) EI_lateral / lbar (11.13b); False where a bay has run
    out of material (L <= 0)."""
    _rest_lengths(dofs, s, L)
    start = s.chain_start
    in_plane = s.lateral_bend_modulus.size > 0
    for y in range(start.size - 1):
        for k in range(start[y] - y, start[y + 1] - y - 1):
            if not L[k] > 0.0:
                return False
            stretch[k] = s.stretch_modulus[k] / L[k]
        for i in range(start[y] + 1, start[y + 1] - 1):
            lbar = 0.5 * (L[i - 1 - y] + L[i - y])
            bend[i] = s.bend_modulus[i] / lbar
            if in_plane:
                lateral[i] = s.lateral_bend_modulus[i] / lbar
        bend[start[y]] = bend[start[y + 1] - 1] = 0.0
        if in_plane:
            lateral[start[y]] = lateral[start[y + 1] - 1] = 0.0
    return True


def _wrap_ends(s: Structure, y: int) -> tuple[int, int]:
    """(first, last) segment of chain y: the two that meet at a periodic chain's wrap."""
    return int(s.chain_start[y] - y), int(s.chain_start[y + 1] - y - 2)


def _wrap_stiffness_now(s: Structure, L: np.ndarray) -> np.ndarray:
    """EI / lbar_0 of each periodic chain's wrap spring (Y,) [N m], lbar_0 = (L_first +
    L_last) / 2 of the material now (11.13b at the wrap, node 0, where segment N-1's image
    meets segment 0); the as-woven EI / lbar_0 (`Structure.wrap_stiffness`) gives EI."""
    k = np.array(s.wrap_stiffness, float)
    for y in np.flatnonzero(k > 0.0):
        first, last = _wrap_ends(s, y)
        k[y] *= (s.rest_length[first] + s.rest_length[last]) / (L[first] + L[last])
    return k


def current(dofs, s: Structure) -> Structure | None:
    """The structure of the material as it lies now: each segment's rest length L_s and
    stiffness EA / L_s, each node's bending stiffnesses over lbar_i (11.13b; 0 at a chain's
    ends), friction left to this module (`has_friction` False); None where a bay has run out
    of material (L <= 0)."""
    L, stretch = np.empty(s.rest_length.size), np.empty(s.rest_length.size)
    bend = np.empty(s.bend_modulus.size)
    lateral = np.empty(s.lateral_bend_modulus.size)
    if not _material_now(np.ascontiguousarray(dofs, float), s, L, stretch, bend, lateral):
        return None
    fields = dict(rest_length=L, stretch_stiffness=stretch, bend_stiffness=bend,
                  wrap_stiffness=_wrap_stiffness_now(s, L), has_friction=False)
    if lateral.size:
        fields["lateral_bend_stiffness"] = lateral
    return s._replace(**fields)


@numba.njit(cache=True)
def _length(pos, i):
    """|r_{i+1} - r_i| [m] in any dimension."""
    total = 0.0
    for k in range(pos.shape[1]):
        e = pos[i + 1, k] - pos[i, k]
        total += e * e
    return np.sqrt(total)


@numba.njit(cache=True)
def _planar_bends(pos, now, energy, grad):
    """Each inner node's bending energy E_i [J] and, where grad has rows, its gradient on
    (r_{i-1}, r_i, r_{i+1}) (n, 6) [N] in the plane: 1/2 EI / lbar (phi - phi0)^2
    (docs/model.md section 2)."""
    start = now.chain_start
    g = np.empty(6)
    for y in range(start.size - 1):
        for i in range(start[y] + 1, start[y + 1] - 1):
            d = bending.turning_angle(pos, i) - now.rest_angle[i]
            energy[i] = 0.5 * now.bend_stiffness[i] * d * d
            if grad.shape[0]:
                bending._angle_gradient(pos, i, g)
                for m in range(6):
                    grad[i, m] = now.bend_stiffness[i] * d * g[m]


@numba.njit(cache=True)
def _spatial_bends(pos, now, energy, grad):
    """`_planar_bends` in space (n, 9): the bending out of and in the plane
    (`dynfab.model.terms.spatial` (b))."""
    start = now.chain_start
    g = np.empty(9)
    for y in range(start.size - 1):
        for i in range(start[y] + 1, start[y + 1] - 1):
            X = pos[i - 1:i + 2]
            kb, kl = now.bend_stiffness[i], now.lateral_bend_stiffness[i]
            theta0, psi0 = now.rest_angle[i], now.lateral_rest_angle[i]
            if grad.shape[0]:
                energy[i] = element.bend_gradient(X, kb, theta0, kl, psi0, g)
                grad[i] = g
            else:
                energy[i] = element.bend_energy(X, kb, theta0, kl, psi0)


BENDS = {2: _planar_bends, 3: _spatial_bends}
"""Each node's bending and its gradient (`_bends`) for each dimension of the nodes."""


def _bends(pos, now: Structure, gradients: bool = True) -> tuple[np.ndarray, np.ndarray]:
    """(E_i (n,) [J], where `gradients` dE_i/dr on its three nodes (n, 3 dim) [N]) of every
    node's bending."""
    d = pos.shape[1]
    energy = np.zeros(pos.shape[0])
    grad = np.zeros((pos.shape[0] if gradients else 0, 3 * d))
    BENDS[d](pos, now, energy, grad)
    return energy, grad


# ----------------------------------------------------------------------- friction (11.13c)


@numba.njit(cache=True)
def _crossing_slip(pos, flat, tie_material, stencil, rotation_law, anchors, c, S):
    """S (3,) of tie c (11.13c): each yarn's material slip from its anchor times its stretch
    at the step's start; in space (`stencil` with rows) the rotation's rho wrap(phi -
    phi_anchor), else 0."""
    S[0] = anchors[c, 2] * (flat[tie_material[c, 0]] - anchors[c, 0])
    S[1] = anchors[c, 3] * (flat[tie_material[c, 1]] - anchors[c, 1])
    S[2] = 0.0
    if stencil.shape[0]:
        six, q = np.empty((6, 3)), np.empty(3)
        for m in range(6):
            six[m] = pos[stencil[c, m]]
        element.crossing_coordinates(six, q)
        S[2] = rotation_law[c, 0] * element.wrap(q[2] - anchors[c, ROTATION])


@numba.njit(cache=True)
def _friction_energy(pos, dofs, s, anchors, limit):
    """sum_c Huber(S_c) [J] (11.13c), F_T frozen."""
    flat = dofs.reshape(-1)
    S = np.empty(3)
    total = 0.0
    for c in range(s.tie_a.size):
        _crossing_slip(pos, flat, s.tie_material, s.tie_stencil, s.tie_rotation_law, anchors,
                       c, S)
        total += element.huber3(S, limit[c], s.tie_friction_law[c, STICK])
    return total


@numba.njit(cache=True)
def _rotation_jacobian(pos, stencil, c, J2, K2):
    """dphi/dX (12,) and d2phi/dX2 (12, 12) of tie c on its stencil's in-plane coordinates
    (node-major, x then y; `dynfab.model.terms.spatial.crossing_kinematics`)."""
    six, q = np.empty((6, 3)), np.empty(3)
    J, K = np.empty((3, 18)), np.empty((3, 18, 18))
    for m in range(6):
        six[m] = pos[stencil[c, m]]
    element.crossing_kinematics(six, q, J, K)
    for a in range(6):
        for i in range(2):
            J2[2 * a + i] = J[2, 3 * a + i]
            for b in range(6):
                for j in range(2):
                    K2[2 * a + i, 2 * b + j] = K[2, 3 * a + i, 3 * b + j]


@numba.njit(cache=True)
def _add_friction_gradient(pos, dofs, s, anchors, limit, grad, physical_grad):
    """grad += lambda_0 dHuber/dS on each tie's two material dofs, physical_grad += rho
    dHuber/dS_3 dphi/dr on its stencil in space (11.13c)."""
    flat, out = dofs.reshape(-1), grad.reshape(-1)
    S, f = np.empty(3), np.empty(3)
    J2, K2 = np.empty(STENCIL_IN_PLANE), np.empty((STENCIL_IN_PLANE, STENCIL_IN_PLANE))
    for c in range(s.tie_a.size):
        _crossing_slip(pos, flat, s.tie_material, s.tie_stencil, s.tie_rotation_law, anchors,
                       c, S)
        element.huber3_gradient(S, limit[c], s.tie_friction_law[c, STICK], f)
        out[s.tie_material[c, 0]] += anchors[c, 2] * f[0]
        out[s.tie_material[c, 1]] += anchors[c, 3] * f[1]
        if s.tie_stencil.shape[0] and f[2] != 0.0:
            _rotation_jacobian(pos, s.tie_stencil, c, J2, K2)
            moment = s.tie_rotation_law[c, 0] * f[2]
            for a in range(6):
                for i in range(2):
                    physical_grad[s.tie_stencil[c, a], i] += moment * J2[2 * a + i]


# ----------------------------------------------------------------------- energy and gradient


def total_energy(dofs, s: Structure, P, anchors, limit, out) -> float:
    """V [J] at the dofs (its terms left in out, the base term set's TERMS), F_T = `limit`
    frozen; +inf where a bay has run out of material."""
    now = current(dofs, s)
    out[:] = 0.0
    if now is None:
        out[STRETCH] = np.inf
        return np.inf
    pos = physical(dofs, s)
    _base(s).energies(pos, now, P, _base_anchors(anchors, s), np.zeros(s.tie_a.size), out)
    if s.has_friction:
        out[FRICTION] = _friction_energy(pos, np.ascontiguousarray(dofs, float), s, anchors,
                                         limit)
    return float(out.sum())


def _base_anchors(anchors, s: Structure) -> np.ndarray:
    """Anchors of the base term set's shape, for its terms that do not read them (its
    friction is off: F_T = 0)."""
    return np.zeros((s.tie_a.size, dim(s)))  # (T, 2) planar, (T, 3) spatial


def energy_vector(s: Structure, dofs, P, anchors, limit) -> np.ndarray:
    """Each term's energy [J] (the base term set's TERMS) at the dofs, F_T = `limit` frozen."""
    out = np.zeros(len(_base(s).TERMS))
    total_energy(dofs, s, np.asarray(P, float), anchors, limit, out)
    return out


@numba.njit(cache=True)
def _pull_back(physical_grad, s, grad):
    """grad += the physical gradient on the dofs that hold each coordinate."""
    g, o = physical_grad.reshape(-1), grad.reshape(-1)
    for d in range(g.size):
        if s.physical_source[d] >= 0:
            o[s.physical_source[d]] += g[d]


@numba.njit(cache=True)
def _pull_back_planes(physical_grad, d, nodes_a, nodes_b, coordinate, weight, grad):
    """grad += on each plane node w / (their count) of the physical gradient on each crossing
    node its plane moves (`_move_with_planes`)."""
    g, o = physical_grad.reshape(-1), grad.reshape(-1)
    for c in range(coordinate.shape[0]):
        for side in range(2):
            if coordinate[c, side] >= 0:
                nodes = nodes_a if side == 0 else nodes_b
                for m in nodes:
                    o[d * m] += weight[c, side] / nodes.size * g[coordinate[c, side]]


def pull_back(physical_grad, s: Structure, grad) -> None:
    """grad += the physical gradient on the dofs that hold each coordinate and on the plane
    nodes that move a crossing's plane (`physical`)."""
    _pull_back(physical_grad, s, grad)
    planes = moving_planes(s)
    if planes is not None:
        _pull_back_planes(physical_grad, dim(s), s.plane_nodes_a, s.plane_nodes_b, *planes,
                          grad)


@numba.njit(cache=True)
def _add_to_bay(flat, material, fraction, k, value):
    """flat += value dL_k/du on segment k's bay ends (dL/du_R = f, dL/du_L = -f)."""
    f = fraction[k]
    if material[k, 0] >= 0:
        flat[material[k, 0]] -= value * f
    if material[k, 1] >= 0:
        flat[material[k, 1]] += value * f


@numba.njit(cache=True)
def _add_material_gradient(pos, L, s, bend_energy, grad):
    """grad += the material part of the elastic terms' gradient (module docstring); L the
    rest lengths now, bend_energy each node's E_i."""
    flat = grad.reshape(-1)
    start, material, fraction = s.chain_start, s.segment_material, s.segment_fraction
    for y in range(start.size - 1):
        a, b = start[y], start[y + 1]
        for i in range(a, b - 1):
            k = i - y
            l = _length(pos, i)
            _add_to_bay(flat, material, fraction, k,
                        0.5 * s.stretch_modulus[k] * (L[k] * L[k] - l * l) / (L[k] * L[k]))
        for i in range(a + 1, b - 1):
            lbar = 0.5 * (L[i - 1 - y] + L[i - y])
            _add_to_bay(flat, material, fraction, i - 1 - y, -0.5 * bend_energy[i] / lbar)
            _add_to_bay(flat, material, fraction, i - y, -0.5 * bend_energy[i] / lbar)


def _wrap_gradients(pos, now: Structure):
    """[(chain, E_w [J], lbar_0 [m], dE_w/dr on its 8 coordinates (8,) [N])] of every
    periodic chain's wrap spring (`assembly.wrap_gradient`; its coordinates
    `_wrap_coordinates`), lbar_0 its material's now (`_wrap_stiffness_now`)."""
    out = []
    for y in np.flatnonzero(now.wrap_stiffness > 0.0):
        grad = np.empty(8)
        energy = assembly.wrap_gradient(pos, now, y, grad)
        first, last = _wrap_ends(now, y)
        out.append((y, energy, 0.5 * (now.rest_length[first] + now.rest_length[last]), grad))
    return out


def _add_wrap_material_gradient(wraps, s: Structure, grad) -> None:
    """grad += dE_w/dlbar_0 dlbar_0/du of each wrap spring, dE_w/dlbar_0 = -E_w / lbar_0 and
    dlbar_0/dL = 1/2 on its two segments (11.13b at the wrap)."""
    flat = grad.reshape(-1)
    for y, energy, lbar, _ in wraps:
        for k in _wrap_ends(s, y):
            _add_to_bay(flat, s.segment_material, s.segment_fraction, k, -0.5 * energy / lbar)


def gradient(dofs, s: Structure, P, anchors, limit, grad) -> None:
    """grad = dV/d(dofs) (n, dim) [N, and N for the slides' J/m], F_T frozen."""
    now = current(dofs, s)
    if now is None:  # a bay has run out of material: no gradient (the energy is +inf)
        grad[:] = np.nan
        return
    dofs = np.ascontiguousarray(dofs, float)
    pos = physical(dofs, s)
    physical_grad = np.zeros_like(pos)
    _base(s).gradient(pos, now, np.asarray(P, float), _base_anchors(anchors, s),
                      np.zeros(s.tie_a.size), physical_grad)
    grad[:] = 0.0
    if s.has_friction:
        _add_friction_gradient(pos, dofs, s, anchors, limit, grad, physical_grad)
    pull_back(physical_grad, s, grad)
    _add_material_gradient(pos, now.rest_length, s, _bends(pos, now, False)[0], grad)
    _add_wrap_material_gradient(_wrap_gradients(pos, now), s, grad)


# ----------------------------------------------------------------------- the Hessian


@numba.njit(cache=True)
def _friction_dofs(s, c, out):
    """(in space the in-plane physical coordinates of tie c's stencil (`STENCIL_IN_PLANE`);
    the dofs of its u_a, u_b plus `material_offset`)."""
    m = 0
    if s.tie_stencil.shape[0]:
        for a in range(6):
            for i in range(2):
                out[m] = 3 * s.tie_stencil[c, a] + i
                m += 1
    offset = material_offset(s)
    out[m], out[m + 1] = s.tie_material[c, 0] + offset, s.tie_material[c, 1] + offset


@numba.njit(cache=True)
def material_offset(s):
    """The Hessian's entries name a physical coordinate p by p and a material dof m by this
    plus m (`SlidingPattern`): the physical coordinates' count."""
    return s.rest_position.size


@numba.njit(cache=True)
def _emit_square(local, size, rows, cols, e, offset=0):
    """(rows, cols) of a dense block on `local`'s first `size` entries plus `offset` (-1
    staying -1), row-major."""
    for p in range(size):
        for q in range(size):
            rows[e] = local[p] + offset if local[p] >= 0 else -1
            cols[e] = local[q] + offset if local[q] >= 0 else -1
            e += 1
    return e


@numba.njit(cache=True)
def _friction_size(s):
    """The dofs of one tie's friction block: its two material ones, in space with its
    stencil's in-plane coordinates before them."""
    return 2 + (STENCIL_IN_PLANE if s.tie_stencil.shape[0] else 0)


@numba.njit(cache=True)
def _bend_materials(s, k, out):
    """The material dofs the bending at the node between segments k - 1 and k reads (3,):
    k - 1's bay ends, then k's right one (its left being one of those), -1 at a chain's
    end."""
    out[0], out[1] = s.segment_material[k - 1, 0], s.segment_material[k - 1, 1]
    out[2] = s.segment_material[k, 1]


NODE_MATERIALS = 8
"""The most material dofs a node's elements read: both bay ends of its chain's segments
i - 2 .. i + 1."""


@numba.njit(cache=True)
def _node_materials(s, table):
    """Each node's material dofs into table (n, NODE_MATERIALS), -1 padded: the bay ends of
    the segments whose stretch or bending reads its position (its chain's segments
    i - 2 .. i + 1), each once: the columns of its mixed Hessian entries, merged over its
    elements. Returns the most any node has."""
    table[:, :] = -1
    start = s.chain_start
    count = 0
    for y in range(start.size - 1):
        for i in range(start[y], start[y + 1]):
            m = 0
            for k in range(max(i - 2, start[y]) - y, min(i + 2, start[y + 1] - 1) - y):
                for side in range(2):
                    dof = s.segment_material[k, side]
                    seen = dof < 0
                    for q in range(m):
                        seen = seen or table[i, q] == dof
                    if not seen:
                        table[i, m] = dof
                        m += 1
            count = max(count, m)
    return count


def node_materials(s: Structure) -> np.ndarray:
    """`_node_materials` as wide as the structure needs."""
    table = np.empty((s.rest_position.shape[0], NODE_MATERIALS), np.int64)
    count = _node_materials(s, table)
    return np.ascontiguousarray(table[:, :count])


@numba.njit(cache=True)
def _wrap_materials(s, y, out):
    """The material dofs the wrap spring of chain y reads (4,): its first segment's bay ends,
    then its last segment's, -1 at a chain's end."""
    first, last = s.chain_start[y] - y, s.chain_start[y + 1] - y - 2
    out[0], out[1] = s.segment_material[first, 0], s.segment_material[first, 1]
    out[2], out[3] = s.segment_material[last, 0], s.segment_material[last, 1]


@numba.njit(cache=True)
def _material_entries(s, d, table, wrap_coordinates, rows, cols):
    """(rows, cols) of every entry `_elastic_material_values`, `_wrap_values` and
    `_friction_values` fill, in their order, a physical coordinate by its index and a material
    dof offset by `material_offset` (-1 where a bay ends at a chain end): each node's mixed
    entries (its d coordinates against its material dofs `table`, both orders), each
    segment's and each inner node's material block (its bay ends' 2 x 2, its 3 x 3), each
    wrap spring's mixed entries (its 8 coordinates, rows of `wrap_coordinates`, against its
    4 material dofs, both orders) and material block (4 x 4), each tie's friction block."""
    start = s.chain_start
    offset = material_offset(s)
    local = np.empty(STENCIL_IN_PLANE + 2, np.int64)
    e = 0
    for i in range(table.shape[0]):
        for j in range(table.shape[1]):
            for c in range(d):
                material = table[i, j] + offset if table[i, j] >= 0 else -1
                rows[e], cols[e] = d * i + c, material
                rows[e + 1], cols[e + 1] = material, d * i + c
                e += 2
    for y in range(start.size - 1):
        for k in range(start[y] - y, start[y + 1] - y - 1):
            local[0], local[1] = s.segment_material[k, 0], s.segment_material[k, 1]
            e = _emit_square(local, 2, rows, cols, e, offset)
        for k in range(start[y] + 1 - y, start[y + 1] - y - 1):
            _bend_materials(s, k, local)
            e = _emit_square(local, 3, rows, cols, e, offset)
    w = 0
    for y in range(start.size - 1):
        if s.wrap_stiffness[y] > 0.0:
            _wrap_materials(s, y, local)
            for p in range(8):
                for q in range(4):
                    material = local[q] + offset if local[q] >= 0 else -1
                    rows[e], cols[e] = wrap_coordinates[w, p], material
                    rows[e + 1], cols[e + 1] = material, wrap_coordinates[w, p]
                    e += 2
            e = _emit_square(local, 4, rows, cols, e, offset)
            w += 1
    size = _friction_size(s)
    for c in range(s.tie_a.size):
        _friction_dofs(s, c, local)
        e = _emit_square(local, size, rows, cols, e)


WRAP_ENTRIES = 8 * 4 * 2 + 4 * 4
"""A wrap spring's material entries: its 8 coordinates against its 4 material dofs, both
orders, and their 4 x 4 block."""


def _material_entry_count(s: Structure, d: int, width: int) -> int:
    segments = s.rest_length.size
    inner = segments - (s.chain_start.size - 1)
    friction = _friction_size(s)
    return (s.rest_position.shape[0] * width * d * 2 + segments * 4 + inner * 9
            + int(np.count_nonzero(s.wrap_stiffness > 0.0)) * WRAP_ENTRIES
            + s.tie_a.size * friction * friction)


def _wrap_coordinates(s: Structure) -> np.ndarray:
    """The 8 physical coordinates of each periodic chain's wrap spring (W, 8), int64."""
    rows = [assembly.wrap_dofs_of(s, y) for y in np.flatnonzero(s.wrap_stiffness > 0.0)]
    return np.array(rows, np.int64).reshape(-1, 8)


@numba.njit(cache=True)
def _add_mixed(table, node, dofs, weights, count, gx, first, d, mixed):
    """mixed[node, slot of dofs[q], :] += gx[first:first + d] weights[q] for q < count (the
    mixed block gx gm^T of one element on one of its nodes, merged per node)."""
    for q in range(count):
        if dofs[q] < 0:
            continue
        j = 0
        while table[node, j] != dofs[q]:
            j += 1
        for c in range(d):
            mixed[node, j, c] += gx[first + c] * weights[q]


@numba.njit(cache=True)
def _put_square(weights, scale, count, values, e):
    """values[e:] = scale weights weights^T (count x count), row-major; the next entry."""
    for p in range(count):
        for q in range(count):
            values[e] = scale * weights[p] * weights[q]
            e += 1
    return e


@numba.njit(cache=True)
def _elastic_material_values(pos, L, s, bend_energy, bend_grad, table, values):
    """The stretch and bending terms' mixed and material Hessian entries (module docstring)
    in `_material_entries`' order; returns the next entry. Each element's mixed block
    d2E/dr dL dL/du = gx gm^T is summed on its nodes' rows (`_add_mixed`), its material
    block is hmm gm gm^T."""
    start, d = s.chain_start, pos.shape[1]
    n, width = table.shape
    mixed = np.zeros((n, width, d))
    gx, gm, dofs = np.empty(3 * d), np.empty(3), np.empty(3, np.int64)
    e = n * width * d * 2
    for y in range(start.size - 1):
        a, b = start[y], start[y + 1]
        for i in range(a, b - 1):
            k = i - y
            l = _length(pos, i)
            EA, f = s.stretch_modulus[k], s.segment_fraction[k]
            coupling = -EA * l / (L[k] * L[k])  # d2E/dl dL, times dl/dr = (-e, e) / l
            for m in range(d):
                unit = (pos[i + 1, m] - pos[i, m]) / l
                gx[m], gx[d + m] = -coupling * unit, coupling * unit
            gm[0], gm[1] = -f, f
            dofs[0], dofs[1] = s.segment_material[k, 0], s.segment_material[k, 1]
            for node in range(2):
                _add_mixed(table, i + node, dofs, gm, 2, gx, d * node, d, mixed)
            e = _put_square(gm, EA * l * l / (L[k] * L[k] * L[k]), 2, values, e)
        for i in range(a + 1, b - 1):
            k = i - y
            lbar = 0.5 * (L[k - 1] + L[k])
            for m in range(3 * d):
                gx[m] = -bend_grad[i, m] / lbar  # d2E/dr dlbar
            f0, f1 = 0.5 * s.segment_fraction[k - 1], 0.5 * s.segment_fraction[k]
            # dlbar/du on (k-1's left, k-1's right, k's right): k's left end is one of the
            # first two (an inner node of a bay: its left; a crossing's node: its right)
            inner = s.segment_material[k, 0] == s.segment_material[k - 1, 0]
            gm[0], gm[1], gm[2] = -f0 - f1 * inner, f0 - f1 * (not inner), f1
            _bend_materials(s, k, dofs)
            for node in range(3):
                _add_mixed(table, i - 1 + node, dofs, gm, 3, gx, d * node, d, mixed)
            e = _put_square(gm, 2.0 * bend_energy[i] / (lbar * lbar), 3, values, e)
    e0 = 0
    for i in range(n):
        for j in range(width):
            for c in range(d):
                values[e0] = values[e0 + 1] = mixed[i, j, c]
                e0 += 2
    return e


@numba.njit(cache=True)
def _friction_values(pos, dofs, s, anchors, limit, secant, values, e):
    """Each tie's friction block G^T A G + rho dHuber/dS_3 d2phi/dr2 (11.13c) in
    `_material_entries`' order from entry e, G = dS/d(its dofs), A = d2Huber/dS2 with the
    tie's secant weight (`dynfab.model.terms.spatial.huber3_hessian`)."""
    flat = dofs.reshape(-1)
    size = _friction_size(s)
    m = size - 2
    S, f, A = np.empty(3), np.empty(3), np.empty((3, 3))
    G = np.zeros((3, size))
    J2, K2 = np.zeros(STENCIL_IN_PLANE), np.zeros((STENCIL_IN_PLANE, STENCIL_IN_PLANE))
    for c in range(s.tie_a.size):
        weight = 0.0 if secant is None else secant[c]
        _crossing_slip(pos, flat, s.tie_material, s.tie_stencil, s.tie_rotation_law, anchors,
                       c, S)
        stick = s.tie_friction_law[c, STICK]
        element.huber3_gradient(S, limit[c], stick, f)
        element.huber3_hessian(S, limit[c], stick, weight, A)
        G[0, m], G[1, m + 1] = anchors[c, 2], anchors[c, 3]
        rho = 0.0
        if m:
            rho = s.tie_rotation_law[c, 0]
            _rotation_jacobian(pos, s.tie_stencil, c, J2, K2)
            for j in range(m):
                G[2, j] = rho * J2[j]
        for p in range(size):
            for q in range(size):
                h = 0.0
                for a in range(3):
                    for b in range(3):
                        h += G[a, p] * A[a, b] * G[b, q]
                if p < m and q < m:
                    h += rho * f[2] * K2[p, q]
                values[e] = h
                e += 1
    return e


def _wrap_values(wraps, s: Structure, values, e) -> int:
    """Each wrap spring's mixed and material Hessian entries in `_material_entries`' order
    from entry e (11.13b at the wrap: d2E_w/dr dlbar_0 = -(dE_w/dr) / lbar_0,
    d2E_w/dlbar_0^2 = 2 E_w / lbar_0^2, dlbar_0/du = 1/2 dL/du on its two segments); returns
    the next entry."""
    for y, energy, lbar, grad in wraps:
        first, last = _wrap_ends(s, y)
        f0, f1 = 0.5 * s.segment_fraction[first], 0.5 * s.segment_fraction[last]
        gm = np.array([-f0, f0, -f1, f1])
        mixed = np.outer(-grad / lbar, gm).ravel()
        values[e:e + 2 * mixed.size:2] = mixed
        values[e + 1:e + 2 * mixed.size:2] = mixed
        e += 2 * mixed.size
        values[e:e + 16] = (2.0 * energy / (lbar * lbar) * np.outer(gm, gm)).ravel()
        e += 16
    return e


def coordinate_map(s: Structure) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(indptr, dofs, weights): the dofs (and weights) an entry's index stands for, CSR over
    the indices [0, 2 n dim) of `_material_entries`: a physical coordinate the dof that holds
    it (1), none where it is held at its as-woven value, the plane nodes (w / their count)
    where a crossing holds it on a plane that moves (`_physical`); a material dof itself."""
    size = s.rest_position.size
    held = np.flatnonzero(s.physical_source >= 0)
    index, dofs, weights = [held], [s.physical_source[held]], [np.ones(held.size)]
    planes = moving_planes(s)
    for c, side in zip(*np.nonzero(planes[0] >= 0)) if planes is not None else ():
        nodes = _plane_nodes(s, side)
        index.append(np.full(nodes.size, planes[0][c, side]))
        dofs.append(dim(s) * nodes)
        weights.append(np.full(nodes.size, planes[1][c, side] / nodes.size))
    index.append(size + np.arange(size))
    dofs.append(np.arange(size))
    weights.append(np.ones(size))
    index = np.concatenate(index)
    order = np.argsort(index, kind="stable")
    indptr = np.concatenate([[0], np.cumsum(np.bincount(index, minlength=2 * size))])
    return (indptr, np.concatenate(dofs).astype(np.int64)[order],
            np.concatenate(weights)[order])


def expand_entries(rows, cols, indptr, dofs, weights):
    """(rows, cols, entry, weight): each entry (rows[e], cols[e]) on the indices of
    `coordinate_map` as the entries on the dofs its row and column stand for, in entry order:
    value[entry] times weight (the chain rule through a linear map); -1 stands for nothing."""
    valid = (rows >= 0) & (cols >= 0)
    r, c = np.where(valid, rows, 0), np.where(valid, cols, 0)
    nr = np.where(valid, indptr[r + 1] - indptr[r], 0)
    nc = np.where(valid, indptr[c + 1] - indptr[c], 0)
    count = nr * nc
    entry = np.repeat(np.arange(rows.size), count)
    j = np.arange(entry.size) - np.repeat(np.cumsum(count) - count, count)
    pr = indptr[r[entry]] + j // nc[entry]
    pc = indptr[c[entry]] + j % nc[entry]
    return dofs[pr], dofs[pc], entry, weights[pr] * weights[pc]


class SlidingPattern(Pattern):
    """The Hessian's entries on the dofs: the base term set's on the physical coordinates,
    then the material entries (`_material_entries`), each moved to the dofs its coordinates
    stand for (`coordinate_map`, `expand_entries`): a coordinate held at its as-woven value
    or a chain end's constant drops out, one on a moving plane spreads over its plane
    nodes."""

    def __init__(self, s: Structure):
        d = dim(s)
        base_rows, base_cols = _base(s).pattern_entries(s)
        self.node_materials = node_materials(s)
        count = _material_entry_count(s, d, self.node_materials.shape[1])
        rows, cols = np.empty(count, np.int64), np.empty(count, np.int64)
        _material_entries(s, d, self.node_materials, _wrap_coordinates(s), rows, cols)
        self.base_size = base_rows.size
        self.size_before = base_rows.size + count
        rows, cols, self.entry, self.weight = expand_entries(
            np.concatenate([base_rows, rows]), np.concatenate([base_cols, cols]),
            *coordinate_map(s))
        super().__init__(s, (rows, cols))
        self._entry_kept = self.entry[self._keep]
        self._weight_kept = None if np.all(self.weight == 1.0) else self.weight[self._keep]

    def on_dofs(self, values) -> np.ndarray:
        """Every entry `hessian_values` fills as the entries on the dofs (`rows`, `cols`)."""
        return values[self.entry] * self.weight

    def matrix(self, values) -> scipy.sparse.csc_matrix:
        """The Hessian on the unknowns (CSC) from every entry `hessian_values` fills."""
        data = values[self._entry_kept]
        if self._weight_kept is not None:  # a plane that moves
            data *= self._weight_kept
        return self.csc(np.bincount(self._slot, weights=data, minlength=self._slots))


_PATTERNS: dict[tuple, tuple] = {}
"""The last few structures' `SlidingPattern`s, by the ids of their arrays (kept beside)."""


def pattern_of(s: Structure) -> SlidingPattern:
    """The `SlidingPattern` of a structure, made once per topology (`assembly.kept_pattern`):
    the spatial one's arrays (`spatial._topology`, which a held lateral set shares) and the
    slots and bays."""
    arrays = (*spatial._topology(s), s.physical_source, s.tie_material, s.segment_material,
              s.tie_plane_weight, s.wrap_stiffness)
    return kept_pattern(_PATTERNS, arrays, lambda: SlidingPattern(s))


def hessian_values(dofs, s: Structure, anchors, limit, secant=None) -> np.ndarray:
    """Every entry of `SlidingPattern` on the physical coordinates and material dofs (before
    `expand_entries`), F_T = `limit` frozen."""
    pattern = pattern_of(s)
    now = current(dofs, s)
    dofs = np.ascontiguousarray(dofs, float)
    pos = physical(dofs, s)
    values = np.zeros(pattern.size_before)
    _base(s).hessian_values(pos, now, _base_anchors(anchors, s), np.zeros(s.tie_a.size),
                            values[:pattern.base_size], None)
    energy, grad = _bends(pos, now)
    rest = values[pattern.base_size:]
    e = _elastic_material_values(pos, now.rest_length, s, energy, grad, pattern.node_materials,
                                 rest)
    e = _wrap_values(_wrap_gradients(pos, now), s, rest, e)
    _friction_values(pos, dofs, s, anchors, limit, secant, rest, e)
    return values


def sparse_hessian(s: Structure, dofs, anchors, limit, secant=0.0):
    """The Hessian of V plus the Huber terms on the structure's unknowns [N/m] (CSC), F_T =
    `limit` frozen; `secant` as `assembly.sparse_hessian`'s."""
    pattern = pattern_of(s)
    values = hessian_values(dofs, s, anchors, limit, secant_weights(secant, s.tie_a.size))
    return pattern.matrix(values)


def full_hessian(s: Structure, dofs, anchors, limit) -> np.ndarray:
    """The Hessian on every dof, dense (for tests and small checks)."""
    pattern = pattern_of(s)
    return pattern.full_matrix(pattern.on_dofs(hessian_values(dofs, s, anchors, limit)))


def stiffest_rows(s: Structure, dofs, anchors) -> tuple[np.ndarray, np.ndarray] | None:
    """Per node, (the largest over its dofs of sum_j |K_ij|, its largest |K_ii|) [N/m] of the
    stiffest tangent a load step from `dofs` can meet, on every dof (held ones included):
    this term set's Hessian with every crossing sticking (F_T infinite where the structure has
    friction) and every contact at its bound k_s (`spatial.rows_at_contact_bound`); a node
    without any (a retired tail's) takes the largest row; None where a bay has run out of
    material. The dynamic solver's Gershgorin masses of the positions and the slides alike
    (`dynfab.kernels.sliding_terms`; docs/model.md 11.13)."""
    pattern = pattern_of(s)
    dofs = np.ascontiguousarray(np.asarray(dofs, float).reshape(s.rest_position.shape))
    if current(dofs, s) is None:
        return None
    limit = np.full(s.tie_a.size, np.inf if s.has_friction else 0.0)
    values = pattern.on_dofs(hessian_values(dofs, s, np.asarray(anchors, float), limit))
    rows, diagonal = spatial.rows_at_contact_bound(physical(dofs, s), s, pattern.rows,
                                                   pattern.cols, values)
    rows[rows == 0.0] = rows.max()  # a retired tail's node: no stiffness, a mass all the same
    return rows, diagonal


# ----------------------------------------------------------------------- friction and the rest


@numba.njit(cache=True)
def _chain_of(chain_start, node):
    return np.searchsorted(chain_start, node, side="right") - 1


@numba.njit(cache=True)
def _stretches(pos, L, s, out):
    """lambda of each tie's two yarns at its nodes (T, 2): the mean stretch l / L of the two
    segments at the node (11.13c), L their rest lengths now."""
    for c in range(s.tie_a.size):
        for side in range(2):
            n = s.tie_a[c] if side == 0 else s.tie_b[c]
            y = _chain_of(s.chain_start, n)
            out[c, side] = 0.5 * (_length(pos, n - 1) / L[n - 1 - y] + _length(pos, n) / L[n - y])


def with_stretches(dofs, s: Structure, anchors) -> np.ndarray:
    """A state's anchors (`state_anchors`) with the stretches lambda_0 (T, 2) of the yarns at
    each crossing at `dofs` after the material ones: what a load step's friction measures
    its slips with (11.13c), taken at the step's start (module docstring)."""
    pos = physical(dofs, s)
    out = np.zeros((s.tie_a.size, 2))
    _stretches(pos, rest_lengths(dofs, s), s, out)
    anchors = np.asarray(anchors, float)
    return np.hstack([anchors[:, :2], out, anchors[:, 2:]])


def has_stretches(anchors) -> bool:
    """The anchors are a step's, with the stretches (`with_stretches`), not a state's."""
    return np.shape(anchors)[1] > max(STRETCHES)


def state_anchors(anchors) -> np.ndarray:
    """A step's anchors without the stretches: (xi_a, xi_b[, phi_anchor]) per tie."""
    return np.delete(np.asarray(anchors, float), STRETCHES, axis=1)


def crossing_slips(dofs, s: Structure, anchors, out) -> None:
    """Every tie's slip S (11.13c) [m] into out (T, 3)."""
    dofs = np.ascontiguousarray(dofs, float)
    pos, flat, S = physical(dofs, s), dofs.reshape(-1), np.empty(3)
    for c in range(s.tie_a.size):
        _crossing_slip(pos, flat, s.tie_material, s.tie_stencil, s.tie_rotation_law, anchors,
                       c, S)
        out[c] = S


@numba.njit(cache=True)
def _return_map(pos, dofs, s, anchors, limit, sliding, friction_force):
    """`return_map` in numba."""
    flat = dofs.reshape(-1)
    S = np.empty(3)
    lost = 0.0
    for c in range(s.tie_a.size):
        _crossing_slip(pos, flat, s.tie_material, s.tie_stencil, s.tie_rotation_law, anchors,
                       c, S)
        stick = s.tie_friction_law[c, STICK]
        n = np.sqrt(S[0] * S[0] + S[1] * S[1] + S[2] * S[2])
        F = limit[c]
        sliding[c] = huber_law.moves(n, F, stick)
        if sliding[c]:
            move = 1.0 - max(F, 0.0) / (stick * n)
            for k in range(2):
                anchors[c, k] += move * (flat[s.tie_material[c, k]] - anchors[c, k])
            if s.tie_stencil.shape[0]:
                anchors[c, ROTATION] += move * S[2] / s.tie_rotation_law[c, 0]
            lost += max(F, 0.0) * move * n
            for k in range(friction_force.shape[1]):
                friction_force[c, k] = -max(F, 0.0) * S[k] / n
        else:
            for k in range(friction_force.shape[1]):
                friction_force[c, k] = -stick * S[k] if F > 0.0 else 0.0
    return lost


def return_map(dofs, anchors, s: Structure, limit, sliding, friction_force) -> float:
    """The anchors' radial return on the slips (11.13c), in place: where k_t |S| > F_T each
    anchor moves so that the slip becomes (F_T / (k_t |S|)) S, the energy lost F_T times the
    slip's change [J] (returned); fills `sliding` and the friction force on the slip (T, 2)
    or (T, 3) [N] (the third the moment over rho), as the fixed crossings'."""
    dofs = np.ascontiguousarray(dofs, float)
    return _return_map(physical(dofs, s), dofs, s, anchors, limit, sliding, friction_force)


def coupling_rows(s: Structure, dofs, anchors, limit, c) -> tuple[np.ndarray, np.ndarray]:
    """(dofs, values): d(dV/d dofs)/dF_T of tie c, G^T S / |S| (`_friction_values`' G) where
    it slides (dHuber/dS = F_T S / |S|), empty where it sticks (as
    `assembly.coupling_rows`)."""
    dofs = np.ascontiguousarray(dofs, float)
    pos, S = physical(dofs, s), np.empty(3)
    _crossing_slip(pos, dofs.reshape(-1), s.tie_material, s.tie_stencil, s.tie_rotation_law,
                   anchors, c, S)
    stick = s.tie_friction_law[c, STICK]
    norm = np.linalg.norm(S)
    if not (limit[c] > 0.0 and huber_law.slides(norm, limit[c], stick) and norm > 0.0):
        return np.zeros(0, np.int64), np.zeros(0)
    rows, values = list(s.tie_material[c]), [anchors[c, 2] * S[0] / norm,
                                             anchors[c, 3] * S[1] / norm]
    if s.tie_stencil.shape[0]:
        J2, K2 = np.zeros(STENCIL_IN_PLANE), np.zeros((STENCIL_IN_PLANE, STENCIL_IN_PLANE))
        _rotation_jacobian(pos, s.tie_stencil, c, J2, K2)
        local = np.empty(STENCIL_IN_PLANE + 2, np.int64)
        _friction_dofs(s, c, local)
        rho = s.tie_rotation_law[c, 0]
        rows += list(s.physical_source[local[:STENCIL_IN_PLANE]])
        values += list(rho * J2 * S[2] / norm)
    rows, values = np.array(rows, np.int64), np.array(values)
    keep = rows >= 0
    return rows[keep], values[keep]


def lateral_gaps(dofs, s: Structure, out) -> None:
    """w - d of each lateral contact (L,) [m] at the physical positions
    (`dynfab.model.fabric.spatial.lateral_gaps`)."""
    spatial.lateral_gaps(physical(dofs, s), s, out)


def rounding_scale(dofs, s: Structure, P, limit) -> float:
    """S [J] with the rounding of V about eps S (the base term set's at the physical
    positions and the material lengths; each tie's F_T times its slides)."""
    now = current(dofs, s)
    if now is None:
        return np.inf
    flat = np.asarray(dofs, float).reshape(-1)
    material = np.abs(flat[s.tie_material]).sum(axis=1)
    return float(_base(s).rounding_scale(physical(dofs, s), now, np.asarray(P, float), limit)
                 + np.sum(np.asarray(limit) * material))


class SlidingTerms:
    """The term set of a structure whose crossings slide, over its base term set: the
    functions of this module with the base's energy terms (TERMS) and its choice of solves
    on kept factors (SOLVE_ON_KEPT_FACTORS), the interface of `assembly` and `spatial`."""

    def __init__(self, base):
        self.TERMS = base.TERMS
        self.SOLVE_ON_KEPT_FACTORS = base.SOLVE_ON_KEPT_FACTORS
        self.CONTACT, self.FRICTION = CONTACT, FRICTION

    total_energy = staticmethod(total_energy)
    energy_vector = staticmethod(energy_vector)
    gradient = staticmethod(gradient)
    pattern_of = staticmethod(pattern_of)
    sparse_hessian = staticmethod(sparse_hessian)
    full_hessian = staticmethod(full_hessian)
    crossing_slips = staticmethod(crossing_slips)
    return_map = staticmethod(return_map)
    coupling_rows = staticmethod(coupling_rows)
    lateral_gaps = staticmethod(lateral_gaps)
    rounding_scale = staticmethod(rounding_scale)
    with_stretches = staticmethod(with_stretches)
    state_anchors = staticmethod(state_anchors)
    physical = staticmethod(physical)


PLANAR, SPATIAL = SlidingTerms(assembly), SlidingTerms(spatial)
"""The term sets of planar and spatial structures whose crossings slide."""
TERMS = assembly.TERMS
"""The planar term set's energy terms (`PLANAR.TERMS`)."""
