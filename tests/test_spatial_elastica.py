"""A straight yarn bent in the fabric's plane is Euler's elastica with EI_lateral
(docs/model.md section 11.2; the issue's reduction).

The plain rod of tests/test_certificate.py (L = 0.1 m, EA / Pcr = 1.4e6) laid along x in the
spatial model: its lateral bending spring (11.1's psi term) carries the rod's EI as
EI_lateral, its out-of-plane bending is 100 times stiffer and every z is held, so it can only
buckle in the plane. Pinned at both ends (x, y held at node 0, y at the end node, whose x is
moved in by Delta), it is solved by the static solver's sparse Newton on the spatial terms
from a kicked start (a half sine in y, 0.2 L high). The end reaction over pi^2 EI_lateral / L^2
must follow the pinned elastica's P / Pcr (Delta / L) with the discrete chain's error,
pi^2 / (12 N^2) to leading order: second order in the segment length, measured on N = 16,
32, 64 (order 2 +- 0.1, as the planar rod's test).
"""

from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np

from dynfab.model.fabric import spatial
from dynfab.model.builders import build_model
from dynfab.solvers.newton_sparse import SparseNewton
from test_certificate import ROD_EI, ROD_L, ROD_PCR, SHORTENINGS, elastica_load, rod_scene

STIFFER_OUT_OF_PLANE = 100.0
"""EI / EI_lateral of the rod here: the out-of-plane bending plays no part (z is held)."""


def in_plane_rod(make_scene, segments):
    """(scene, spatial structure) of the rod along x, bending laterally with EI_lateral."""
    scene = rod_scene(make_scene, segments)
    planar = build_model(scene).structure
    n = planar.rest_position.shape[0]
    assert planar.tie_a.size == 0 and planar.chain_start.size == 2
    rest = np.column_stack([planar.rest_position[:, 0], np.zeros(n), np.zeros(n)])
    fixed = np.zeros((n, 3), bool)
    fixed[:, 2] = True          # in the plane only
    fixed[0, :2] = True         # pinned
    fixed[-1, :] = True         # pinned, its x prescribed
    structure = planar._replace(
        rest_position=rest, fixed=fixed.ravel(), dof_tie=np.full(3 * n, -1, np.int64),
        bend_stiffness=STIFFER_OUT_OF_PLANE * planar.bend_stiffness,
        lateral_bend_stiffness=planar.bend_stiffness.copy(), lateral_rest_angle=np.zeros(n),
        tie_stencil=np.zeros((0, 6), np.int64), tie_rotation_law=np.zeros((0, 3)),
        lateral_stencil=np.zeros((0, 4), np.int64), lateral_law=np.zeros((0, 3)))
    return scene, structure


def end_load(make_scene, segments, shortening):
    """P / Pcr of the rod pushed in by Delta = shortening L, and its midpoint's deflection."""
    scene, structure = in_plane_rod(make_scene, segments)
    backend = SparseNewton(SimpleNamespace(structure=structure, scene=scene))
    x = structure.rest_position[:, 0]
    pos = structure.rest_position.copy()
    pos[:, 0] *= 1.0 - shortening
    pos[:, 1] = 0.2 * ROD_L * np.sin(math.pi * x / ROD_L)
    pos[-1, 1] = 0.0
    no_ties = np.zeros((0, 3))
    backend.equilibrium(pos, np.zeros(1), no_ties)
    grad = np.zeros_like(pos)
    spatial.gradient(pos, structure, np.zeros(1), no_ties, np.zeros(0), grad)
    return -grad[-1, 0] / ROD_PCR, pos[segments // 2, 1]  # the rod pushes the end out


def test_a_rod_bent_in_the_plane_converges_to_the_elastica_at_second_order(make_scene):
    assert ROD_PCR == math.pi ** 2 * ROD_EI / ROD_L ** 2
    errors = []
    for segments in (16, 32, 64):
        row = []
        for shortening in SHORTENINGS:
            load, deflection = end_load(make_scene, segments, shortening)
            assert abs(deflection) > 0.1 * ROD_L  # buckled in the plane, not straight
            row.append(load - elastica_load(shortening))
        errors.append(row)
    errors = np.array(errors)
    order = np.log2(errors[1] / errors[2])
    assert np.all(np.abs(order - 2) < 0.1), (errors, order)
