"""Independent helpers shared by the verification tests (plain functions, not fixtures).

Scene building through the TOML parser (as a user's scene file), fabric scenes and
their models (a held family, no core spring), a load-path driver, the dense matrix of a
banded one (`dynfab.banded.to_dense`, checked against `band_matvec` in
test_certificate.py), and the series contact law of
docs/model.md section 3 solved here with scipy (brentq on g(R), arc lengths from ellipe),
independently of dynfab.terms.contact. Import with `from independent import ...`
(pytest puts tests/ on sys.path).
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
from scipy.optimize import brentq
from scipy.special import ellipe

from dynfab import assembly
from dynfab.banded import to_dense as dense  # noqa: F401 (the tests' name for it)
from dynfab.fabric.from_scene import FabricModel
from dynfab.model import build_model, initial_state
from dynfab.scene import Scene, parse_scene_text, validate_scene
from dynfab.structure import chain_of_node, dim
from dynfab.static import StaticSolver
from toml_writer import toml_text as scene_toml  # TOML of {table: {key: value}}

EPS = np.finfo(float).eps

PAPER_WARP = {"EA": 13.72, "EI": 1.47e-7, "kawabata_C": 0.2e-3, "kawabata_K": 0.2}
PAPER_WEFT = {"EI": 1.47e-7, "amplitude": 0.5e-3, "kawabata_C": 0.2e-3, "kawabata_K": 0.2}
PAPER_FRICTION = {"alpha": 0.2, "beta": 1e3, "contact_length": 2e-3, "fiber_radius": 1e-3}


# --------------------------------------------------------------------------
# Scenes (docs/model.md section 1).


def make_scene(sweep=None, **tables) -> Scene:
    """A Scene from {table: {key: value}} (and an optional [sweep]), through the TOML parser.

    Sweep keys are dotted parameter names ("warp.kawabata_K"), written quoted.
    """
    return parse_scene_text(scene_toml({**tables, "sweep": sweep} if sweep else tables))


def scene_with(scene: Scene, **tables) -> Scene:
    """A copy of `scene` with keys of its tables changed, {table: {key: value}}, validated once
    as a whole (several keys that only together make a valid scene, a patch resized, say)."""
    changes = {name: replace(getattr(scene, name), **keys) for name, keys in tables.items()}
    return validate_scene(replace(scene, **changes))


# --------------------------------------------------------------------------
# Fabric scenes and their models (docs/model.md section 10).

FAMILY_GEOMETRY = ("length", "segments", "amplitude")
"""The keys of a family's dict that the warps take from [geometry]."""


def fabric_scene(warp: dict, weft: dict, warps: int, wefts: int, geometry=None,
                 **tables) -> Scene:
    """A fabric scene (geometry.model = "fabric") through the TOML parser: `warp` and `weft`
    each family's {length, segments, amplitude, EA, EI, kawabata_C, kawabata_K[,
    linear_density]}, `warps` x `wefts` yarns; `geometry` more [geometry] keys (boundary,
    planes); `tables` the other tables ([load] at least; [friction], [contact], [gravity],
    [pullout], [static], ...)."""
    return make_scene(
        geometry={"model": "fabric", **{key: warp[key] for key in FAMILY_GEOMETRY},
                  "crossings": wefts, **(geometry or {})},
        warp={key: value for key, value in warp.items() if key not in FAMILY_GEOMETRY},
        weft={**weft, "count": warps}, **tables)


def held_family(scene: Scene, family: str) -> FabricModel:
    """The fabric model of `scene` with every dof of one family ("warp" or "weft") held at its
    as-woven position besides the scene's own boundary (docs/model.md section 10: with the
    wefts held, each warp is the one-yarn model with a rigid weft spring)."""
    structure = FabricModel.from_scene(scene).structure
    chosen = structure.chain_family[chain_of_node(structure)] == {"warp": 0, "weft": 1}[family]
    held = np.repeat(chosen, dim(structure))
    return FabricModel.from_scene(scene, structure._replace(fixed=structure.fixed | held))


def without_core_spring(scene: Scene) -> FabricModel:
    """The fabric model of `scene` with k_c = inf at every crossing: Kawabata's law alone, a
    hard wall at g = C_wa + C_we (docs/model.md section 10). A scene takes finite numbers
    only (contact.core_stiffness), so the law is set on the structure."""
    structure = FabricModel.from_scene(scene).structure
    law = structure.tie_contact_law.copy()
    law[:, 0] = np.inf
    return FabricModel.from_scene(scene, structure._replace(tie_contact_law=law))


