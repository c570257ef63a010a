"""The spatial fabric's energy, gradient and sparse Hessian (docs/model.md section 11).

Nodes move in x, y, z (dim 3, the fabric's plane x-y). The potential is

V = sum_segments E_stretch + sum_inner_nodes E_bend (elevation and in-plane turning)
    + sum_ties (E_contact + H_friction + E_shear) + sum_lateral E_lateral

with each element's energy and exact local derivatives in `dynfab.model.terms.spatial`: the
stretch spring, the bending in two planes, the contact along e_z of `dynfab.model.fabric.contact`
(the same closure and law as the planar fabric, z the last coordinate), the Huber friction
on the three-component slip (s_x, s_y, rho phi) with F_T = `limit` frozen and the rotation
spring of each crossing (`tie_stencil`, `tie_rotation_law`), and the lateral contacts
between neighbouring yarns (`lateral_stencil`, `lateral_law`). A specimen is loaded by its
held nodes (displacement control), so there is no end-load work; the load term stays 0.

The functions mirror the planar fabric's (`dynfab.model.fabric.assembly`), so the static solver's
sparse backend takes either through `dynfab.model.terms.kinematics.terms_of`. The Hessian's
entries are every element's dense local block, in a fixed order (`pattern_entries`); numba
fills the values in that order and `assembly.Pattern` sums them on the unknowns.
"""

from __future__ import annotations

import numba
import numpy as np
import scipy.sparse

from dynfab.model.fabric import contact
from dynfab.model.fabric.assembly import Pattern, kept_pattern, secant_weights
from dynfab.model.terms import huber as huber_law
from dynfab.model.terms import nodes as node_terms
from dynfab.model.terms import spatial as element

STRETCH, BENDING, CONTACT, FRICTION, LOAD, GRAVITY, SHEAR, LATERAL = range(8)
"""Indices of the energy vector (the first six as the planar fabric's)."""
TERMS = ("stretch", "bending", "contact", "friction", "load", "gravity", "shear", "lateral",
         *node_terms.NAMES)
"""The energy vector's terms: the spatial fabric's own, then the registry's node terms
(`dynfab.model.terms.nodes`) from NODE_TERMS on."""
NODE_TERMS = 8
SOLVE_ON_KEPT_FACTORS = True
"""Whether Newton's Hessian solves try GMRES on the step's last factors first
(`dynfab.model.fabric.kept_factor`): yes on a specimen, whose factorisation costs 20 to 28
triangular solves (docs/model.md 11.10)."""
STICK = 3
"""Column of k_t [N/m] in `tie_friction_law`."""
RHO, SHEAR_K, PHI_REST = range(3)
"""Columns of `tie_rotation_law`."""
SIGN, WIDTH, LATERAL_K, BRANCH, COMPACTION, PACKED, CORE_FROM = range(7)
"""Columns of `lateral_law` (`dynfab.model.structure.Structure`)."""
IN_PLANE = 2
"""The dofs of a node a crossing or lateral contact acts on: x and y. Their slips, rotation
and distance are in-plane (`dynfab.model.terms.spatial.crossing_coordinates`,
`lateral_distance`), so their Hessians' rows and columns on z are zero by construction and
stay out of the pattern (docs/model.md 11.10)."""


@numba.njit(cache=True)
def _gather(pos, nodes, X):
    """X[m] = pos[nodes[m]] (the element's stencil)."""
    for m in range(nodes.size):
        for k in range(3):
            X[m, k] = pos[nodes[m], k]


@numba.njit(cache=True)
def _scatter(nodes, g, grad):
    """grad[nodes[m]] += g[3 m: 3 m + 3]."""
    for m in range(nodes.size):
        for k in range(3):
            grad[nodes[m], k] += g[3 * m + k]


@numba.njit(cache=True)
def _crossing_law(s, c):
    """(rho, K, phi_rest, k_t) of tie c."""
    law = s.tie_rotation_law[c]
    return law[RHO], law[SHEAR_K], law[PHI_REST], s.tie_friction_law[c, STICK]


