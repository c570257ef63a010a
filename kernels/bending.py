"""Bending springs on exact turning angles in a kernel (docs/model.md section 2; paper eqs. 13, 16).

Warp twin of `dynfab.terms.bending`, in its sign convention (grad += dV/dr). E_bend = sum_{i=1}^{N-1} 1/2 (EI / lbar_i)
(phi_i - phi0_i)^2, phi_i = theta(b) - theta(a) = atan2(a x b, a . b), with
a = r_i - r_{i-1}, b = r_{i+1} - r_i, theta(v) = atan2(v_z, v_x):

    dtheta/dv = (-v_z, v_x) / |v|^2,
    d2theta/dv2 = [[2 v_x v_z, v_z^2 - v_x^2], [v_z^2 - v_x^2, -2 v_x v_z]] / |v|^4,

and d phi_i / d(r_{i-1}, r_i, r_{i+1}) = (-g_a, g_a - g_b, g_b) with
g_a = dphi/da = -dtheta(a)/da and g_b = dphi/db = dtheta(b)/db. `stiffness` = EI / lbar_i
(`YarnArrays.bend_stiffness`), `rest_angle` = phi0_i.
"""

import functools
from types import SimpleNamespace

import warp as wp

from dynfab.kernels import banded, yarn_arrays
from dynfab.kernels.precision import VECTORS


@functools.cache
def functions(scalar) -> SimpleNamespace:
    """The bending `wp.func`s for one scalar type."""
    vec = VECTORS[scalar]
    mat = wp.types.matrix((2, 2), scalar)
    YarnArrays = yarn_arrays.struct(scalar)
    band_ops = banded.functions(scalar)

    @wp.func
    def turning_angle(a: vec, b: vec) -> scalar:
        """phi [rad] from segment a to segment b: atan2(a x b, a . b)."""
        return wp.atan2(a[0] * b[1] - a[1] * b[0], wp.dot(a, b))

    @wp.func
    def angle_gradient_a(a: vec) -> vec:
        """g_a = dphi/da = -dtheta(a)/da = (a_z, -a_x) / |a|^2."""
        return vec(a[1], -a[0]) / wp.dot(a, a)

    @wp.func
    def angle_gradient_b(b: vec) -> vec:
        """g_b = dphi/db = dtheta(b)/db = (-b_z, b_x) / |b|^2."""
        return vec(-b[1], b[0]) / wp.dot(b, b)

    @wp.func
    def theta_hessian(v: vec) -> mat:
        """d2theta/dv2 (2x2) [1/m^2]."""
        n2 = wp.dot(v, v) * wp.dot(v, v)
        hxx = scalar(2.0) * v[0] * v[1] / n2
        hxz = (v[1] * v[1] - v[0] * v[0]) / n2
        return mat(hxx, hxz, hxz, -hxx)

    @wp.func
    def energy(y: int, pos: wp.array2d(dtype=vec), yarn: YarnArrays,
               anchors: wp.array2d(dtype=scalar), P: scalar,
               contact_force: wp.array2d(dtype=scalar)) -> scalar:
        """E_bend [J] = sum_i 1/2 k_i (phi_i - phi0_i)^2."""
        stiffness = yarn.bend_stiffness
        rest_angle = yarn.rest_angle
        total = scalar(0.0)
        for i in range(1, pos.shape[1] - 1):
            d = turning_angle(pos[y, i] - pos[y, i - 1], pos[y, i + 1] - pos[y, i]) - rest_angle[y, i]
            total += scalar(0.5) * stiffness[y, i] * d * d
        return total

    @wp.func(inline=True)
    def add_gradient(y: int, pos: wp.array2d(dtype=vec), yarn: YarnArrays,
                     anchors: wp.array2d(dtype=scalar), P: scalar,
                     contact_force: wp.array2d(dtype=scalar), contact_tangent: wp.array2d(dtype=scalar),
                     friction_limit: wp.array2d(dtype=scalar), grad: wp.array2d(dtype=vec)):
        """grad += k (phi - phi0) dphi/dr [N]."""
        stiffness = yarn.bend_stiffness
        rest_angle = yarn.rest_angle
        for i in range(1, pos.shape[1] - 1):
            a = pos[y, i] - pos[y, i - 1]
            b = pos[y, i + 1] - pos[y, i]
            moment = stiffness[y, i] * (turning_angle(a, b) - rest_angle[y, i])
            ga = moment * angle_gradient_a(a)
            gb = moment * angle_gradient_b(b)
            grad[y, i - 1] = grad[y, i - 1] - ga
            grad[y, i] = grad[y, i] + ga - gb
            grad[y, i + 1] = grad[y, i + 1] + gb

    @wp.func
    def selector_a(p: int) -> scalar:
        """da/dr_{i-1+p}: -1, 1, 0."""
        value = scalar(0.0)
        if p == 0:
            value = scalar(-1.0)
        elif p == 1:
            value = scalar(1.0)
        return value

    @wp.func
    def selector_b(p: int) -> scalar:
        """db/dr_{i-1+p}: 0, -1, 1."""
        value = scalar(1.0)
        if p == 0:
            value = scalar(0.0)
        elif p == 1:
            value = scalar(-1.0)
        return value

    @wp.func
    def node_gradient(p: int, ga: vec, gb: vec) -> vec:
        """dphi/dr of node i-1+p: -g_a, g_a - g_b, g_b."""
        return selector_a(p) * ga + selector_b(p) * gb

    @wp.func(inline=True)
    def add_hessian(y: int, pos: wp.array2d(dtype=vec), yarn: YarnArrays,
                    anchors: wp.array2d(dtype=scalar), contact_tangent: wp.array2d(dtype=scalar),
                    friction_limit: wp.array2d(dtype=scalar), definite: bool, stiffest: bool,
                    band: wp.array3d(dtype=scalar)):
        """band += k dphi dphi^T + k (phi - phi0) d2phi [N/m] over nodes (i-1, i, i+1).

        d2phi = -S_a^T H(a) S_a + S_b^T H(b) S_b with selectors S_a = (-1, 1, 0) and
        S_b = (0, -1, 1), H = d2theta/dv2. With `definite`, the second (moment)
        term, which can be indefinite, is dropped: k dphi dphi^T is positive
        semi-definite (docs/model.md section 5, semi_implicit).
        """
        stiffness = yarn.bend_stiffness
        rest_angle = yarn.rest_angle
        for i in range(1, pos.shape[1] - 1):
            a = pos[y, i] - pos[y, i - 1]
            b = pos[y, i + 1] - pos[y, i]
            k = stiffness[y, i]
            moment = k * (turning_angle(a, b) - rest_angle[y, i])
            if definite:
                moment = scalar(0.0)
            ga = angle_gradient_a(a)
            gb = angle_gradient_b(b)
            ha = -moment * theta_hessian(a)
            hb = moment * theta_hessian(b)
            for p in range(3):
                gp = node_gradient(p, ga, gb)
                for q in range(3):
                    gq = node_gradient(q, ga, gb)
                    block = k * wp.outer(gp, gq) + selector_a(p) * selector_a(q) * ha \
                        + selector_b(p) * selector_b(q) * hb
                    band_ops.add_block(band, y, i - 1 + p, i - 1 + q, block)

    return SimpleNamespace(energy=energy, add_gradient=add_gradient, add_hessian=add_hessian,
                           theta_hessian=theta_hessian)
