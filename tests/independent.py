"""Independent helpers shared by the verification tests (plain functions, not fixtures).

Scene building through the TOML parser (as a user's scene file), fabric scenes and
their models (a held family, no core spring), a load-path driver, the dense matrix of a
banded one (`dynfab.linalg.banded.to_dense`, checked against `band_matvec` in
test_certificate.py), and the tests' one reference of the contact and friction laws,
written from docs/model.md independently of dynfab.model.terms: the series contact law of
section 3 solved with scipy (brentq on g(R), arc lengths from ellipe) and Gralen's law of
section 4. Import with `from independent import ...` (pytest puts tests/ on sys.path).
"""

from __future__ import annotations

import math
import re
from dataclasses import replace
from pathlib import Path

import numpy as np
from scipy.optimize import brentq
from scipy.special import ellipe

from dynfab.model import assembly
from dynfab.linalg.banded import to_dense as dense  # noqa: F401 (the tests' name for it)
from dynfab.model.fabric.model import FabricModel
from dynfab.model.yarn import initial_state
from dynfab.model.builders import build_model
from dynfab.scene import Scene, parse_scene_text, validate_scene
from dynfab.model.structure import chain_of_node, dim
from dynfab.solvers.static import StaticSolver
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


PULLOUT = Path(__file__).resolve().parents[1] / "runs" / "fabric_pullout.toml"
PULLOUT_RISE = 22
"""Steps of runs/fabric_pullout.toml's first two stages (the wefts tensioned, then the warp
pulled 0.2 mm through its slip front to the peak), within half a segment of every crossing."""


def pullout_text(motion: str = "fixed", steps: int = PULLOUT_RISE) -> str:
    """runs/fabric_pullout.toml with crossing.motion = `motion` and its load path cut to its
    first `steps` steps (default: to the peak, where crossings that are fixed pairs of nodes
    hold: the scene as it was before crossings could slide)."""
    text = PULLOUT.read_text().replace('motion = "sliding"', f'motion = "{motion}"')
    for name in ("values", "weft_values"):
        match = re.search(rf"^{name} = \[(.*)\]$", text, flags=re.M)
        kept = ", ".join(match.group(1).split(", ")[:steps])
        text = text.replace(match.group(0), f"{name} = [{kept}]")
    return text


def pullout_scene(motion: str = "fixed", steps: int = PULLOUT_RISE) -> Scene:
    """`pullout_text` as a scene."""
    return parse_scene_text(pullout_text(motion, steps))


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
    (`dynfab.solvers.certificate.StepStability`: error_estimate = residual x est ||H^-1||_inf), H
    the Hessian on the free dofs with F_T frozen at the step's anchors and limits. Hager-Higham's
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


def closure_of_force(R, law):
    """g(R) = R/k + sum_m C_m (1 - exp(-a_m R)) [m], law = (k, C_wa, a_wa, C_we, a_we)
    (docs/model.md section 3; k the weft's k_we, or k_we and a core spring in series)."""
    k, c_wa, a_wa, c_we, a_we = law
    return R / k - c_wa * math.expm1(-a_wa * R) - c_we * math.expm1(-a_we * R)


def contact_force(g, law):
    """R(g) [N] of a crossing closed by g [m]: the root of closure_of_force(R, law) = g by
    brentq (0 for g <= 0), to rtol 4 eps: exact to ~1e-15 relative. The root lies in
    [0, k g] since g(R) >= R / k."""
    if g <= 0:
        return 0.0
    return brentq(lambda R: closure_of_force(R, law) - g, 0.0, law[0] * g, xtol=1e-300,
                  rtol=4 * EPS, maxiter=500)


def contact_energy(R, law):
    """E(R) = R^2/(2 k) + sum_m (C_m/a_m)(1 - exp(-a_m R)(1 + a_m R)) [J] of a crossing carrying
    R [N], the integral of R dg along the series law (docs/model.md section 3)."""
    k, c_wa, a_wa, c_we, a_we = law
    return R * R / (2 * k) + sum(c / a * (1 - math.exp(-a * R) * (1 + a * R))
                                 for c, a in ((c_wa, a_wa), (c_we, a_we)))


def gralen(R, onset, alpha=PAPER_FRICTION["alpha"],
           constant=PAPER_FRICTION["beta"] * PAPER_FRICTION["contact_length"]
           * PAPER_FRICTION["fiber_radius"]):
    """F_T = alpha R + beta ell r_f (1 - exp(-R / R_0)) [N] where R > 0, else 0, with
    `constant` = beta ell r_f and `onset` = R_0 (0: the literal law, the jump at R = 0+)
    (docs/model.md section 4, paper eq. 20); the paper's alpha and beta ell r_f by default."""
    R = np.asarray(R, dtype=float)
    rise = -np.expm1(-R / onset) if onset > 0 else np.ones_like(R)
    return np.where(R > 0, alpha * R + constant * rise, 0.0)