@numba.njit(cache=True)
def energies(pos, s, P, anchors, limit, out):
    """Each term's energy [J] into out (len(TERMS),); P unused (no end loads), kept for the
    planar signature."""
    out[:] = 0.0
    pair, triple = np.empty((2, 3)), np.empty((3, 3))
    six, four = np.empty((6, 3)), np.empty((4, 3))
    start = s.chain_start
    for y in range(start.size - 1):
        for i in range(start[y], start[y + 1] - 1):
            _gather(pos, np.arange(i, i + 2), pair)
            out[STRETCH] += element.stretch_energy(pair, s.stretch_stiffness[i - y],
                                                   s.rest_length[i - y])
        for i in range(start[y] + 1, start[y + 1] - 1):
            _gather(pos, np.arange(i - 1, i + 2), triple)
            out[BENDING] += element.bend_energy(triple, s.bend_stiffness[i], s.rest_angle[i],
                                                s.lateral_bend_stiffness[i],
                                                s.lateral_rest_angle[i])
    out[CONTACT] = contact.energy(pos, s)
    for c in range(s.tie_a.size):
        rho, K, phi_rest, stick = _crossing_law(s, c)
        _gather(pos, s.tie_stencil[c], six)
        spring = element.crossing_energy(six, anchors[c], rho, 0.0, stick, K, phi_rest)
        out[SHEAR] += spring
        if limit[c] > 0.0:
            out[FRICTION] += element.crossing_energy(six, anchors[c], rho, limit[c], stick,
                                                     0.0, phi_rest)
    for e in range(s.lateral_stencil.shape[0]):
        _gather(pos, s.lateral_stencil[e], four)
        law = s.lateral_law[e]
        out[LATERAL] += element.lateral_energy(four, law[SIGN], law[WIDTH], law[LATERAL_K],
                                               law[BRANCH], law[COMPACTION], law[PACKED],
                                               law[CORE_FROM])
    node_terms.energies(pos, s.rest_position, s.node_parameters, s.node_term_active,
                        out[NODE_TERMS:])


@numba.njit(cache=True)
def lateral_gaps(pos, s, out):
    """w - d of each lateral contact into out (L,) [m], d its signed distance
    (`dynfab.model.terms.spatial.lateral_distance`): positive where neighbouring yarns press."""
    four = np.empty((4, 3))
    for e in range(s.lateral_stencil.shape[0]):
        _gather(pos, s.lateral_stencil[e], four)
        out[e] = s.lateral_law[e, WIDTH] - element.lateral_distance(four, s.lateral_law[e, SIGN])


@numba.njit(cache=True)
def total_energy(pos, s, P, anchors, limit, out):
    """V [J] (its terms left in out)."""
    energies(pos, s, P, anchors, limit, out)
    return out.sum()


@numba.njit(cache=True)
def _put(H, values, k):
    """values[k:] = H row by row; returns the next free entry."""
    n = H.shape[0]
    for i in range(n):
        for j in range(n):
            values[k] = H[i, j]
            k += 1
    return k


@numba.njit(cache=True)
def _put_in_plane(H, values, k):
    """values[k:] = H's block on the x and y dofs of its nodes (3 per node), row by row;
    returns the next free entry."""
    m = H.shape[0] // 3
    for a in range(m):
        for i in range(IN_PLANE):
            for b in range(m):
                for j in range(IN_PLANE):
                    values[k] = H[3 * a + i, 3 * b + j]
                    k += 1
    return k


@numba.njit(cache=True)
def _emit_in_plane(nodes, g, H, grad, values, k):
    """`_emit` of an element acting on x and y alone: g whole, H's in-plane block."""
    if grad.shape[0]:
        _scatter(nodes, g, grad)
    if values.size:
        k = _put_in_plane(H, values, k)
    return k


@numba.njit(cache=True)
def _emit(nodes, g, H, grad, values, k):
    """One element's derivatives: g added to grad on `nodes` (where grad has rows), H into
    values from entry k (where values has entries); returns the next entry."""
    if grad.shape[0]:
        _scatter(nodes, g, grad)
    if values.size:
        k = _put(H, values, k)
    return k


