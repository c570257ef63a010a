"""Gutowski's lateral compaction of neighbouring yarns (docs/model.md 11.5, (11.5)-(11.6)).

Checked against the law as Gutowski wrote it (Gutowski et al., J. Rheol. 31 (1987): the
transverse pressure of an aligned fibre bundle sigma = A_s (sqrt(V / V0) - 1) /
(sqrt(V_a / V) - 1)^4, A_s = 3 pi E_f / beta^4), written here from the paper's formula and
not from the code's closed form:

- two yarns pressed sideways to a centreline distance d (< w): the element's force is
  sigma(V0 w / d) t l, the pressure over the side face of a yarn of thickness t along the
  length l that the contact stands for; past s_core the core's spring takes over, the energy
  continuous to its second derivative;
- a row of N parallel yarns, the first held and the last pushed towards it, its laws
  alternating between two families: the static solver's equilibrium carries one force F
  through every contact, and each contact's width is the one at which its law carries F
  (the width state in closed form: the inverse of Gutowski's law, by bisection here), to
  the solver's tolerance over the contact's stiffness;
- the builder's law constants from a scene's keys, and the refusals of bad keys.
"""

from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np
import pytest

from dynfab.model.builders.specimen import specimen_structure
from dynfab.errors import UserError
from dynfab.model.fabric import spatial
from dynfab.solvers.newton_sparse import SparseNewton
from dynfab.scene import parse_scene_text, with_key
from dynfab.model.structure import Structure
from dynfab.model.terms import spatial as element
from dynfab.model.terms.contact import NATURAL
from test_shear_specimens import FRAME, scene_text

GLASS = dict(E=72e9, beta=350.0, V0=0.64, Va=0.785)
"""A glass roving (the Cao scenes' estimates, runs/cao2008_frame.toml)."""
WIDTH, THICKNESS, LENGTH = 4.2e-3, 0.6e-3, 5.18e-3
"""w, t [m] and the contact's length l [m]."""


def gutowski(V, E, beta, V0, Va):
    """Gutowski's transverse pressure [Pa] of an aligned fibre bundle at fibre fraction V."""
    return 3 * math.pi * E / beta ** 4 * (math.sqrt(V / V0) - 1) / (math.sqrt(Va / V) - 1) ** 4


CORE = 1e5
"""The yarns' core stiffness [N/m] (`lateral_stiffness`)."""


def law_constants(E, beta, V0, Va, width=WIDTH):
    """(A [N], s_a [m], s_core [m]) as docs/model.md (11.6) defines them, s_core where the
    law's stiffness reaches CORE (bisection)."""
    A = 3 * math.pi * E / beta ** 4 * THICKNESS * LENGTH
    packed = V0 * width / Va
    low, high = packed, width
    for _ in range(200):
        mid = 0.5 * (low + high)
        stiff = element.compaction_law(mid, width, CORE, A, packed, packed)[2] > CORE
        low, high = (mid, high) if stiff else (low, mid)
    return A, packed, high


def pair(distance):
    """X (4, 3) = (A_prev, A_next, A, B): yarn A along x, B at y = distance."""
    return np.ascontiguousarray([[-1e-3, 0, 0], [1e-3, 0, 0], [0, 0, 0], [0, distance, 0]],
                                dtype=float)


@pytest.mark.parametrize("distance", [4.15e-3, 4.0e-3, 3.8e-3, 3.7e-3])  # above s_core
def test_two_yarns_pressed_sideways_carry_gutowskis_pressure(distance):
    law = law_constants(**GLASS)
    g, H = np.empty(12), np.empty((12, 12))
    element.lateral_derivatives(pair(distance), 1.0, WIDTH, CORE, g, H, NATURAL, *law)
    force_on_B = -g[10]  # -dE/dy_B: pushes B away from A
    expected = gutowski(GLASS["V0"] * WIDTH / distance, **GLASS) * THICKNESS * LENGTH
    assert force_on_B == pytest.approx(expected, rel=1e-12)


