"""The fabric's energy, gradient and sparse Hessian (docs/model.md sections 2, 10).

On the periodic cell two more pieces: the bending spring across the wrap at each yarn's
node 0 (segment N-1's image, then segment 0), and the planes X_j, Y_k moving with the
cell's stretch, so the slip also depends on the yarn end nodes that hold the cell
length; and the cell length is one unknown per family (tied dofs, `Pattern.index`).

V = sum_yarns (E_stretch + E_bend) + sum_c E_contact,c + sum_c H_c - W_load - W_gravity

with the one-yarn stretch and bending terms (`dynfab.model.terms.stretch`, `bending`) on each
yarn's own (in-plane coordinate, z) chain, the two-node contact (`dynfab.model.fabric.contact`)
and the 2D Huber friction (`dynfab.model.fabric.friction`, F_T frozen) per crossing, and the end
load along each yarn, W_load = sum_y P_y (u_N,y - u0_N,y) (force control; 0 under
displacement control), and gravity on the physical masses when asked
(`dynfab.model.terms.gravity`, docs/model.md section 2).

The Hessian is one band per yarn (half-bandwidth `dynfab.linalg.banded.BANDWIDTH` in that yarn's
dofs, which are contiguous) plus, per crossing, the contact block on (z_a, z_b) and the
friction block on (x_a, y_b). `Pattern` fixes the order of its entries once; numba fills
the values in that order, and `Pattern.matrix` sums them into a scipy CSC matrix on the
free dofs.
"""

from __future__ import annotations

import numba
import numpy as np
import scipy.sparse

from dynfab.linalg.banded import BANDWIDTH
from dynfab.model.fabric import contact, friction
from dynfab.model.terms import bending, gravity, stretch
from dynfab.model.terms import nodes as node_terms

STRETCH, BENDING, CONTACT, FRICTION, LOAD, GRAVITY = range(6)
"""Indices of the energy vector."""
TERMS = ("stretch", "bending", "contact", "friction", "load", "gravity", *node_terms.NAMES)
"""The energy vector's terms: the fabric's own, then the registry's node terms
(`dynfab.model.terms.nodes`) from NODE_TERMS on."""
NODE_TERMS = 6
SOLVE_ON_KEPT_FACTORS = False
"""Whether Newton's Hessian solves try GMRES on the step's last factors first
(`dynfab.model.fabric.kept_factor`): not on the planar fabric, whose factorisation costs so few
triangular solves that the attempts that fail cost more than the ones that succeed save
(docs/model.md 11.10; docs/results.md, "Solves on kept factors")."""


@numba.njit(cache=True)
def energies(pos, fabric, P, anchors, limit, out):
    """Each term's energy [J] into out (len(TERMS),); P the end force per yarn (Y,) [N]."""
    out[:] = 0.0
    start = fabric.chain_start
    for y in range(start.size - 1):
        a, b = start[y], start[y + 1]
        out[STRETCH] += stretch.energy(pos[a:b], fabric.rest_length[a - y:b - y - 1],
                                       fabric.stretch_stiffness[a - y:b - y - 1])
        out[BENDING] += bending.energy(pos[a:b], fabric.bend_stiffness[a:b],
                                       fabric.rest_angle[a:b])
        n = fabric.load_node[y]
        out[LOAD] -= P[y] * (pos[n, 0] - fabric.rest_position[n, 0])
        if fabric.wrap_stiffness[y] > 0.0:
            d = wrap_angle(pos, fabric, y) - fabric.wrap_rest_angle[y]
            out[BENDING] += 0.5 * fabric.wrap_stiffness[y] * d * d
    out[CONTACT] = contact.energy(pos, fabric)
    if fabric.has_friction:
        px, py = planes(pos, fabric)
        out[FRICTION] = friction.energy(pos, anchors, fabric, px, py, limit)
    out[GRAVITY] = gravity.energy_per_node(pos, fabric.rest_position, fabric.mass, fabric.gravity)
    node_terms.energies(pos, fabric.rest_position, fabric.node_parameters,
                        fabric.node_term_active, out[NODE_TERMS:])


@numba.njit(cache=True)
def total_energy(pos, fabric, P, anchors, limit, out):
    """V [J] (its terms left in out)."""
    energies(pos, fabric, P, anchors, limit, out)
    return out.sum()