@numba.njit(cache=True)
def _add_node_blocks(pos, s, i, last, H):
    """H (6, 6), segment (i, i + 1)'s block, += the node terms' Hessian of node i, and of node
    i + 1 where it is its chain's `last` (every node's once: the node terms live on these
    blocks, `dynfab.model.terms.nodes`)."""
    for m in range(2 if last else 1):
        block = np.zeros((3, 3))
        node_terms.add_node_hessian(pos, s.rest_position, s.node_parameters, s.node_term_active,
                                    i + m, block)
        H[3 * m:3 * m + 3, 3 * m:3 * m + 3] += block


@numba.njit(cache=True)
def _derivatives(pos, s, anchors, limit, secant, grad, values):
    """Every element's gradient and Hessian, each element's once (`dynfab.model.terms.spatial`):
    the gradient added to grad (nodes, 3) [N] where it has rows, the Hessian's entries into
    values in `pattern_entries`' order [N/m] where it has entries; F_T = `limit` frozen,
    `secant` (T,): each crossing's weight of its secant friction stiffness when sliding,
    None: 0."""
    pair, triple = np.empty((2, 3)), np.empty((3, 3))
    six, four = np.empty((6, 3)), np.empty((4, 3))
    g6, g9, g18, g12 = np.empty(6), np.empty(9), np.empty(18), np.empty(12)
    H6, H9, H18, H12 = np.empty((6, 6)), np.empty((9, 9)), np.empty((18, 18)), np.empty((12, 12))
    k = 0
    start = s.chain_start
    node_blocks = values.size > 0 and node_terms.any_active(s.node_term_active)
    for y in range(start.size - 1):
        for i in range(start[y], start[y + 1] - 1):
            nodes = np.arange(i, i + 2)
            _gather(pos, nodes, pair)
            element.stretch_derivatives(pair, s.stretch_stiffness[i - y], s.rest_length[i - y],
                                        g6, H6)
            if node_blocks:
                _add_node_blocks(pos, s, i, i + 2 == start[y + 1], H6)
            k = _emit(nodes, g6, H6, grad, values, k)
        for i in range(start[y] + 1, start[y + 1] - 1):
            nodes = np.arange(i - 1, i + 2)
            _gather(pos, nodes, triple)
            element.bend_derivatives(triple, s.bend_stiffness[i], s.rest_angle[i],
                                     s.lateral_bend_stiffness[i], s.lateral_rest_angle[i],
                                     g9, H9)
            k = _emit(nodes, g9, H9, grad, values, k)
    if grad.shape[0]:
        contact.add_gradient(pos, s, grad)
        node_terms.add_gradient(pos, s.rest_position, s.node_parameters, s.node_term_active,
                                grad)
    for c in range(s.tie_a.size):
        if values.size:
            g = contact.closure(pos, s, c)
            law = s.tie_contact_law[c]
            t = contact.crossing_tangent(g, contact.force(g, law), law)
            values[k], values[k + 1], values[k + 2], values[k + 3] = t, -t, -t, t
            k += 4
        rho, K, phi_rest, stick = _crossing_law(s, c)
        _gather(pos, s.tie_stencil[c], six)
        weight = 0.0
        if secant is not None:
            weight = secant[c]
        element.crossing_derivatives(six, anchors[c], rho, limit[c], stick, K, phi_rest, weight,
                                     g18, H18)
        k = _emit_in_plane(s.tie_stencil[c], g18, H18, grad, values, k)
    for e in range(s.lateral_stencil.shape[0]):
        _gather(pos, s.lateral_stencil[e], four)
        law = s.lateral_law[e]
        element.lateral_derivatives(four, law[SIGN], law[WIDTH], law[LATERAL_K], g12, H12,
                                    law[BRANCH], law[COMPACTION], law[PACKED], law[CORE_FROM])
        k = _emit_in_plane(s.lateral_stencil[e], g12, H12, grad, values, k)


@numba.njit(cache=True)
def gradient(pos, s, P, anchors, limit, grad):
    """grad = dV/dr (nodes, 3) [N], F_T frozen; P unused (no end loads)."""
    grad[:, :] = 0.0
    _derivatives(pos, s, anchors, limit, None, grad, np.zeros(0))