def test_apart_the_yarns_carry_nothing_and_the_law_starts_without_a_jump():
    law = law_constants(**GLASS)
    assert element.lateral_energy(pair(1.01 * WIDTH), 1.0, WIDTH, CORE, NATURAL, *law) == 0.0
    e, e1, _ = element.compaction_law(WIDTH, WIDTH, CORE, *law)
    assert e == 0.0 and e1 == 0.0


def test_past_s_core_the_core_takes_over_continuously():
    # s_core where the law's stiffness is the core's: energy, force and stiffness continuous
    A, packed, core_from = law_constants(**GLASS)
    assert packed < core_from < WIDTH
    below = element.compaction_law(core_from * (1 - 1e-9), WIDTH, CORE, A, packed, core_from)
    above = element.compaction_law(core_from * (1 + 1e-9), WIDTH, CORE, A, packed, core_from)
    for lo, hi in zip(below, above):
        assert lo == pytest.approx(hi, rel=1e-6)
    assert element.compaction_law(0.9 * packed, WIDTH, CORE, A, packed, core_from)[2] == CORE


# --------------------------------------------------------------------------
# A row of N yarns through the static solver.

NODES = 3
"""Nodes per yarn; the lateral contacts at its middle node."""


def row_structure(laws, spacing, push):
    """N = len(laws) + 1 straight yarns along x at y = k spacing, contact k between yarns k and
    k + 1 at their middle nodes with law k = (A, s_a, s_core); yarn 0 held, yarn N-1 held at
    y + push, the others free along y only."""
    N = len(laws) + 1
    x = np.linspace(-1e-3, 1e-3, NODES)
    rest = np.array([[xi, k * spacing, 0.0] for k in range(N) for xi in x])
    n = rest.shape[0]
    start = np.arange(N + 1) * NODES
    fixed = np.ones((n, 3), bool)
    fixed[NODES:(N - 1) * NODES, 1] = False
    stencil = [[k * NODES, k * NODES + 2, k * NODES + 1, (k + 1) * NODES + 1]
               for k in range(N - 1)]
    lateral = np.array([[1.0, WIDTH, CORE, float(NATURAL), *law] for law in laws])
    zeros = np.zeros
    structure = Structure(
        rest_position=rest, mass=np.full(n, 1e-6), gravity=zeros(n),
        chain_start=start, chain_family=zeros(N, np.int64), chain_plane=zeros(N),
        rest_length=np.full(N * (NODES - 1), 1e-3), stretch_stiffness=np.full(N * (NODES - 1), 1e3),
        bend_stiffness=zeros(n), rest_angle=zeros(n), wrap_stiffness=zeros(N),
        wrap_rest_angle=zeros(N), load_node=start[1:] - 1, load_factor=zeros(N),
        tie_a=zeros(0, np.int64), tie_b=zeros(0, np.int64), tie_side=zeros(0),
        tie_gap_offset=zeros(0), tie_contact_law=zeros((0, 5)), tie_friction_law=zeros((0, 4)),
        tie_plane=zeros((0, 2)), tie_plane_weight=zeros((0, 2)),
        plane_nodes_a=zeros(0, np.int64), plane_nodes_b=zeros(0, np.int64), has_friction=False,
        fixed=fixed.ravel(), dof_tie=np.full(3 * n, -1, np.int64),
        lateral_bend_stiffness=zeros(n), lateral_rest_angle=zeros(n),
        tie_stencil=zeros((0, 6), np.int64), tie_rotation_law=zeros((0, 3)),
        lateral_stencil=np.array(stencil, np.int64), lateral_law=lateral)
    positions = rest.copy()  # the push shared evenly: every contact starts on its law
    positions[:, 1] += np.repeat(np.arange(N) / (N - 1), NODES) * push
    return structure, positions


