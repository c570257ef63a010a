"""Bending springs on exact turning angles (docs/model.md section 2; paper eqs. 13, 16).

E_bend = sum_{i=1}^{N-1} 1/2 (EI / lbar_i) (phi_i - phi0_i)^2, phi_i the signed
turning angle from segment a = r_i - r_{i-1} to b = r_{i+1} - r_i,
phi_i = theta(b) - theta(a) with theta(v) = atan2(v_z, v_x), so

    dtheta/dv = (-v_z, v_x) / |v|^2,
    d2theta/dv2 = [[2 v_x v_z, v_z^2 - v_x^2], [v_z^2 - v_x^2, -2 v_x v_z]] / |v|^4.

The node pair (i-1, i+1) is 4 dofs apart at most (5 = BANDWIDTH), so every
entry of the 6 x 6 local Hessian lies in the band.
"""

import numba
import numpy as np

from dynfab.linalg.banded import BANDWIDTH


@numba.njit(cache=True)
def turning_angle(pos, i):
    """phi_i [rad] = atan2(a x b, a . b)."""
    ax, az = pos[i, 0] - pos[i - 1, 0], pos[i, 1] - pos[i - 1, 1]
    bx, bz = pos[i + 1, 0] - pos[i, 0], pos[i + 1, 1] - pos[i, 1]
    return np.arctan2(ax * bz - az * bx, ax * bx + az * bz)


@numba.njit(cache=True)
def energy(pos, stiffness, rest_angle):
    """E_bend [J]; `stiffness` = EI / lbar_i per node [N m] (0 at the end nodes)."""
    total = 0.0
    for i in range(1, pos.shape[0] - 1):
        d = turning_angle(pos, i) - rest_angle[i]
        total += 0.5 * stiffness[i] * d * d
    return total


@numba.njit(cache=True)
def _angle_gradient(pos, i, out):
    """dphi_i / d(r_{i-1}, r_i, r_{i+1}) into out (6,)."""
    ax, az = pos[i, 0] - pos[i - 1, 0], pos[i, 1] - pos[i - 1, 1]
    bx, bz = pos[i + 1, 0] - pos[i, 0], pos[i + 1, 1] - pos[i, 1]
    na, nb = ax * ax + az * az, bx * bx + bz * bz
    gax, gaz = az / na, -ax / na      # dphi/da = -dtheta(a)/da
    gbx, gbz = -bz / nb, bx / nb      # dphi/db = dtheta(b)/db
    out[0], out[1] = -gax, -gaz
    out[2], out[3] = gax - gbx, gaz - gbz
    out[4], out[5] = gbx, gbz


@numba.njit(cache=True)
def add_gradient(pos, stiffness, rest_angle, grad):
    """grad += k (phi - phi0) dphi/dr."""
    g = np.empty(6)
    for i in range(1, pos.shape[0] - 1):
        moment = stiffness[i] * (turning_angle(pos, i) - rest_angle[i])
        _angle_gradient(pos, i, g)
        for m in range(3):
            grad[i - 1 + m, 0] += moment * g[2 * m]
            grad[i - 1 + m, 1] += moment * g[2 * m + 1]


@numba.njit(cache=True)
def _put_block(out, p, q, sign, hxx, hxz):
    """out[2p:2p+2, 2q:2q+2] = sign x [[hxx, hxz], [hxz, -hxx]] (a d2theta/dv2 block)."""
    out[2 * p, 2 * q] = sign * hxx
    out[2 * p, 2 * q + 1] = sign * hxz
    out[2 * p + 1, 2 * q] = sign * hxz
    out[2 * p + 1, 2 * q + 1] = -sign * hxx


@numba.njit(cache=True)
def _angle_hessian(pos, i, out):
    """d2phi_i / dr2 (6, 6) over (r_{i-1}, r_i, r_{i+1}).

    phi = theta(b) - theta(a), a = r_i - r_{i-1}, b = r_{i+1} - r_i, so with the
    2x2 blocks Ha = d2theta/da2, Hb = d2theta/db2 the node blocks are
    [[-Ha, Ha, 0], [Ha, Hb - Ha, -Hb], [0, -Hb, Hb]].
    """
    ax, az = pos[i, 0] - pos[i - 1, 0], pos[i, 1] - pos[i - 1, 1]
    bx, bz = pos[i + 1, 0] - pos[i, 0], pos[i + 1, 1] - pos[i, 1]
    na2, nb2 = (ax * ax + az * az) ** 2, (bx * bx + bz * bz) ** 2
    axx, axz = 2.0 * ax * az / na2, (az * az - ax * ax) / na2
    bxx, bxz = 2.0 * bx * bz / nb2, (bz * bz - bx * bx) / nb2
    _put_block(out, 0, 0, -1.0, axx, axz)
    _put_block(out, 0, 1, 1.0, axx, axz)
    _put_block(out, 1, 0, 1.0, axx, axz)
    _put_block(out, 1, 1, 1.0, bxx - axx, bxz - axz)
    _put_block(out, 1, 2, -1.0, bxx, bxz)
    _put_block(out, 2, 1, -1.0, bxx, bxz)
    _put_block(out, 2, 2, 1.0, bxx, bxz)
    _put_block(out, 0, 2, 0.0, 0.0, 0.0)
    _put_block(out, 2, 0, 0.0, 0.0, 0.0)


@numba.njit(cache=True)
def add_hessian(pos, stiffness, rest_angle, band):
    """band += k dphi dphi^T + k (phi - phi0) d2phi."""
    g = np.empty(6)
    h = np.empty((6, 6))
    for i in range(1, pos.shape[0] - 1):
        k = stiffness[i]
        moment = k * (turning_angle(pos, i) - rest_angle[i])
        _angle_gradient(pos, i, g)
        _angle_hessian(pos, i, h)
        base = 2 * (i - 1)
        for p in range(6):
            for q in range(max(0, p - BANDWIDTH), 6):
                band[base + p, q - p + BANDWIDTH] += k * g[p] * g[q] + moment * h[p, q]


# The term's entry points (`dynfab.model.terms`).


@numba.njit(cache=True)
def yarn_energy(pos, yarn, frozen):
    """E_bend [J] of a `dynfab.model.yarn.Yarn`."""
    return energy(pos, yarn.bend_stiffness, yarn.rest_angle)


@numba.njit(cache=True)
def add_yarn_gradient(pos, yarn, frozen, grad):
    """grad += dE_bend/dr."""
    add_gradient(pos, yarn.bend_stiffness, yarn.rest_angle, grad)


@numba.njit(cache=True)
def add_yarn_hessian(pos, yarn, frozen, band):
    """band += d2E_bend/dr2."""
    add_hessian(pos, yarn.bend_stiffness, yarn.rest_angle, band)
