"""The energy, gradient and sparse Hessian of a fabric whose crossings slide along the yarns
(docs/model.md 11.13), on the structure's dofs (`dynfab.model.builders.sliding`).

The elastic terms, the contact and the loads are the planar fabric's own
(`dynfab.model.fabric.assembly`), evaluated at the physical positions (`physical`: each dof
where it is a coordinate, a sliding crossing's node on the plane it crosses) with each
segment's rest length and each spring's stiffness those of the material in it now
(`current`):

    E_s = 1/2 EA (l_s - L_s)^2 / L_s,      L_s = f_s (u_R - u_L),                  (11.13a)
    E_i = 1/2 EI (phi_i - phi0_i)^2 / lbar_i,   lbar_i = (L_{i-1} + L_i) / 2,       (11.13b)

u_L, u_R the material coordinates of the segment's bay ends (a crossing's dof, or a chain end's
constant), f_s its share of the bay. Their gradient on the dofs is the physical gradient
pulled back (`Structure.physical_source`) plus the material part dE/dL dL/du, with

    dE_s/dL = EA (L^2 - l^2) / (2 L^2),  d2E_s/dl dL = -EA l / L^2,  d2E_s/dL2 = EA l^2 / L^3,
    dE_i/dlbar = -E_i / lbar,  d2E_i/dr dlbar = -(dE_i/dr) / lbar,  d2E_i/dlbar2 = 2 E_i / lbar^2,

dL/du = (-f, +f) and dlbar/dL = 1/2, each linear in u; the Hessian adds those mixed and
material blocks (`_material_entries`, `_material_values`, in one order). Friction acts on the
slip of the material through the crossing measured in space,

    S_k = lambda_k (u_k - xi_k),   lambda_k = (l_1 / L_1 + l_2 / L_2) / 2,            (11.13c)

on each yarn k of the crossing, lambda_k the mean stretch of the two segments at its node at
the step's start (held through the step with the anchors: `with_stretches`): so Gralen's F_T
is a force in space, as the fixed crossing's, and the tension jumps by F_T across a sliding
crossing (its material balance, the jump of the Eshelby force W - lambda T =
-T (1 + (lambda - 1) / 2) per unit of u, is F_T lambda), a yarn pulled through crossings
carrying the sum of their limits. The planar Huber law (`dynfab.model.fabric.friction`) on S,
its block on the two material dofs. A bay
whose material runs out (L <= 0: two crossings meeting, or a yarn end reaching its last
crossing before it leaves it) has energy +inf, which the line searches refuse.
"""

from __future__ import annotations

import numba
import numpy as np

from dynfab.model.fabric import assembly
from dynfab.model.fabric import friction
from dynfab.model.fabric.assembly import Pattern, secant_weights
from dynfab.model.structure import Structure
from dynfab.model.terms import bending
from dynfab.model.terms import huber as huber_law

TERMS = assembly.TERMS
CONTACT, FRICTION, STRETCH = assembly.CONTACT, assembly.FRICTION, assembly.STRETCH
SOLVE_ON_KEPT_FACTORS = assembly.SOLVE_ON_KEPT_FACTORS


# ----------------------------------------------------------------------- kinematics


@numba.njit(cache=True)
def _physical(dofs, s, out):
    """out = the physical positions (n, 2) of the dofs (module docstring)."""
    flat, rest, o = dofs.reshape(-1), s.rest_position.reshape(-1), out.reshape(-1)
    for d in range(o.size):
        source = s.physical_source[d]
        o[d] = flat[source] if source >= 0 else rest[d]


@numba.njit(cache=True)
def _bay_end(flat, material, end, k, side):
    """The material coordinate [m] of side 0 (left) or 1 (right) of segment k's bay
    (`Structure.segment_material`, `segment_material_end`; arrays, not the structure: a
    structure passed to a function called in a loop costs about 0.5 us a call)."""
    index = material[k, side]
    return flat[index] if index >= 0 else end[k, side]


@numba.njit(cache=True)
def _rest_lengths(dofs, s, out):
    """out = L_s (n - Y,) [m] (11.13a)."""
    flat = dofs.reshape(-1)
    material, end = s.segment_material, s.segment_material_end
    for k in range(out.size):
        out[k] = s.segment_fraction[k] * (_bay_end(flat, material, end, k, 1)
                                          - _bay_end(flat, material, end, k, 0))