def width_at(force, law):
    """The width d < w at which Gutowski's law (`law` = (E, beta, V0, Va)) carries `force`
    over t l [N], by bisection: the closed form's inverse."""
    E, beta, V0, Va = law
    low, high = V0 * WIDTH / Va * (1 + 1e-12), WIDTH
    for _ in range(200):
        mid = 0.5 * (low + high)
        if gutowski(V0 * WIDTH / mid, E, beta, V0, Va) * THICKNESS * LENGTH > force:
            low = mid
        else:
            high = mid
    return 0.5 * (low + high)


def test_a_row_of_yarns_carries_one_force_at_the_widths_its_laws_give():
    # two families alternating (a stiffer glass and a wavier one): the same force through
    # every contact, each at its own width
    families = [GLASS, dict(GLASS, beta=280.0, V0=0.6)]
    laws = [law_constants(**families[k % 2]) for k in range(4)]
    spacing = 5.0e-3
    structure, positions = row_structure(laws, spacing, push=4 * (3.9e-3 - spacing))
    model = SimpleNamespace(structure=structure,
                            scene=parse_scene_text(scene_text(FRAME, [1e-3])))
    solver = SparseNewton(model, tolerance=1e-12)
    info, _ = solver.equilibrium(positions, np.zeros(5), np.zeros((0, 3)))
    assert info.converged and info.residual <= 1e-12
    gaps = np.empty(4)
    spatial.lateral_gaps(positions, structure, gaps)
    widths = WIDTH - gaps
    # the force of contact 0, from its own law at its width; every contact's width is the
    # one its law carries that force at, to the residual over the law's stiffness there
    force = gutowski(families[0]["V0"] * WIDTH / widths[0], **families[0]) * THICKNESS * LENGTH
    for k, width in enumerate(widths):
        law = families[k % 2]
        expected = width_at(force, tuple(law.values()))
        stiffness = element.compaction_law(width, WIDTH, CORE, *laws[k])[2]
        assert abs(width - expected) <= 4 * 1e-12 / stiffness + 1e-15, (k, width, expected)
    assert widths[1] != pytest.approx(widths[0], rel=1e-3)  # the families differ
    assert widths.sum() == pytest.approx(4 * 3.9e-3, rel=1e-12)


# --------------------------------------------------------------------------
# The scene's keys.

COMPACTION_KEYS = dict(fibre_modulus=72e9, fibre_volume_fraction=0.64, packing_limit=0.785,
                       fibre_waviness=350.0)


def compacting_frame(**changed):
    """The 60 mm test frame with both families' compaction keys (`changed` replacing some)."""
    lines = "".join(f"{key} = {value!r}\n" for key, value in
                    {**COMPACTION_KEYS, **changed}.items())
    text = scene_text(FRAME, [1e-3]).replace("[warp]\n", "[warp]\n" + lines)
    return parse_scene_text(text.replace("[weft]\n", "[weft]\n" + lines))


def test_the_builder_takes_the_laws_constants_from_the_yarn():
    scene = compacting_frame()
    law = specimen_structure(scene).lateral_law
    A = 3 * math.pi * 72e9 / 350.0 ** 4 * 2 * scene.warp.amplitude * scene.weft.spacing
    assert np.allclose(law[:, spatial.COMPACTION], A, rtol=1e-14)
    assert np.allclose(law[:, spatial.PACKED], 0.64 * scene.warp.width / 0.785, rtol=1e-14)
    # s_core: the law's stiffness there is the core's (lateral_stiffness) to the bisection
    k = law[0, spatial.LATERAL_K]
    stiffness = element.compaction_law(law[0, spatial.CORE_FROM], scene.warp.width, k,
                                       law[0, spatial.COMPACTION], law[0, spatial.PACKED],
                                       law[0, spatial.PACKED])[2]
    assert stiffness == pytest.approx(k, rel=1e-9)


@pytest.mark.parametrize("key, value, message", [
    ("packing_limit", 0.95, "must be at most 0.9069"),
    ("fibre_volume_fraction", 0.8, "must be below warp.packing_limit"),
])
def test_bad_compaction_keys_are_refused_in_one_line(key, value, message):
    with pytest.raises(UserError, match=message) as info:
        compacting_frame(**{key: value})
    assert "\n" not in str(info.value)