@numba.njit(cache=True)
def hessian_values(pos, s, anchors, limit, values, secant=None):
    """The Hessian's entries in `pattern_entries`' order [N/m], F_T = `limit` frozen;
    `secant` (T,): each crossing's weight of its secant friction stiffness when sliding
    (`dynfab.model.terms.spatial.huber3_hessian`), None: 0."""
    _derivatives(pos, s, anchors, limit, secant, np.zeros((0, 3)), values)


@numba.njit(cache=True)
def crossing_slips(pos, s, anchors, out):
    """Each crossing's slip S (`dynfab.model.terms.spatial.crossing_slip`) into out (T, 3) [m]: what
    the Newton's secant weights watch (`dynfab.solvers.newton_sparse.kinked`)."""
    six = np.empty((6, 3))
    for c in range(s.tie_a.size):
        _gather(pos, s.tie_stencil[c], six)
        out[c] = element.crossing_slip(six, anchors[c], s.tie_rotation_law[c, RHO])


def _block(nodes: np.ndarray, components: int = 3) -> tuple[np.ndarray, np.ndarray]:
    """(rows, cols) of the dense blocks on the first `components` dofs of each node of each
    row of `nodes` (E, m), row-major."""
    dofs = (3 * nodes[:, :, None] + np.arange(components)).reshape(nodes.shape[0],
                                                                  components * nodes.shape[1])
    m = dofs.shape[1]
    return np.repeat(dofs, m, axis=1).ravel(), np.tile(dofs, (1, m)).ravel()


def pattern_entries(s) -> tuple[np.ndarray, np.ndarray]:
    """(rows, cols) of every entry `hessian_values` fills, in its order."""
    rows, cols = [], []
    start = s.chain_start
    for y in range(start.size - 1):
        a, b = int(start[y]), int(start[y + 1])
        for width, first in ((2, a), (3, a)):
            count = b - a - width + 1
            if count <= 0:
                continue
            nodes = first + np.arange(count)[:, None] + np.arange(width)
            r, c = _block(nodes)
            rows.append(r)
            cols.append(c)
    z_a, z_b = 3 * s.tie_a + 2, 3 * s.tie_b + 2
    friction_rows, friction_cols = _block(s.tie_stencil, IN_PLANE)
    per = (IN_PLANE * s.tie_stencil.shape[1]) ** 2
    for c in range(s.tie_a.size):
        rows.append(np.array([z_a[c], z_a[c], z_b[c], z_b[c]]))
        cols.append(np.array([z_a[c], z_b[c], z_a[c], z_b[c]]))
        rows.append(friction_rows[c * per:(c + 1) * per])
        cols.append(friction_cols[c * per:(c + 1) * per])
    r, c = _block(s.lateral_stencil, IN_PLANE)
    rows.append(r)
    cols.append(c)
    return (np.concatenate(rows).astype(np.int64) if rows else np.zeros(0, np.int64),
            np.concatenate(cols).astype(np.int64) if cols else np.zeros(0, np.int64))


_PATTERNS: dict[tuple, tuple] = {}
"""The last few spatial structures' `Pattern`s, by the ids of `_topology` (kept beside)."""


def _topology(structure) -> tuple:
    """The arrays a spatial structure's `Pattern` is made of: a structure derived from
    another by a law (`_replace`, as the static solver's held lateral set,
    `dynfab.solvers.newton_sparse.held_lateral_set`) shares them, and with them the pattern and its
    nested-dissection order."""
    s = structure
    return (s.chain_start, s.tie_a, s.tie_b, s.tie_stencil, s.lateral_stencil, s.fixed,
            s.dof_tie)


def pattern_of(structure) -> Pattern:
    """The `Pattern` of a spatial structure, made once per topology and kept
    (`assembly.kept_pattern`)."""
    return kept_pattern(_PATTERNS, _topology(structure),
                        lambda: Pattern(structure, pattern_entries(structure)))


def sparse_hessian(structure, pos, anchors, limit, secant=0.0):
    """The Hessian of V plus the friction terms on the structure's unknowns [N/m] (CSC);
    `secant`: one weight for every crossing or one per crossing (`hessian_values`)."""
    pattern = pattern_of(structure)
    values = np.zeros(pattern.size)
    hessian_values(pos, structure, anchors, limit, values,
                   secant_weights(secant, structure.tie_a.size))
    return pattern.matrix(values)