def physical(dofs, s: Structure) -> np.ndarray:
    """The physical positions (n, 2) [m] of the dofs."""
    out = np.empty(s.rest_position.shape)
    _physical(np.ascontiguousarray(dofs, float), s, out)
    return out


def rest_lengths(dofs, s: Structure) -> np.ndarray:
    """Each segment's rest length now, L_s (n - Y,) [m] (11.13a)."""
    out = np.empty(s.rest_length.size)
    _rest_lengths(np.ascontiguousarray(dofs, float), s, out)
    return out


@numba.njit(cache=True)
def _material_now(dofs, s, L, stretch, bend):
    """Each segment's rest length L (11.13a) and stiffness EA / L, each node's bending stiffness
    EI / lbar (11.13b); False where a bay has run out of material (L <= 0)."""
    _rest_lengths(dofs, s, L)
    start = s.chain_start
    for y in range(start.size - 1):
        for k in range(start[y] - y, start[y + 1] - y - 1):
            if not L[k] > 0.0:
                return False
            stretch[k] = s.stretch_modulus[k] / L[k]
        for i in range(start[y] + 1, start[y + 1] - 1):
            bend[i] = s.bend_modulus[i] / (0.5 * (L[i - 1 - y] + L[i - y]))
        bend[start[y]] = bend[start[y + 1] - 1] = 0.0
    return True


def current(dofs, s: Structure) -> Structure | None:
    """The structure of the material as it lies now: each segment's rest length L_s and
    stiffness EA / L_s, each node's bending stiffness EI / lbar_i (11.13b; 0 at a chain's
    ends), friction left to this module (`has_friction` False); None where a bay has run out
    of material (L <= 0)."""
    L, stretch = np.empty(s.rest_length.size), np.empty(s.rest_length.size)
    bend = np.empty(s.bend_modulus.size)
    if not _material_now(np.ascontiguousarray(dofs, float), s, L, stretch, bend):
        return None
    return s._replace(rest_length=L, stretch_stiffness=stretch, bend_stiffness=bend,
                      has_friction=False)


# ----------------------------------------------------------------------- energy and gradient


def total_energy(dofs, s: Structure, P, anchors, limit, out) -> float:
    """V [J] at the dofs (its terms left in out, `TERMS`), F_T = `limit` frozen; +inf where a
    bay has run out of material."""
    now = current(dofs, s)
    out[:] = 0.0
    if now is None:
        out[STRETCH] = np.inf
        return np.inf
    assembly.energies(physical(dofs, s), now, P, anchors, limit, out)
    if s.has_friction:
        out[FRICTION] = _friction_energy(np.ascontiguousarray(dofs, float), s, anchors, limit)
    return float(out.sum())


def energy_vector(s: Structure, dofs, P, anchors, limit) -> np.ndarray:
    """Each term's energy [J] (`TERMS`) at the dofs, F_T = `limit` frozen."""
    out = np.zeros(len(TERMS))
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
def _add_to_bay(flat, material, fraction, k, value):
    """flat += value dL_k/du on segment k's bay ends (dL/du_R = f, dL/du_L = -f)."""
    f = fraction[k]
    if material[k, 0] >= 0:
        flat[material[k, 0]] -= value * f
    if material[k, 1] >= 0:
        flat[material[k, 1]] += value * f


@numba.njit(cache=True)
def _length(pos, i):
    ex, ez = pos[i + 1, 0] - pos[i, 0], pos[i + 1, 1] - pos[i, 1]
    return np.sqrt(ex * ex + ez * ez)


@numba.njit(cache=True)
def _add_material_gradient(pos, now, s, grad):
    """grad += the material part of the elastic terms' gradient (module docstring)."""
    flat = grad.reshape(-1)
    start, material, fraction = s.chain_start, s.segment_material, s.segment_fraction
    for y in range(start.size - 1):
        a, b = start[y], start[y + 1]
        for i in range(a, b - 1):
            k = i - y
            L, l = now.rest_length[k], _length(pos, i)
            _add_to_bay(flat, material, fraction, k,
                        0.5 * s.stretch_modulus[k] * (L * L - l * l) / (L * L))
        for i in range(a + 1, b - 1):
            d = bending.turning_angle(pos, i) - s.rest_angle[i]
            energy = 0.5 * now.bend_stiffness[i] * d * d
            lbar = 0.5 * (now.rest_length[i - 1 - y] + now.rest_length[i - y])
            _add_to_bay(flat, material, fraction, i - 1 - y, -0.5 * energy / lbar)
            _add_to_bay(flat, material, fraction, i - y, -0.5 * energy / lbar)