@numba.njit(cache=True)
def gradient(pos, fabric, P, anchors, limit, grad):
    """grad = dV/dr (nodes, 2) [N], F_T frozen."""
    grad[:, :] = 0.0
    start = fabric.chain_start
    for y in range(start.size - 1):
        a, b = start[y], start[y + 1]
        stretch.add_gradient(pos[a:b], fabric.rest_length[a - y:b - y - 1],
                             fabric.stretch_stiffness[a - y:b - y - 1], grad[a:b])
        bending.add_gradient(pos[a:b], fabric.bend_stiffness[a:b], fabric.rest_angle[a:b],
                             grad[a:b])
        grad[fabric.load_node[y], 0] -= P[y]
        if fabric.wrap_stiffness[y] > 0.0:
            _add_wrap_gradient(pos, fabric, y, grad)
    contact.add_gradient(pos, fabric, grad)
    gravity.add_gradient_per_node(fabric.mass, fabric.gravity, grad)
    node_terms.add_gradient(pos, fabric.rest_position, fabric.node_parameters,
                            fabric.node_term_active, grad)
    if fabric.has_friction:
        px, py = planes(pos, fabric)
        for c in range(fabric.tie_a.size):
            sx, sy = friction.slip(pos, anchors, fabric, px, py, c)
            gx, gy = friction.huber_gradient(sx, sy, limit[c],
                                             fabric.tie_friction_law[c, friction.STICK])
            grad[fabric.tie_a[c], 0] += gx
            if fabric.tie_b[c] >= 0:
                grad[fabric.tie_b[c], 0] += gy
            nx, ny = fabric.plane_nodes_a.size, fabric.plane_nodes_b.size
            for node in fabric.plane_nodes_a:
                grad[node, 0] -= fabric.tie_plane_weight[c, 0] / nx * gx
            for node in fabric.plane_nodes_b:
                grad[node, 0] -= fabric.tie_plane_weight[c, 1] / ny * gy


@numba.njit(cache=True)
def planes(pos, fabric):
    """(X_j, Y_k) of every crossing [m]: as woven, moved with the mean end displacement of
    each family where the planes follow it (periodic cell, planes "affine";
    docs/model.md section 10): X_j = X0_j + w_j mean_k (x_N,k - x0_N,k)."""
    u_x, u_y = 0.0, 0.0
    for node in fabric.plane_nodes_a:
        u_x += (pos[node, 0] - fabric.rest_position[node, 0]) / fabric.plane_nodes_a.size
    for node in fabric.plane_nodes_b:
        u_y += (pos[node, 0] - fabric.rest_position[node, 0]) / fabric.plane_nodes_b.size
    return (fabric.tie_plane[:, 0] + fabric.tie_plane_weight[:, 0] * u_x,
            fabric.tie_plane[:, 1] + fabric.tie_plane_weight[:, 1] * u_y)


@numba.njit(cache=True)
def slip_jacobian(fabric, c):
    """ds/d(x_a, y_b, x_N..., y_M...) of crossing c (2, 2 + n_x + n_y): the slip's own nodes,
    then the end nodes moving the planes (weights -w / n each)."""
    nx, ny = fabric.plane_nodes_a.size, fabric.plane_nodes_b.size
    J = np.zeros((2, 2 + nx + ny))
    J[0, 0] = 1.0
    J[1, 1] = 1.0 if fabric.tie_b[c] >= 0 else 0.0
    for m in range(nx):
        J[0, 2 + m] = -fabric.tie_plane_weight[c, 0] / nx
    for m in range(ny):
        J[1, 2 + nx + m] = -fabric.tie_plane_weight[c, 1] / ny
    return J


@numba.njit(cache=True)
def _wrap_points(pos, fabric, y):
    """(r_{N-1}, r_N, r_N + r_1 - r_0) of yarn y: the three points whose turning angle at the
    middle one is the bending angle across the periodic wrap (segment N-1, then segment 0
    shifted by the cell length)."""
    a, b = fabric.chain_start[y], fabric.chain_start[y + 1]
    p = np.empty((3, 2))
    p[0, :] = pos[b - 2]
    p[1, :] = pos[b - 1]
    p[2, :] = pos[b - 1] + pos[a + 1] - pos[a]
    return p


@numba.njit(cache=True)
def wrap_angle(pos, fabric, y):
    """The turning angle [rad] at node 0 of a periodic yarn (docs/model.md section 10)."""
    return bending.turning_angle(_wrap_points(pos, fabric, y), 1)