def energy_vector(structure, pos, P, anchors, limit) -> np.ndarray:
    """Each term's energy [J] (`TERMS`)."""
    out = np.zeros(len(TERMS))
    energies(pos, structure, np.asarray(P, float), anchors, limit, out)
    return out


@numba.njit(cache=True)
def rounding_scale(pos, s, P, limit):
    """S [J] with the rounding of V about eps S (docs/model.md section 6's rounding rule):
    every element's forces times the sizes of the coordinates they act on, in absolute
    values (the planar `assembly.rounding_scale`'s rule on the spatial elements)."""
    total = 0.0
    pair, triple = np.empty((2, 3)), np.empty((3, 3))
    six, four = np.empty((6, 3)), np.empty((4, 3))
    g6, g9, g18, g12 = np.empty(6), np.empty(9), np.empty(18), np.empty(12)
    H6, H9, H18, H12 = np.empty((6, 6)), np.empty((9, 9)), np.empty((18, 18)), np.empty((12, 12))
    start = s.chain_start
    for y in range(start.size - 1):
        for i in range(start[y], start[y + 1] - 1):
            _gather(pos, np.arange(i, i + 2), pair)
            element.stretch_derivatives(pair, s.stretch_stiffness[i - y], s.rest_length[i - y],
                                        g6, H6)
            total += np.sum(np.abs(g6) * np.abs(pair.ravel()))
        for i in range(start[y] + 1, start[y + 1] - 1):
            _gather(pos, np.arange(i - 1, i + 2), triple)
            element.bend_derivatives(triple, s.bend_stiffness[i], s.rest_angle[i],
                                     s.lateral_bend_stiffness[i], s.lateral_rest_angle[i],
                                     g9, H9)
            total += np.sum(np.abs(g9) * np.abs(triple.ravel()))
    for c in range(s.tie_a.size):
        g = contact.closure(pos, s, c)
        R = contact.force(g, s.tie_contact_law[c])
        total += R * (abs(pos[s.tie_a[c], 2]) + abs(pos[s.tie_b[c], 2]) + abs(g))
        rho, K, phi_rest, stick = _crossing_law(s, c)
        _gather(pos, s.tie_stencil[c], six)
        total += limit[c] * np.sum(np.abs(six[:, :2]))
        element.crossing_derivatives(six, np.zeros(3), rho, 0.0, stick, K, phi_rest, 0.0,
                                     g18, H18)
        total += np.sum(np.abs(g18) * np.abs(six.ravel()))
    for e in range(s.lateral_stencil.shape[0]):
        _gather(pos, s.lateral_stencil[e], four)
        law = s.lateral_law[e]
        element.lateral_derivatives(four, law[SIGN], law[WIDTH], law[LATERAL_K], g12, H12,
                                    law[BRANCH], law[COMPACTION], law[PACKED], law[CORE_FROM])
        total += np.sum(np.abs(g12) * np.abs(four.ravel()))
    return total


@numba.njit(cache=True)
def slip_direction(pos, anchors, s, limit, c, out):
    """d(dV/dr)/dF_T of tie c on its stencil's dofs into out (18,): J^T D S/|S| where the
    crossing slides (dH/dS = F_T S/|S|), zeros where it sticks (dH/dS = k_t S): the
    friction's dependence on the limit, for the coupled Newton's Jacobian."""
    rho, K, phi_rest, stick = _crossing_law(s, c)
    six = np.empty((6, 3))
    _gather(pos, s.tie_stencil[c], six)
    S = element.crossing_slip(six, anchors[c], rho)
    norm = np.sqrt(S[0] * S[0] + S[1] * S[1] + S[2] * S[2])
    out[:] = 0.0
    if not (limit[c] > 0.0 and huber_law.slides(norm, limit[c], stick) and norm > 0.0):
        return
    q, J, K3 = np.empty(3), np.empty((3, 18)), np.empty((3, 18, 18))
    element.crossing_kinematics(six, q, J, K3)
    unit = np.array([S[0], S[1], rho * S[2]]) / norm  # D S / |S|, D = diag(1, 1, rho)
    for j in range(18):
        out[j] = J[0, j] * unit[0] + J[1, j] * unit[1] + J[2, j] * unit[2]