@numba.njit(cache=True)
def _chain_of(chain_start, node):
    return np.searchsorted(chain_start, node, side="right") - 1


@numba.njit(cache=True)
def _stretches(pos, dofs, s, out):
    """lambda of each tie's two yarns at its nodes (T, 2): the mean stretch l / L of the two
    segments at the node (11.13c)."""
    flat = dofs.reshape(-1)
    for c in range(s.tie_a.size):
        for side in range(2):
            n = s.tie_a[c] if side == 0 else s.tie_b[c]
            y = _chain_of(s.chain_start, n)
            k1, k2 = n - 1 - y, n - y
            u = flat[s.tie_material[c, side]]
            material, end = s.segment_material, s.segment_material_end
            L1 = s.segment_fraction[k1] * (u - _bay_end(flat, material, end, k1, 0))
            L2 = s.segment_fraction[k2] * (_bay_end(flat, material, end, k2, 1) - u)
            out[c, side] = 0.5 * (_length(pos, n - 1) / L1 + _length(pos, n) / L2)


@numba.njit(cache=True)
def _slip(flat, tie_material, anchors, c):
    """(S_a, S_b) of tie c (11.13c): each yarn's material slip from its anchor times the
    stretch there at the step's start (anchors' columns 2, 3)."""
    return (anchors[c, 2] * (flat[tie_material[c, 0]] - anchors[c, 0]),
            anchors[c, 3] * (flat[tie_material[c, 1]] - anchors[c, 1]))


@numba.njit(cache=True)
def _friction_energy(dofs, s, anchors, limit):
    """sum_c H(S_c) [J] (11.13c), F_T frozen."""
    flat = dofs.reshape(-1)
    total = 0.0
    for c in range(s.tie_a.size):
        sx, sy = _slip(flat, s.tie_material, anchors, c)
        total += friction.huber(sx, sy, limit[c], s.tie_friction_law[c, friction.STICK])
    return total


@numba.njit(cache=True)
def _add_friction_gradient(dofs, s, anchors, limit, grad):
    """grad += dH/du = lambda_0 dH/dS on each tie's two material dofs (11.13c)."""
    flat, out = dofs.reshape(-1), grad.reshape(-1)
    for c in range(s.tie_a.size):
        sx, sy = _slip(flat, s.tie_material, anchors, c)
        gx, gy = friction.huber_gradient(sx, sy, limit[c], s.tie_friction_law[c, friction.STICK])
        out[s.tie_material[c, 0]] += anchors[c, 2] * gx
        out[s.tie_material[c, 1]] += anchors[c, 3] * gy


def gradient(dofs, s: Structure, P, anchors, limit, grad) -> None:
    """grad = dV/d(dofs) (n, 2) [N, and N for the material coordinates' J/m], F_T frozen."""
    now = current(dofs, s)
    if now is None:  # a bay has run out of material: no gradient (the energy is +inf)
        grad[:] = np.nan
        return
    pos = physical(dofs, s)
    physical_grad = np.zeros_like(pos)
    assembly.gradient(pos, now, np.asarray(P, float), anchors, limit, physical_grad)
    grad[:] = 0.0
    _pull_back(physical_grad, s, grad)
    _add_material_gradient(pos, now, s, grad)
    if s.has_friction:
        _add_friction_gradient(np.ascontiguousarray(dofs, float), s, anchors, limit, grad)


# ----------------------------------------------------------------------- the Hessian


@numba.njit(cache=True)
def _segment_dofs(s, i, k, out):
    """(the dofs holding the 4 coordinates of segment k's nodes i, i+1; its 2 bay-end dofs),
    -1 for a coordinate held on a plane or a chain end's constant."""
    for m in range(4):
        out[m] = s.physical_source[2 * i + m]
    out[4], out[5] = s.segment_material[k, 0], s.segment_material[k, 1]