@numba.njit(cache=True)
def _wrap_dofs(fabric, y):
    """Dofs of (r_{N-1}, r_N, r_0, r_1) of yarn y, and the map M (6, 8) from them to the
    three wrap points: p0 = r_{N-1}, p1 = r_N, p2 = r_N + r_1 - r_0."""
    a, b = fabric.chain_start[y], fabric.chain_start[y + 1]
    dofs = np.empty(8, np.int64)
    for m, node in enumerate((b - 2, b - 1, a, a + 1)):
        dofs[2 * m], dofs[2 * m + 1] = 2 * node, 2 * node + 1
    M = np.zeros((6, 8))
    for k in range(2):
        M[k, k] = 1.0
        M[2 + k, 2 + k] = 1.0
        M[4 + k, 2 + k] = 1.0
        M[4 + k, 6 + k] = 1.0
        M[4 + k, 4 + k] = -1.0
    return dofs, M


@numba.njit(cache=True)
def wrap_gradient(pos, fabric, y, out):
    """The wrap spring's energy 1/2 k (phi - phi0)^2 [J] (returned) and its gradient
    k (phi - phi0) dphi/dr on its 8 dofs (`_wrap_dofs`) into out (8,) [N] (the chain rule
    through `_wrap_dofs`' map)."""
    p = _wrap_points(pos, fabric, y)
    g = np.empty(6)
    bending._angle_gradient(p, 1, g)
    d = bending.turning_angle(p, 1) - fabric.wrap_rest_angle[y]
    moment = fabric.wrap_stiffness[y] * d
    _, M = _wrap_dofs(fabric, y)
    full = M.T @ g
    for m in range(8):
        out[m] = moment * full[m]
    return 0.5 * fabric.wrap_stiffness[y] * d * d


@numba.njit(cache=True)
def _add_wrap_gradient(pos, fabric, y, grad):
    """grad += the wrap spring's gradient (`wrap_gradient`)."""
    local = np.empty(8)
    wrap_gradient(pos, fabric, y, local)
    dofs, _ = _wrap_dofs(fabric, y)
    flat = grad.reshape(-1)
    for m in range(8):
        flat[dofs[m]] += local[m]


@numba.njit(cache=True)
def wrap_hessian(pos, fabric, y):
    """(dofs (8,), the wrap spring's Hessian (8, 8)) of yarn y: M^T (k g g^T + m H) M."""
    p = _wrap_points(pos, fabric, y)
    g, h = np.empty(6), np.empty((6, 6))
    bending._angle_gradient(p, 1, g)
    bending._angle_hessian(p, 1, h)
    k = fabric.wrap_stiffness[y]
    moment = k * (bending.turning_angle(p, 1) - fabric.wrap_rest_angle[y])
    local = k * np.outer(g, g) + moment * h
    dofs, M = _wrap_dofs(fabric, y)
    return dofs, M.T @ local @ M


@numba.njit(cache=True)
def yarn_band(pos, fabric, y, band):
    """band = d2(E_stretch + E_bend + the node terms)/dr2 of yarn y in its own dofs
    (`dynfab.linalg.banded` layout)."""
    a, b = fabric.chain_start[y], fabric.chain_start[y + 1]
    band[:, :] = 0.0
    stretch.add_hessian(pos[a:b], fabric.rest_length[a - y:b - y - 1],
                        fabric.stretch_stiffness[a - y:b - y - 1], band)
    bending.add_hessian(pos[a:b], fabric.bend_stiffness[a:b], fabric.rest_angle[a:b], band)
    node_terms.add_band(pos[a:b], fabric.rest_position[a:b], fabric.node_parameters[a:b],
                        fabric.node_term_active, band)


@numba.njit(cache=True)
def crossing_blocks(pos, fabric, anchors, limit, tangent, huber, secant=None):
    """dR/dg per crossing into tangent (C,) and the Huber block (h_xx, h_xy, h_yy) into
    huber (C, 3) (zeros without friction; `secant`: see `friction.hessians`)."""
    contact.tangents(pos, fabric, tangent)
    huber[:, :] = 0.0
    if fabric.has_friction:
        px, py = planes(pos, fabric)
        friction.hessians(pos, anchors, fabric, px, py, limit, huber, secant)