def record_inverse_norm(record) -> float:
    """est ||H^-1||_inf [m/N] of a step's certificate: its error_estimate over its residual
    (`dynfab.certificate.StepStability`: error_estimate = residual x est ||H^-1||_inf), H the
    Hessian on the free dofs with F_T frozen at the step's anchors and limits. Hager-Higham's
    estimate, a lower bound of the norm, in practice within a factor 3: on the fabric patches
    of tests/test_fabric_certificate.py the dense inverse's norm to 1e-8."""
    residual = float(np.ravel(record["residual"])[0])
    assert residual > 0, "a residual of 0 leaves the norm out of the record"
    return float(np.ravel(record["error_estimate"])[0]) / residual


def run(scene):
    """Solve the scene's load path from the as-woven state; (model, records)."""
    model = build_model(scene)
    state, solver, records = initial_state(model), StaticSolver(model), []
    for value in model.load_values:
        state, record = solver.step(state, value)
        records.append(record)
    return model, records


# --------------------------------------------------------------------------
# The series contact law, solved independently (docs/model.md sections 3, 4).


def series_law(scene):
    """(k_we, C_wa, a_wa, C_we, a_we) from the scene's parameters (docs/model.md section 3, paper
    eqs. 4, 6-8).

    Lc of the half-wave z = A sin(pi x / p) is (2 p / pi) E(-(A pi / p)^2) with E
    the complete elliptic integral of the second kind (scipy's parameter m).
    """
    geo, weft = scene.geometry, scene.weft
    pcr = math.pi ** 2 * weft.EI / weft.length ** 2
    lp = weft.length / weft.count
    k_we = (math.pi ** 4 / 2) * weft.EI / lp ** 3 * (1 + (weft.tension / pcr) / weft.count ** 2)

    def arc(p, a):
        return 2 * p / math.pi * ellipe(-(a * math.pi / p) ** 2)

    lc_wa = arc(geo.length / geo.crossings, geo.amplitude)
    lc_we = arc(weft.length / weft.count, weft.amplitude)
    return (k_we, scene.warp.kawabata_C, scene.warp.kawabata_K / lc_wa,
            weft.kawabata_C, weft.kawabata_K / lc_we)


def contact_forces(scene, positions, phase=1.0):
    """R_j [N] of every crossing from node positions (N+1, 2), solved here with brentq.

    g_j = c_j - s_j z_{n_j}, s_j = s_k (-1)^(j+1), c_j = s_j z0_{n_j} (as woven) or
    A_wa + A_we (prestressed); R solves R/k + sum_m C_m (1 - exp(-a_m R)) = g for g > 0.
    brentq to rtol 4.5 eps: R is then exact to ~1e-15 relative.
    """
    geo = scene.geometry
    k, cwa, awa, cwe, awe = series_law(scene)
    j = np.arange(1, geo.crossings + 1)
    nodes = (2 * j - 1) * geo.segments // (2 * geo.crossings)
    sides = phase * (-1.0) ** (j + 1)
    x0 = nodes * geo.length / geo.segments
    z0 = phase * geo.amplitude * np.sin(geo.crossings * math.pi * x0 / geo.length)
    offset = (np.full(j.size, geo.amplitude + scene.weft.amplitude)
              if geo.reference == "prestressed" else sides * z0)
    forces = np.zeros(j.size)
    for i, g in enumerate(offset - sides * positions[nodes, 1]):
        if g > 0:
            law = lambda R, g=g: R / k - cwa * math.expm1(-awa * R) - cwe * math.expm1(-awe * R) - g
            forces[i] = brentq(law, 0.0, k * g, xtol=1e-300, rtol=4.5 * EPS, maxiter=500)
    return forces


def pull(yarn, positions):
    """Force in x that the yarn, contacts and load exert on each crossing node [N], friction excluded.

    -dV/dx_{n_j} with V the model's energy without the friction term (F_T = 0
    makes the Huber term's derivative vanish). At equilibrium pull + friction = 0
    up to the Newton residual.
    """
    c = yarn.crossing_node.size
    grad = np.zeros_like(positions)
    assembly.gradient(positions, yarn, 0.0, np.zeros(c), np.zeros(c), grad)
    return -grad[yarn.crossing_node, 0]


# --------------------------------------------------------------------------
# Finite differences (central), for the gradient and Hessian checks of every term.


def fd_gradient(energy, r, h):
    """Central differences of energy(r) in every coordinate, steps as rounded."""
    out = np.zeros_like(r)
    for idx in np.ndindex(r.shape):
        plus, minus = r.copy(), r.copy()
        plus[idx] += h
        minus[idx] -= h
        out[idx] = (energy(plus) - energy(minus)) / (plus[idx] - minus[idx])
    return out


def fd_jacobian(gradient, r, h):
    """J[:, k] = central difference of gradient(r).ravel() in coordinate k."""
    n = r.size
    out = np.zeros((n, n))
    for k in range(n):
        plus, minus = r.copy().ravel(), r.copy().ravel()
        plus[k] += h
        minus[k] -= h
        out[:, k] = (gradient(plus.reshape(r.shape)) - gradient(minus.reshape(r.shape))).ravel() \
            / (plus[k] - minus[k])
    return out