def scene_gralen(scene, R):
    """`gralen` with the scene's [friction] constants."""
    f = scene.friction
    return gralen(R, f.onset_force, f.alpha, f.beta * f.contact_length * f.fiber_radius)


def contact_forces(scene, positions, phase=1.0):
    """R_j [N] of every crossing from node positions (N+1, 2), by `contact_force`.

    g_j = c_j - s_j z_{n_j}, s_j = s_k (-1)^(j+1), c_j = s_j z0_{n_j} (as woven) or
    A_wa + A_we (prestressed).
    """
    geo = scene.geometry
    law = series_law(scene)
    j = np.arange(1, geo.crossings + 1)
    nodes = (2 * j - 1) * geo.segments // (2 * geo.crossings)
    sides = phase * (-1.0) ** (j + 1)
    x0 = nodes * geo.length / geo.segments
    z0 = phase * geo.amplitude * np.sin(geo.crossings * math.pi * x0 / geo.length)
    offset = (np.full(j.size, geo.amplitude + scene.weft.amplitude)
              if geo.reference == "prestressed" else sides * z0)
    return np.array([contact_force(g, law) for g in offset - sides * positions[nodes, 1]])


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


# --------------------------------------------------------------------------
# The one-yarn model's energy, term by term (docs/model.md sections 1-4).


def turning_angles(r):
    """phi_i = atan2(e_{i-1} x e_i, e_{i-1} . e_i) at the interior nodes of r (N+1, 2)."""
    e = np.diff(r, axis=0)
    a, b = e[:-1], e[1:]
    return np.arctan2(a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0], (a * b).sum(axis=1))


def yarn_energies(scene, r, phase, P, anchors, friction_limit):
    """Each term of V = E_stretch + E_bend + sum E_contact + sum H - W_load - W_gravity [J] of
    one yarn of phase s_k at positions r (N+1, 2), written from docs/model.md sections 1-4
    with numpy: as-woven r0_i = (i L/N, s_k A sin(N_we pi x_i / L)); springs EA/l0 and
    EI/lbar (lbar the Voronoi lengths, the ends' halves); crossings n_j = (2j - 1) N / (2 N_we)
    closed by g_j = s_j (z0 - z) (as woven) or A_wa + A_we - s_j z (prestressed), their
    energy `contact_energy` at `contact_force`; the stick springs k_t = EA / (L/N) (or the
    scene's) as the Huber energy at the frozen limits `friction_limit`; gravity
    rho_l lbar g (z - z0); the end force P times the end's x displacement.
    """
    geo, warp = scene.geometry, scene.warp
    N, L = geo.segments, geo.length
    x = np.arange(N + 1) * L / N
    r0 = np.stack([x, phase * geo.amplitude * np.sin(geo.crossings * math.pi * x / L)], axis=1)
    l0 = np.hypot(*np.diff(r0, axis=0).T)
    lbar = np.concatenate([[l0[0] / 2], (l0[:-1] + l0[1:]) / 2, [l0[-1] / 2]])
    phi0 = turning_angles(r0) if geo.reference == "as_woven" else np.zeros(N - 1)
    j = np.arange(1, geo.crossings + 1)
    nodes, sides = (2 * j - 1) * N // (2 * geo.crossings), phase * (-1.0) ** (j + 1)
    if geo.reference == "as_woven":
        g = sides * (r0[nodes, 1] - r[nodes, 1])
    else:
        g = geo.amplitude + scene.weft.amplitude - sides * r[nodes, 1]
    law = series_law(scene)
    energies = {
        "stretch": np.sum(0.5 * warp.EA / l0 * (np.hypot(*np.diff(r, axis=0).T) - l0) ** 2),
        "bending": np.sum(0.5 * warp.EI / lbar[1:-1] * (turning_angles(r) - phi0) ** 2),
        "contact": sum(contact_energy(contact_force(gj, law), law) for gj in g),
        "load": -P * (r[-1, 0] - r0[-1, 0]),
    }
    if scene.friction is not None:
        k_t = scene.friction.stick_stiffness or warp.EA / (L / N)
        slip = np.abs(r[nodes, 0] - anchors)
        F = friction_limit
        energies["friction"] = np.sum(np.where(k_t * slip <= F, 0.5 * k_t * slip ** 2,
                                               F * slip - F ** 2 / (2 * k_t)))
    if scene.gravity is not None:
        energies["gravity"] = np.sum(warp.linear_density * lbar * scene.gravity.g
                                     * (r[:, 1] - r0[:, 1]))
    return energies