def test_a_family_with_part_of_the_compaction_keys_is_refused():
    scene = parse_scene_text(scene_text(FRAME, [1e-3]))
    with pytest.raises(UserError, match="warp.fibre_modulus given without warp.fibre_volume"):
        with_key(scene, "warp.fibre_modulus", 72e9)


# --------------------------------------------------------------------------
# dynfab fit identifies the law from a force-angle curve.

FIT_D = [2e-3, 5e-3, 7.5e-3, 8.5e-3, 9.2e-3]
"""Corner displacements [m] of a 22 mm frame: past its yarns' meeting (35.8 degrees at
d = 7.8 mm) into their compaction (41.5 degrees at 9.2 mm)."""


def small_compacting_frame():
    lines = "".join(f"{key} = {value!r}\n" for key, value in COMPACTION_KEYS.items())
    text = scene_text(FRAME.replace("side = 0.06", "side = 0.022"), FIT_D)
    text = text.replace("[warp]\n", "[warp]\n" + lines).replace("[weft]\n", "[weft]\n" + lines)
    return parse_scene_text(text)


def test_a_made_up_force_angle_curve_gives_back_the_fibre_waviness():
    # The scene's own clamp forces (the zero-residual curve) fitted for warp.fibre_waviness from
    # a start 15 % off, the wefts' at the truth: the truth is the minimum; the optimiser stops
    # once a step in theta = log beta is below xtol (1e-8) (1 + |theta|), |theta| ~ 5.9, so 10
    # x that (tests/test_fit_specimen.py's rule).
    from dynfab import run
    from dynfab.fitting.fit import fit
    from dynfab.results.measured_curve import curve_from_columns

    scene = small_compacting_frame()
    steps = run(scene, solver="static").steps
    assert np.asarray(steps["lateral_gap"])[-1].max() > 0  # the law acts on the curve
    data = curve_from_columns(["end_displacement [m]", "clamp_force [N]"],
                              np.c_[FIT_D, steps["clamp_force"][1:]], "displacement",
                              model="specimen")
    truth = COMPACTION_KEYS["fibre_waviness"]
    result = fit(scene, data, ["warp.fibre_waviness"], substeps=1,
                 start={"warp.fibre_waviness": 0.85 * truth})
    assert result.converged, result.warnings
    value = result.parameters["warp.fibre_waviness"]["value"]
    assert abs(math.log(value / truth)) <= 10 * 1e-8 * (1 + abs(math.log(truth)))


@pytest.mark.parametrize("method", ["explicit", "semi_implicit"])
def test_static_and_dynamic_agree_past_the_meeting_of_the_yarns(method):
    # The 22 mm frame into the yarns' compaction: the dynamic solver's explicit relaxation
    # (the kernels' Gutowski law) and its semi-implicit one (the spatial tangent's lateral
    # blocks, E_lat''(d) dd dd^T) reach the static equilibria within the two runs' error
    # bounds (tests/test_shear_dynamic.py's rule); the recorded widths and fibre fractions
    # are each other's closed form, V = V0 w / width.
    pytest.importorskip("warp")
    from dynfab import run

    scene = small_compacting_frame()
    static = run(scene, solver="static").steps
    dynamic = run(scene, solver="dynamic", method=method).steps
    for k in range(len(FIT_D) + 1):
        bound = static["error_estimate"][k] + dynamic["error_estimate"][k]
        difference = np.abs(static["positions"][k] - dynamic["positions"][k]).max()
        assert difference <= bound, (k, difference, bound)
    pressing = np.asarray(static["lateral_gap"])[-1] > 0
    assert pressing.any()
    width = np.asarray(static["yarn_width"])[-1][pressing]
    fraction = np.asarray(static["fibre_volume_fraction"])[-1][pressing]
    assert np.allclose(fraction, 0.64 * WIDTH / width, rtol=1e-12)