@numba.njit(cache=True)
def hessian_values(pos, fabric, anchors, limit, values, secant=None):
    """The Hessian's entries (F_T frozen) in `Pattern` order into values; `secant` (C,):
    each crossing's weight of its secant stiffness when sliding (`friction.huber_hessian`),
    None: 0."""
    start = fabric.chain_start
    k = 0
    for y in range(start.size - 1):
        n = 2 * (start[y + 1] - start[y])
        band = np.zeros((n, 2 * BANDWIDTH + 1))
        yarn_band(pos, fabric, y, band)
        for i in range(n):
            for o in range(2 * BANDWIDTH + 1):
                j = i + o - BANDWIDTH
                if 0 <= j < n:
                    values[k] = band[i, o]
                    k += 1
        if fabric.wrap_stiffness[y] > 0.0:
            _, block = wrap_hessian(pos, fabric, y)
            values[k:k + 64] = block.ravel()
            k += 64
    c_count = fabric.tie_a.size
    tangent, huber = np.zeros(c_count), np.zeros((c_count, 3))
    crossing_blocks(pos, fabric, anchors, limit, tangent, huber, secant)
    for c in range(c_count):
        t = tangent[c]
        if fabric.tie_b[c] >= 0:
            values[k:k + 4] = (t, -t, -t, t)
        else:  # to ground: on z_a alone (`Pattern` puts all four entries there)
            values[k:k + 4] = (t, 0.0, 0.0, 0.0)
        k += 4
        J = slip_jacobian(fabric, c)
        h = np.array([[huber[c, 0], huber[c, 1]], [huber[c, 1], huber[c, 2]]])
        block = (J.T @ h @ J).ravel()
        values[k:k + block.size] = block
        k += block.size


def slip_dofs(fabric, c) -> np.ndarray:
    """The dofs of `slip_jacobian`'s columns for crossing c: x_a, y_b, then the end nodes'
    in-plane dofs that move the planes."""
    b = fabric.tie_b[c] if fabric.tie_b[c] >= 0 else fabric.tie_a[c]  # ground: J's column is 0
    return np.concatenate([[2 * fabric.tie_a[c], 2 * b],
                           2 * fabric.plane_nodes_a, 2 * fabric.plane_nodes_b]).astype(np.int64)


def wrap_dofs_of(fabric, y) -> np.ndarray:
    """The 8 dofs of yarn y's wrap spring (`_wrap_dofs`), in plain numpy."""
    a, b = fabric.chain_start[y], fabric.chain_start[y + 1]
    nodes = np.array([b - 2, b - 1, a, a + 1])
    return np.stack([2 * nodes, 2 * nodes + 1], axis=1).ravel()


def pattern_entries(fabric) -> tuple[np.ndarray, np.ndarray]:
    """(rows, cols) of every entry `hessian_values` fills, in its order."""
    rows, cols = [], []
    start = fabric.chain_start
    for y in range(start.size - 1):
        n = 2 * (start[y + 1] - start[y])
        i, o = np.meshgrid(np.arange(n), np.arange(2 * BANDWIDTH + 1), indexing="ij")
        j = i + o - BANDWIDTH
        keep = (j >= 0) & (j < n)
        rows.append(2 * start[y] + i[keep])
        cols.append(2 * start[y] + j[keep])
        if fabric.wrap_stiffness[y] > 0.0:
            dofs = wrap_dofs_of(fabric, y)
            rows.append(np.repeat(dofs, 8))
            cols.append(np.tile(dofs, 8))
    za = 2 * fabric.tie_a + 1
    zb = np.where(fabric.tie_b >= 0, 2 * fabric.tie_b + 1, za)  # ground: a's own z
    for c in range(za.size):
        friction_dofs = slip_dofs(fabric, c)
        rows.append(np.array([za[c], za[c], zb[c], zb[c]]))
        cols.append(np.array([za[c], zb[c], za[c], zb[c]]))
        rows.append(np.repeat(friction_dofs, friction_dofs.size))
        cols.append(np.tile(friction_dofs, friction_dofs.size))
    return np.concatenate(rows), np.concatenate(cols)