@numba.njit(cache=True)
def _bend_dofs(s, i, k, out):
    """(the dofs holding the 6 coordinates of nodes i-1..i+1; the bay ends of segments k-1
    and k: k-1's two, then k's right one, its left being one of those), -1 as
    `_segment_dofs`."""
    for m in range(6):
        out[m] = s.physical_source[2 * (i - 1) + m]
    out[6], out[7] = s.segment_material[k - 1, 0], s.segment_material[k - 1, 1]
    out[8] = s.segment_material[k, 1]


@numba.njit(cache=True)
def _emit_block(local, positions, materials, rows, cols, e):
    """(rows, cols) of the mixed (position x material, both orders) and material x material
    entries of one element whose dofs are `local`: `positions` physical ones, then
    `materials` material ones; returns the next entry."""
    for p in range(positions):
        for q in range(materials):
            rows[e], cols[e] = local[p], local[positions + q]
            rows[e + 1], cols[e + 1] = local[positions + q], local[p]
            e += 2
    for p in range(materials):
        for q in range(materials):
            rows[e], cols[e] = local[positions + p], local[positions + q]
            e += 1
    return e


@numba.njit(cache=True)
def _material_entry_count(s):
    segments = s.rest_length.size
    inner = segments - (s.chain_start.size - 1)
    ties = s.tie_a.size
    return segments * (4 * 2 * 2 + 4) + inner * (6 * 3 * 2 + 9) + 4 * ties


@numba.njit(cache=True)
def _material_entries(s, rows, cols):
    """(rows, cols) of every entry `_material_values` fills, in its order: each segment's
    stretch block, each inner node's bending block, each tie's friction block, on the dofs
    (-1 where a coordinate is held on a plane or a bay ends at a chain end)."""
    start = s.chain_start
    local = np.empty(10, np.int64)
    e = 0
    for y in range(start.size - 1):
        a, b = start[y], start[y + 1]
        for i in range(a, b - 1):
            _segment_dofs(s, i, i - y, local)
            e = _emit_block(local, 4, 2, rows, cols, e)
        for i in range(a + 1, b - 1):
            _bend_dofs(s, i, i - y, local)
            e = _emit_block(local, 6, 3, rows, cols, e)
    for c in range(s.tie_a.size):
        u_a, u_b = s.tie_material[c, 0], s.tie_material[c, 1]
        rows[e:e + 4] = np.array([u_a, u_a, u_b, u_b])
        cols[e:e + 4] = np.array([u_a, u_b, u_a, u_b])
        e += 4


@numba.njit(cache=True)
def _put_block(gx, gm, hmm, positions, materials, values, e):
    """values (in `_emit_block`'s order) of the block gx gm^T (both orders) and hmm gm gm^T."""
    for p in range(positions):
        for q in range(materials):
            values[e] = values[e + 1] = gx[p] * gm[q]
            e += 2
    for p in range(materials):
        for q in range(materials):
            values[e] = hmm * gm[p] * gm[q]
            e += 1
    return e