@numba.njit(cache=True)
def return_map(pos, anchors, s, limit, sliding, friction_force):
    """The radial return of every sliding crossing's anchor (`dynfab.model.terms.spatial`), in
    place; returns the energy lost [J]. Fills `sliding` (T,) and the friction force on the
    slip (T, 3): [N, N, N] (-k_t S sticking, -F_T S/|S| sliding; the third is the moment
    over rho)."""
    lost = 0.0
    six = np.empty((6, 3))
    for c in range(s.tie_a.size):
        rho, K, phi_rest, stick = _crossing_law(s, c)
        _gather(pos, s.tie_stencil[c], six)
        S = element.crossing_slip(six, anchors[c], rho)
        norm = np.sqrt(S[0] * S[0] + S[1] * S[1] + S[2] * S[2])
        F = limit[c]
        if F > 0.0 and huber_law.moves(norm, F, stick):
            friction_force[c, :] = -F * S / norm
        elif F > 0.0:
            friction_force[c, :] = -stick * S
        else:
            friction_force[c, :] = 0.0
        energy, slid = element.crossing_return_map(six, anchors[c], rho, F, stick)
        sliding[c] = slid
        lost += energy
    return lost


def coupling_rows(structure, pos, anchors, limit, c) -> tuple[np.ndarray, np.ndarray]:
    """(dofs, values): d(dV/dr)/dF_T of tie c on its stencil's dofs (`slip_direction`), empty
    where it sticks (as `dynfab.model.fabric.assembly.coupling_rows`)."""
    out = np.zeros(18)
    slip_direction(pos, anchors, structure, limit, c, out)
    if not np.any(out):
        return np.zeros(0, np.int64), np.zeros(0)
    return (3 * structure.tie_stencil[c][:, None] + np.arange(3)).ravel(), out



def stiffest_rows(structure, pos, anchors) -> tuple[np.ndarray, np.ndarray]:
    """Per node, (the largest over its three dofs of sum_j |K_ij|, its largest |K_ii|) [N/m]
    of the stiffest tangent K a load step from `pos` can meet (docs/model.md, "The dynamic
    solver (decisions)": masses and time step): every crossing sticking (F_T infinite where
    the structure has friction), every contact at its bound k_s, the other terms exact at
    `pos`; on every dof, held ones included, as the planar kernels' band. The dynamic solver's
    Gershgorin masses of a spatial structure (`dynfab.kernels.structure_checks`)."""
    s = structure
    pattern = pattern_of(s)
    limit = np.full(s.tie_a.size, np.inf if s.has_friction else 0.0)
    values = np.zeros(pattern.size)
    hessian_values(pos, s, np.asarray(anchors, float), limit, values)
    return rows_at_contact_bound(pos, s, pattern.rows, pattern.cols, values)


def rows_at_contact_bound(pos, s, rows, cols, values) -> tuple[np.ndarray, np.ndarray]:
    """Per node, (the largest over its dofs of sum_j |K_ij|, its largest |K_ii|) [N/m] of the
    Hessian K whose entries (rows, cols, values) are on every dof (n dim), each tie's contact
    raised from its dR/dg at `pos` (the physical positions) to its bound k_s on (z_a, z_b)."""
    n, d = pos.shape
    tangent = np.zeros(s.tie_a.size)
    contact.tangents(pos, s, tangent)
    raise_to = np.asarray(s.tie_contact_law, float)[:, 0] - tangent  # k_s - dR/dg
    z_a, z_b = d * s.tie_a + d - 1, d * s.tie_b + d - 1
    rows = np.concatenate([rows, z_a, z_a, z_b, z_b])
    cols = np.concatenate([cols, z_a, z_b, z_a, z_b])
    values = np.concatenate([values, raise_to, -raise_to, -raise_to, raise_to])
    K = scipy.sparse.coo_matrix((values, (rows, cols)), shape=(d * n, d * n)).tocsr()
    K.sum_duplicates()
    row_sums = np.asarray(abs(K).sum(axis=1)).ravel().reshape(n, d)
    diagonal = np.abs(K.diagonal()).reshape(n, d)
    return row_sums.max(axis=1), diagonal.max(axis=1)