class Pattern:
    """Row and column of every Hessian entry `hessian_values` fills, and the free dofs."""

    def __init__(self, fabric, entries=None):
        """The planar fabric's entries (`pattern_entries`), or `entries` = (rows, cols) as
        another term set fills them (the spatial fabric's, `dynfab.model.fabric.spatial`)."""
        rows, cols = pattern_entries(fabric) if entries is None else entries
        self.rows, self.cols = rows, cols
        self.size = rows.size
        self.free = ~fabric.fixed
        # the unknowns: one per free dof, a tied dof sharing its master's (periodic cell)
        index = np.full(fabric.fixed.size, -1)
        own = self.free & (fabric.dof_tie < 0)
        index[own] = np.arange(own.sum())
        tied = self.free & (fabric.dof_tie >= 0)
        index[tied] = index[fabric.dof_tie[tied]]
        self.index = index
        self.free_count = int(own.sum())
        keep = (index[rows] >= 0) & (index[cols] >= 0)
        self._keep = keep
        # CSC assembly through a fixed sparse summation matrix: entry e of `values`
        # goes to slot slot[e] of the CSC data (duplicates share a slot).
        r, c = index[rows[keep]], index[cols[keep]]
        key = c * self.free_count + r
        unique, slot = np.unique(key, return_inverse=True)
        self._slot = slot
        self._slots = unique.size
        self._indices = (unique % self.free_count).astype(np.int32)
        columns = unique // self.free_count
        self._indptr = np.searchsorted(columns, np.arange(self.free_count + 1)).astype(np.int32)

    def reduce(self, full) -> np.ndarray:
        """A dof vector (gradient) on the unknowns: summed over each unknown's dofs."""
        flat = np.asarray(full).ravel()
        keep = self.index >= 0
        return np.bincount(self.index[keep], weights=flat[keep], minlength=self.free_count)

    def expand(self, reduced) -> np.ndarray:
        """An unknowns' vector (a step) on every dof: 0 on the fixed ones."""
        out = np.zeros(self.index.size)
        keep = self.index >= 0
        out[keep] = reduced[self.index[keep]]
        return out

    def matrix(self, values) -> scipy.sparse.csc_matrix:
        """The Hessian on the unknowns (CSC), from `hessian_values`' entries (T^T H T with
        T the 0/1 map from unknowns to dofs)."""
        data = np.bincount(self._slot, weights=values[self._keep], minlength=self._slots)
        return self.csc(data)

    def counts(self) -> scipy.sparse.csc_matrix:
        """The matrix on the unknowns whose every entry counts the Hessian entries summed into
        it: its sparsity, what an ordering reads."""
        return self.csc(np.bincount(self._slot, minlength=self._slots).astype(float))

    def csc(self, data) -> scipy.sparse.csc_matrix:
        """The CSC matrix on the unknowns of the summed entries `data` (one per slot)."""
        return scipy.sparse.csc_matrix((data, self._indices, self._indptr),
                                       shape=(self.free_count, self.free_count))

    def full_matrix(self, values) -> np.ndarray:
        """The Hessian on every dof, dense (for tests and small checks)."""
        n = self.free.size
        return scipy.sparse.coo_matrix((values, (self.rows, self.cols)), shape=(n, n)).toarray()


@numba.njit(cache=True)
def rounding_scale(pos, fabric, P, limit):
    """S [J] with the rounding of V about eps S: sum_i |r_i| sum_terms |dE_term/dr_i|.

    A coordinate r_i rounds by eps |r_i| (not eps times a segment length), which moves a
    term by |dE_term/dr_i| eps |r_i|; summed per term with absolute values, because the
    terms' forces cancel at equilibrium while their roundings do not. Stretch: the
    segment tension |k (l - l0)| on both end nodes; bending: the moment |k (phi - phi0)|
    over the segment lengths on three nodes; contact: R on both z; friction: F_T on the
    slip coordinates; load: |P| on the end node; gravity m g on z (docs/model.md section 6's
    rounding rule).
    """
    total = 0.0
    start = fabric.chain_start
    for y in range(start.size - 1):
        a, b = start[y], start[y + 1]
        for i in range(a, b - 1):
            ex, ez = pos[i + 1, 0] - pos[i, 0], pos[i + 1, 1] - pos[i, 1]
            length = np.sqrt(ex * ex + ez * ez)
            tension = abs(fabric.stretch_stiffness[i - y] * (length - fabric.rest_length[i - y]))
            size = abs(pos[i, 0]) + abs(pos[i, 1]) + abs(pos[i + 1, 0]) + abs(pos[i + 1, 1])
            total += tension * size
            if i > a:
                moment = abs(fabric.bend_stiffness[i] * (bending.turning_angle(pos, i)
                                                          - fabric.rest_angle[i]))
                total += 3.0 * moment * size / length
        n = fabric.load_node[y]
        total += abs(P[y]) * abs(pos[n, 0])
    for i in range(fabric.mass.size):
        total += fabric.mass[i] * abs(fabric.gravity[i]) * abs(pos[i, 1])
    for c in range(fabric.tie_a.size):
        a, b = fabric.tie_a[c], fabric.tie_b[c]
        zb, xb = (abs(pos[b, 1]), abs(pos[b, 0])) if b >= 0 else (0.0, 0.0)
        g = contact.closure(pos, fabric, c)
        total += contact.force(g, fabric.tie_contact_law[c]) * (abs(pos[a, 1]) + zb + abs(g))
        total += limit[c] * (abs(pos[a, 0]) + xb)
    return total