@numba.njit(cache=True)
def _material_values(pos, dofs, now, s, anchors, limit, secant, values):
    """The mixed and material Hessian entries (module docstring) in `_material_entries`'
    order; the friction blocks with each tie's secant weight (`friction.huber_hessian`)."""
    start = s.chain_start
    gx, gm, g = np.empty(6), np.empty(4), np.empty(6)
    e = 0
    for y in range(start.size - 1):
        a, b = start[y], start[y + 1]
        for i in range(a, b - 1):
            k = i - y
            ex, ez = pos[i + 1, 0] - pos[i, 0], pos[i + 1, 1] - pos[i, 1]
            l = np.sqrt(ex * ex + ez * ez)
            L, EA, f = now.rest_length[k], s.stretch_modulus[k], s.segment_fraction[k]
            mixed = -EA * l / (L * L)  # d2E/dl dL, times dl/dr = (-e, e) / l
            gx[0], gx[1], gx[2], gx[3] = -mixed * ex / l, -mixed * ez / l, mixed * ex / l, \
                mixed * ez / l
            gm[0], gm[1] = -f, f
            e = _put_block(gx, gm, EA * l * l / (L * L * L), 4, 2, values, e)
        for i in range(a + 1, b - 1):
            k = i - y
            kb = now.bend_stiffness[i]
            d = bending.turning_angle(pos, i) - s.rest_angle[i]
            energy = 0.5 * kb * d * d
            lbar = 0.5 * (now.rest_length[k - 1] + now.rest_length[k])
            bending._angle_gradient(pos, i, g)
            for m in range(6):
                gx[m] = -kb * d * g[m] / lbar  # d2E/dr dlbar
            f0, f1 = 0.5 * s.segment_fraction[k - 1], 0.5 * s.segment_fraction[k]
            # dlbar/du on (k-1's left, k-1's right, k's right): k's left end is one of the
            # first two (an inner node of a bay: its left; a crossing's node: its right)
            inner = s.segment_material[k, 0] == s.segment_material[k - 1, 0]
            gm[0], gm[1], gm[2] = -f0 - f1 * inner, f0 - f1 * (not inner), f1
            e = _put_block(gx, gm, 2.0 * energy / (lbar * lbar), 6, 3, values, e)
    flat = dofs.reshape(-1)
    for c in range(s.tie_a.size):
        weight = 0.0 if secant is None else secant[c]
        sx, sy = _slip(flat, s.tie_material, anchors, c)
        xx, xy, yy = friction.huber_hessian(sx, sy, limit[c], s.tie_friction_law[c, friction.STICK],
                                            weight)
        la, lb = anchors[c, 2], anchors[c, 3]  # d2H/du2 = diag(lambda_0) d2H/dS2 diag(lambda_0)
        values[e], values[e + 1], values[e + 2], values[e + 3] = la * la * xx, la * lb * xy, \
            la * lb * xy, lb * lb * yy
        e += 4


class SlidingPattern(Pattern):
    """The Hessian's entries on the dofs: the planar fabric's (`assembly.planar_entries`), each
    physical dof moved to the dof that holds it, then the material entries
    (`_material_entries`); those on a coordinate held on a plane or a chain end's constant
    left out (`kept`)."""

    def __init__(self, s: Structure):
        base_rows, base_cols = assembly.planar_entries(s)
        count = _material_entry_count(s)
        rows, cols = np.empty(count, np.int64), np.empty(count, np.int64)
        _material_entries(s, rows, cols)
        rows = np.concatenate([s.physical_source[base_rows], rows])
        cols = np.concatenate([s.physical_source[base_cols], cols])
        self.base_size = base_rows.size
        self.kept = (rows >= 0) & (cols >= 0)
        super().__init__(s, (rows[self.kept], cols[self.kept]))


_PATTERNS: dict[int, tuple] = {}
"""The last few structures' `SlidingPattern`s, by id (the structure kept alive beside it)."""


def pattern_of(s: Structure) -> SlidingPattern:
    """The `SlidingPattern` of a structure, made once (the static solver, the certificate and
    the model share it, and with it the nested-dissection order)."""
    entry = _PATTERNS.get(id(s))
    if entry is None or entry[0] is not s:
        if len(_PATTERNS) >= assembly.PATTERNS_KEPT:
            _PATTERNS.pop(next(iter(_PATTERNS)))
        entry = _PATTERNS[id(s)] = (s, SlidingPattern(s))
    return entry[1]


def hessian_values(dofs, s: Structure, anchors, limit, secant=None) -> np.ndarray:
    """Every entry of `SlidingPattern` (before `kept`), F_T = `limit` frozen."""
    pattern = pattern_of(s)
    now = current(dofs, s)
    pos = physical(dofs, s)
    values = np.zeros(pattern.kept.size)
    assembly.hessian_values(pos, now, anchors, limit, values[:pattern.base_size], None)
    _material_values(pos, np.ascontiguousarray(dofs, float), now, s, anchors, limit, secant,
                     values[pattern.base_size:])
    return values


def sparse_hessian(s: Structure, dofs, anchors, limit, secant=0.0):
    """The Hessian of V plus the Huber terms on the structure's unknowns [N/m] (CSC), F_T =
    `limit` frozen; `secant` as `assembly.sparse_hessian`'s."""
    pattern = pattern_of(s)
    values = hessian_values(dofs, s, anchors, limit, secant_weights(secant, s.tie_a.size))
    return pattern.matrix(values[pattern.kept])


