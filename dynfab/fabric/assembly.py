"""The fabric's energy, gradient and sparse Hessian (MODEL.md sections 2, 10).

V = sum_yarns (E_stretch + E_bend) + sum_c E_contact,c + sum_c H_c - W_load

with the one-yarn stretch and bending terms (`dynfab.terms.stretch`, `bending`) on each
yarn's own (in-plane coordinate, z) chain, the two-node contact (`dynfab.fabric.contact`)
and the 2D Huber friction (`dynfab.fabric.friction`, F_T frozen) per crossing, and the end
load along each yarn, W_load = sum_y P_y (u_N,y - u0_N,y) (force control; 0 under
displacement control).

The Hessian is one band per yarn (half-bandwidth `dynfab.banded.BANDWIDTH` in that yarn's
dofs, which are contiguous) plus, per crossing, the contact block on (z_a, z_b) and the
friction block on (x_a, y_b). `Pattern` fixes the order of its entries once; numba fills
the values in that order, and `Pattern.matrix` sums them into a scipy CSC matrix on the
free dofs.
"""

from __future__ import annotations

import numba
import numpy as np
import scipy.sparse

from dynfab.banded import BANDWIDTH
from dynfab.fabric import contact, friction
from dynfab.terms import bending, stretch

STRETCH, BENDING, CONTACT, FRICTION, LOAD = range(5)
"""Indices of the energy vector."""
TERMS = ("stretch", "bending", "contact", "friction", "load")


@numba.njit(cache=True)
def energies(pos, fabric, P, anchors, limit, out):
    """Each term's energy [J] into out (5,); P the end force per yarn (Y,) [N]."""
    out[:] = 0.0
    start = fabric.yarn_start
    for y in range(start.size - 1):
        a, b = start[y], start[y + 1]
        out[STRETCH] += stretch.energy(pos[a:b], fabric.rest_length[a - y:b - y - 1],
                                       fabric.stretch_stiffness[a - y:b - y - 1])
        out[BENDING] += bending.energy(pos[a:b], fabric.bend_stiffness[a:b],
                                       fabric.rest_angle[a:b])
        n = fabric.load_node[y]
        out[LOAD] -= P[y] * (pos[n, 0] - fabric.rest_position[n, 0])
    out[CONTACT] = contact.energy(pos, fabric.warp_node, fabric.weft_node, fabric.side,
                                  fabric.gap_offset, fabric.contact_law)
    if fabric.has_friction:
        out[FRICTION] = friction.energy(pos, anchors, fabric.warp_node, fabric.weft_node,
                                        fabric.plane_x, fabric.plane_y, limit,
                                        fabric.stick_stiffness)


@numba.njit(cache=True)
def total_energy(pos, fabric, P, anchors, limit, out):
    """V [J] (its terms left in out)."""
    energies(pos, fabric, P, anchors, limit, out)
    return out.sum()


@numba.njit(cache=True)
def gradient(pos, fabric, P, anchors, limit, grad):
    """grad = dV/dr (nodes, 2) [N], F_T frozen."""
    grad[:, :] = 0.0
    start = fabric.yarn_start
    for y in range(start.size - 1):
        a, b = start[y], start[y + 1]
        stretch.add_gradient(pos[a:b], fabric.rest_length[a - y:b - y - 1],
                             fabric.stretch_stiffness[a - y:b - y - 1], grad[a:b])
        bending.add_gradient(pos[a:b], fabric.bend_stiffness[a:b], fabric.rest_angle[a:b],
                             grad[a:b])
        grad[fabric.load_node[y], 0] -= P[y]
    contact.add_gradient(pos, fabric.warp_node, fabric.weft_node, fabric.side,
                         fabric.gap_offset, fabric.contact_law, grad)
    if fabric.has_friction:
        friction.add_gradient(pos, anchors, fabric.warp_node, fabric.weft_node, fabric.plane_x,
                              fabric.plane_y, limit, fabric.stick_stiffness, grad)