_PATTERNS: dict[tuple, tuple] = {}
"""The last few planar structures' `Pattern`s, by the structure's id (kept alive beside)."""
PATTERNS_KEPT = 8


def kept_pattern(cache: dict, arrays: tuple, make) -> Pattern:
    """The pattern made of `arrays` (what a structure's pattern depends on), taken from
    `cache` where it was made of the very same arrays, else `make()` kept there (the oldest
    of PATTERNS_KEPT dropped): the static solver, the certificate and the model share it, and
    with it the nested-dissection order (`dynfab.model.fabric.ordering`)."""
    key = tuple(map(id, arrays))
    entry = cache.get(key)
    if entry is None or any(a is not b for a, b in zip(entry[0], arrays)):
        if len(cache) >= PATTERNS_KEPT:
            cache.pop(next(iter(cache)))
        entry = cache[key] = (arrays, make())
    return entry[1]


def pattern_of(structure) -> Pattern:
    """The `Pattern` of a structure, made once (`kept_pattern`)."""
    return kept_pattern(_PATTERNS, (structure,), lambda: Pattern(structure))


def secant_weights(secant, count: int) -> np.ndarray | None:
    """`secant` (a weight in [0, 1] for every tie, or one per tie) as the (count,) array the
    Hessians take, or None where every weight is 0 (the exact Hessian)."""
    weights = np.asarray(secant, float)
    if not np.any(weights):
        return None
    return np.ascontiguousarray(np.broadcast_to(weights, (count,)))


def sparse_hessian(structure, pos, anchors, limit, secant=0.0):
    """The Hessian of V plus the Huber terms on the structure's unknowns [N/m] (CSC), F_T =
    `limit` frozen (docs/model.md (6.1)); `secant` in [0, 1], one for all ties or one per
    tie: the weight of each sliding tie's secant stiffness
    (`dynfab.model.fabric.friction.huber_hessian`)."""
    pattern = pattern_of(structure)
    values = np.zeros(pattern.size)
    hessian_values(pos, structure, anchors, limit, values,
                   secant_weights(secant, structure.tie_a.size))
    return pattern.matrix(values)


def crossing_slips(pos, structure, anchors, out) -> None:
    """Every tie's slip (s_x, s_y, 0) [m] into out (T, 3), the planes at `pos`: what the
    Newton's secant weights watch (`dynfab.solvers.newton_sparse.kinked`)."""
    px, py = planes(pos, structure)
    friction.slips(pos, anchors, structure, px, py, out)


def energy_vector(structure, pos, P, anchors, limit) -> np.ndarray:
    """Each term's energy [J] (`TERMS`) at `pos` under end loads P (Y,) [N], F_T = `limit`
    frozen."""
    out = np.zeros(len(TERMS))
    energies(pos, structure, np.asarray(P, float), anchors, limit, out)
    return out


def return_map(pos, anchors, structure, limit, sliding, friction_force) -> float:
    """The anchors' radial return at `pos`, the planes there, in place
    (`dynfab.model.fabric.friction.return_map`); returns the energy lost [J]."""
    px, py = planes(pos, structure)
    return friction.return_map(pos, anchors, structure, px, py, limit, sliding, friction_force)


def coupling_rows(structure, pos, anchors, limit, c) -> tuple[np.ndarray, np.ndarray]:
    """(dofs, values): d(dV/dr)/dF_T of tie c, J^T s/|s| on its slip dofs where it slides
    (dH/ds = F_T s/|s|), empty where it sticks (dH/ds = k_t s): the friction's dependence on
    its limit, for the coupled Newton's Jacobian (`dynfab.solvers.newton_sparse`)."""
    px, py = planes(pos, structure)
    sx, sy = friction.slip(pos, anchors, structure, px, py, c)
    norm = np.hypot(sx, sy)
    stick = structure.tie_friction_law[c, friction.STICK]
    if not (limit[c] > 0.0 and friction.is_sliding(sx, sy, limit[c], stick)):
        return np.zeros(0, np.int64), np.zeros(0)
    return slip_dofs(structure, c), slip_jacobian(structure, c).T @ np.array([sx, sy]) / norm