def full_hessian(s: Structure, dofs, anchors, limit) -> np.ndarray:
    """The Hessian on every dof, dense (for tests and small checks)."""
    pattern = pattern_of(s)
    return pattern.full_matrix(hessian_values(dofs, s, anchors, limit)[pattern.kept])


# ----------------------------------------------------------------------- friction and the rest


def with_stretches(dofs, s: Structure, anchors) -> np.ndarray:
    """The anchors (T, 2) [m] with the stretches lambda_0 (T, 2) of the yarns at each crossing
    at `dofs` beside them (T, 4): what a load step's friction measures its slips with
    (11.13c), taken at the step's start."""
    pos = physical(dofs, s)
    out = np.zeros((s.tie_a.size, 2))
    _stretches(pos, np.ascontiguousarray(dofs, float), s, out)
    return np.hstack([np.asarray(anchors, float)[:, :2], out])


def crossing_slips(dofs, s: Structure, anchors, out) -> None:
    """Every tie's slip (S_a, S_b, 0) (11.13c) [m] into out (T, 3)."""
    flat = np.asarray(dofs, float).reshape(-1)
    for c in range(s.tie_a.size):
        out[c, 0], out[c, 1] = _slip(flat, s.tie_material, anchors, c)
        out[c, 2] = 0.0


@numba.njit(cache=True)
def _return_map(dofs, s, anchors, limit, sliding, friction_force):
    """`return_map` in numba."""
    flat = dofs.reshape(-1)
    lost = 0.0
    for c in range(s.tie_a.size):
        sx, sy = _slip(flat, s.tie_material, anchors, c)
        stick = s.tie_friction_law[c, friction.STICK]
        n = np.hypot(sx, sy)
        F = limit[c]
        sliding[c] = huber_law.moves(n, F, stick)
        if sliding[c]:
            move = 1.0 - F / (stick * n)
            for k in range(2):
                anchors[c, k] += move * (flat[s.tie_material[c, k]] - anchors[c, k])
            lost += F * move * n
            friction_force[c, 0], friction_force[c, 1] = -F * sx / n, -F * sy / n
        else:
            friction_force[c, 0], friction_force[c, 1] = -stick * sx, -stick * sy
    return lost


def return_map(dofs, anchors, s: Structure, limit, sliding, friction_force) -> float:
    """The anchors' radial return on the slips (11.13c), in place: where k_t |S| > F_T each
    material anchor moves so that the slip becomes (F_T / (k_t |S|)) S, the energy lost F_T
    times the slip's change [J] (returned); fills `sliding` and the friction force on the
    slip (T, 2) [N] (as `dynfab.model.fabric.friction.return_map`)."""
    return _return_map(np.ascontiguousarray(dofs, float), s, anchors, limit, sliding,
                       friction_force)


def coupling_rows(s: Structure, dofs, anchors, limit, c) -> tuple[np.ndarray, np.ndarray]:
    """(dofs, values): d(dV/d dofs)/dF_T of tie c, lambda_0 S / |S| on its material dofs where
    it slides (dH/dS = F_T S / |S|), empty where it sticks (as `assembly.coupling_rows`)."""
    sx, sy = _slip(np.asarray(dofs, float).reshape(-1), s.tie_material, anchors, c)
    stick = s.tie_friction_law[c, friction.STICK]
    if not (limit[c] > 0.0 and friction.is_sliding(sx, sy, limit[c], stick)):
        return np.zeros(0, np.int64), np.zeros(0)
    norm = np.hypot(sx, sy)
    return s.tie_material[c].copy(), np.array([anchors[c, 2] * sx, anchors[c, 3] * sy]) / norm


def rounding_scale(dofs, s: Structure, P, limit) -> float:
    """S [J] with the rounding of V about eps S (`assembly.rounding_scale` at the physical
    positions and the material lengths; each tie's F_T times its material coordinates)."""
    now = current(dofs, s)
    if now is None:
        return np.inf
    flat = np.asarray(dofs, float).reshape(-1)
    material = np.abs(flat[s.tie_material]).sum(axis=1)
    return float(assembly.rounding_scale(physical(dofs, s), now, np.asarray(P, float), limit)
                 + np.sum(np.asarray(limit) * material))