@numba.njit(cache=True)
def yarn_band(pos, fabric, y, band):
    """band = d2(E_stretch + E_bend)/dr2 of yarn y in its own dofs (`dynfab.banded` layout)."""
    a, b = fabric.yarn_start[y], fabric.yarn_start[y + 1]
    band[:, :] = 0.0
    stretch.add_hessian(pos[a:b], fabric.rest_length[a - y:b - y - 1],
                        fabric.stretch_stiffness[a - y:b - y - 1], band)
    bending.add_hessian(pos[a:b], fabric.bend_stiffness[a:b], fabric.rest_angle[a:b], band)


@numba.njit(cache=True)
def crossing_blocks(pos, fabric, anchors, limit, tangent, huber, secant=False):
    """dR/dg per crossing into tangent (C,) and the Huber block (h_xx, h_xy, h_yy) into
    huber (C, 3) (zeros without friction; `secant`: see `friction.huber_hessian`)."""
    contact.tangents(pos, fabric.warp_node, fabric.weft_node, fabric.side, fabric.gap_offset,
                     fabric.contact_law, tangent)
    huber[:, :] = 0.0
    if fabric.has_friction:
        friction.hessians(pos, anchors, fabric.warp_node, fabric.weft_node, fabric.plane_x,
                          fabric.plane_y, limit, fabric.stick_stiffness, huber, secant)


@numba.njit(cache=True)
def hessian_values(pos, fabric, anchors, limit, values, secant=False):
    """The Hessian's entries (F_T frozen) in `Pattern` order into values; `secant`: the
    sliding crossings' secant stiffness instead (`friction.huber_hessian`)."""
    start = fabric.yarn_start
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
    c_count = fabric.warp_node.size
    tangent, huber = np.zeros(c_count), np.zeros((c_count, 3))
    crossing_blocks(pos, fabric, anchors, limit, tangent, huber, secant)
    for c in range(c_count):
        t = tangent[c]
        values[k:k + 8] = (t, -t, -t, t, huber[c, 0], huber[c, 1], huber[c, 1], huber[c, 2])
        k += 8


class Pattern:
    """Row and column of every Hessian entry `hessian_values` fills, and the free dofs."""

    def __init__(self, fabric):
        rows, cols = [], []
        start = fabric.yarn_start
        for y in range(start.size - 1):
            n = 2 * (start[y + 1] - start[y])
            i, o = np.meshgrid(np.arange(n), np.arange(2 * BANDWIDTH + 1), indexing="ij")
            j = i + o - BANDWIDTH
            keep = (j >= 0) & (j < n)
            rows.append(2 * start[y] + i[keep])
            cols.append(2 * start[y] + j[keep])
        za, zb = 2 * fabric.warp_node + 1, 2 * fabric.weft_node + 1
        xa, yb = 2 * fabric.warp_node, 2 * fabric.weft_node
        rows.append(np.stack([za, za, zb, zb, xa, xa, yb, yb], axis=1).ravel())
        cols.append(np.stack([za, zb, za, zb, xa, yb, xa, yb], axis=1).ravel())
        rows, cols = np.concatenate(rows), np.concatenate(cols)
        self.rows, self.cols = rows, cols
        self.size = rows.size
        self.free = ~fabric.fixed
        index = np.full(fabric.fixed.size, -1)
        index[self.free] = np.arange(self.free.sum())
        self.free_count = int(self.free.sum())
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

    def matrix(self, values) -> scipy.sparse.csc_matrix:
        """The Hessian on the free dofs (CSC), from `hessian_values`' entries."""
        data = np.bincount(self._slot, weights=values[self._keep], minlength=self._slots)
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
    slip coordinates; load: |P| on the end node (MODEL.md 6's rounding rule).
    """
    total = 0.0
    start = fabric.yarn_start
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
    for c in range(fabric.warp_node.size):
        za, zb = pos[fabric.warp_node[c], 1], pos[fabric.weft_node[c], 1]
        g = contact.closure(pos, fabric.warp_node, fabric.weft_node, fabric.side,
                            fabric.gap_offset, c)
        total += contact.force(g, fabric.contact_law) * (abs(za) + abs(zb) + abs(g))
        total += limit[c] * (abs(pos[fabric.warp_node[c], 0]) + abs(pos[fabric.weft_node[c], 0]))
    return total
