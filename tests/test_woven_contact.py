"""The woven-in contact (docs/model.md section 10, "The woven-in contact", (10.12)-(10.16)).

The yarns' rest lengths and rest turnings are solved so that the as-woven fabric is an
equilibrium with the contact force R_p (`[crossing] preload`) at every crossing and no
tension. Checked here:

- the as-woven state's forces: zero on every free dof of a periodic cell, a clamped patch and
  a picture frame (their yarn ends held), to float64's rounding of the stiffest spring's
  force (the construction is exact: no discretisation error);
- the static solver at zero load keeps R_p at every crossing to its tolerance, and the
  dynamic solver (both methods) finds the same state within the two error bounds;
- a free yarn end relaxes: a pulled-out warp's and a bias specimen's crossings lose contact
  within a few crossings of the end and keep R_p (median within 5 %) inside;
- against beam theory: a yarn whose stress-free shape is the continuum beam's (rest
  curvature = the sine's less M / EI, M the triangle wave of (10.13)), pressed into its sine
  by held crossing yarns, carries R_p at its crossings to second order in the segment length;
- a preload whose release would fold a free yarn end is refused in one line; without a
  preload the structure is the stress-free one, to the bit.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from dynfab import run
from dynfab.model.builders import woven_rest
from dynfab.model.builders.fabric import fabric_structure
from dynfab.errors import UserError
from dynfab.model.fabric import assembly, contact
from dynfab.model.fabric.model import FabricModel
from dynfab.model.fabric.specimen_model import SpecimenModel
from dynfab.scene import parse_scene_text
from dynfab.solvers.static import StaticSolver
from independent import EPS, PAPER_FRICTION, fabric_scene, held_family, record_inverse_norm
from test_shear_specimens import BIAS, FRAME, scene_text

PRELOAD = 0.01
"""R_p [N]: of the order of the paper yarn's contact forces (1e-3 to 3e-2 N)."""
WARP = dict(length=0.025, segments=16, amplitude=0.5e-3, EA=13.72, EI=1.47e-7,
            kawabata_C=0.2e-3, kawabata_K=0.2)
WEFT = dict(length=0.025, segments=16, amplitude=0.4e-3, EA=10.0, EI=2e-7,
            kawabata_C=0.15e-3, kawabata_K=0.3)
"""An unbalanced fabric, 4 crossings per yarn, 4 segments between crossings."""
GEOMETRIES = {"periodic cell": dict(boundary="periodic"), "clamped patch": {}}


def patch(geometry: dict, preload=PRELOAD, control="force", values=(0.0,), **tables):
    """A 4 x 4 fabric of WARP and WEFT with the woven-in contact `preload` [N]."""
    crossing = {} if preload is None else {"crossing": {"preload": preload}}
    return fabric_scene(WARP, WEFT, 4, 4, geometry=geometry,
                        load=dict(control=control, values=list(values),
                                  weft_values=[0.0] * len(values)), **crossing, **tables)


def rounding_force(structure) -> float:
    """64 eps max(EA / l0) max|r| [N]: what rounding the positions leaves of the stiffest
    spring's force (the stretch springs' tension is computed from them)."""
    return 64 * EPS * structure.stretch_stiffness.max() * np.abs(structure.rest_position).max()


def contact_forces(structure, positions) -> np.ndarray:
    out = np.zeros(structure.tie_a.size)
    contact.forces(positions, structure, out)
    return out


@pytest.mark.parametrize("geometry", GEOMETRIES.values(), ids=GEOMETRIES.keys())
def test_the_as_woven_state_carries_the_preload_in_equilibrium(geometry):
    # (10.12): the closure offset puts R_p on every crossing; (10.13)-(10.15): the rest shapes
    # balance it. The patch's ends lie midway between crossings, where (10.13)'s moment
    # vanishes, and are held in z (its vertical force +-R_p / 2); the cell's are images.
    s = fabric_structure(patch(geometry))
    pos = s.rest_position
    assert np.allclose(contact_forces(s, pos), PRELOAD, rtol=4 * EPS, atol=0)
    T = s.tie_a.size
    grad = np.zeros_like(pos)
    assembly.gradient(pos, s, np.zeros(s.chain_start.size - 1), np.zeros((T, 2)), np.zeros(T),
                      grad)
    free = ~s.fixed.reshape(pos.shape)
    assert np.abs(grad[free]).max() <= rounding_force(s)
    # and the crossing forces are what the held ends resist: not a zero-force state
    assert np.abs(grad[~free]).max() > 0.1 * PRELOAD


def test_without_a_preload_the_structure_is_the_stress_free_one_to_the_bit():
    stress_free = fabric_structure(patch({}, preload=None))
    zero = fabric_structure(patch({}, preload=0.0))
    for name, value in stress_free._asdict().items():
        assert np.array_equal(value, getattr(zero, name)), name
    # as woven: rest lengths the woven segments', rest turnings the woven turnings
    woven = stress_free.rest_position[: WARP["segments"] + 1]
    assert np.array_equal(stress_free.rest_length[: WARP["segments"]],
                          np.hypot(*np.diff(woven, axis=0).T))


@pytest.mark.parametrize("geometry", GEOMETRIES.values(), ids=GEOMETRIES.keys())
def test_the_static_solver_keeps_the_preload_at_zero_load(geometry):
    result = run(patch(geometry, friction=PAPER_FRICTION), solver="static")
    steps = result.steps
    # |R - R_p| <= k |delta g| <= k (2 x the position error bound): the contact's tangent k
    # (3.7b) at most the core stiffness k_c, the closure moving by both nodes' errors
    bound = float(steps["error_estimate"][0])
    k_c = 1e5
    R = steps["contact_force"][0]
    assert np.abs(R - PRELOAD).max() <= 2 * k_c * bound + 64 * EPS * PRELOAD
    assert int(steps["negative_eigenvalues"][0]) == 0
    assert bound <= 1e-9  # the bound itself small: a state at rest, not a loose solve


@pytest.mark.parametrize("method", ["explicit", "semi_implicit"])
def test_static_and_dynamic_agree_on_the_woven_state(method):
    # Both solve the zero-load step from the as-woven state, now an equilibrium: the dynamic
    # one relaxes what rounding leaves; |x_dyn - x_static| within the sum of the two runs'
    # error bounds (tests/test_shear_dynamic.py's rule). A pull is added so that the state
    # moves and both solvers work: its path is not at rest.
    scene = patch({}, control="displacement", values=(0.0, 2e-5), friction=PAPER_FRICTION)
    static = run(scene, solver="static").steps
    dynamic = run(scene, solver="dynamic", method=method).steps
    for k in range(2):
        bound = static["error_estimate"][k] + dynamic["error_estimate"][k]
        difference = np.abs(static["positions"][k] - dynamic["positions"][k]).max()
        assert difference <= bound, (k, difference, bound)
    assert np.allclose(dynamic["contact_force"][0], PRELOAD, rtol=0,
                       atol=2e5 * float(dynamic["error_estimate"][0]) + 1e-15)


def test_a_free_yarn_end_loses_the_contact_near_it_and_only_there():
    # A pull-out's pulled warp has a free first node: (10.13)'s vertical force R_p / 2 there
    # has nothing to hold it, so the warp's end relaxes. Its first crossing loses most of its
    # contact, and the first weft, pushed by it, some of its others'; the crossings three
    # spacings and more from the free end (weft 4) keep R_p within 5 %.
    scene = patch({}, control="displacement", values=(0.0,), friction=PAPER_FRICTION,
                  pullout={"warp": 2})
    steps = run(scene, solver="static").steps
    rank = woven_rest.crossings_from_free_end(fabric_structure(scene))
    R = steps["contact_force"][0]  # (warps, wefts)
    assert rank.min() == 1 and np.count_nonzero(rank == 1) == 1  # the pulled warp's first
    assert R[1, 0] == R.ravel()[rank == 1][0] < 0.5 * PRELOAD
    assert np.all(np.abs(R[:, 3] / PRELOAD - 1) < 0.05)


def test_the_free_end_band_of_a_bias_specimen_is_narrow():
    # docs/model.md section 10, at a free end: the bias specimen's yarns end free on its long
    # sides; after step 0 the median contact of the crossings three and more from a free end
    # is within 5 % of R_p (the criterion), the last crossing's well below it.
    scene = parse_scene_text(scene_text(BIAS, [1e-3]))
    model = SpecimenModel(scene)
    solver = StaticSolver(model)
    _, record = solver.step(solver.initial_state(), 0.0)
    preload = scene.crossing.preload
    rank = woven_rest.crossings_from_free_end(model.structure)
    R = record["contact_force"]
    assert abs(np.median(R[rank >= 3]) / preload - 1) < 0.05
    assert np.median(R[rank == 1]) < 0.9 * preload


def test_a_picture_frame_keeps_the_preload_at_every_crossing():
    # Every yarn of a frame is held by a bar at both ends (with its end piece): no free end,
    # so step 0 finds the woven state at rest and every crossing at R_p.
    steps = run(parse_scene_text(scene_text(FRAME, [3e-3])), solver="static").steps
    bound = float(steps["error_estimate"][0])
    assert np.abs(steps["contact_force"][0] - 0.1).max() <= 2 * 1e5 * bound + 1e-15


def test_a_preload_that_would_fold_a_free_yarn_end_is_refused_in_one_line():
    # (10.16): released at a free end the woven-in moment turns the yarn by about
    # 2 R_p p^2 / (16 EI); past 90 degrees from the fabric's plane it folds back.
    with pytest.raises(UserError) as info:
        fabric_structure(patch({}, preload=1.0, control="displacement",
                               pullout={"warp": 2}))
    message = str(info.value)
    assert "\n" not in message
    assert message.startswith("crossing.preload = 1 N:") and "folds back" in message
    p, EI, A = WARP["length"] / 4, WARP["EI"], WARP["amplitude"]
    largest = (math.pi / 2 - math.atan(math.pi * A / p)) * 8 * EI / p ** 2
    assert f"below {largest:.3g} N" in message
    fabric_structure(patch({}, preload=0.99 * largest, control="displacement",
                           pullout={"warp": 2}))
    # a patch whose yarn ends are all held takes any preload
    fabric_structure(patch({}, preload=1.0))


# --------------------------------------------------------------------------
# Against beam theory.

SPACING = 5e-3
AMPLITUDE = 0.3e-3
SPACINGS = 4
BEAM_EI = 1e-6
BEAM_EA = 1e4
"""A stiff yarn (EA) bent by much more than its weight of crimp: R_p = 0.05 N against the
straight rest shape's 48 EI A / p^3 = 0.115 N (the rest shape half set)."""


def beam_rest_shape(s: np.ndarray, preload: float) -> np.ndarray:
    """The stress-free shape (m, 2) [m] of the continuum yarn at arc lengths `s` of its woven
    sine z = A sin(pi x / p), x in [0, SPACINGS p], node 0 at x = 0 held: rest curvature
    kappa0(s) = kappa(s) - M(x(s)) / EI, M the triangle wave of (10.13) (0 at x = k p,
    -+R_p p / 4 at the crossings, the first pressed upwards), integrated for the tangent angle
    and the shape by fine trapezoids (errors far below the chain's)."""
    fine = np.linspace(0.0, SPACINGS * SPACING, 400_001)
    dz = AMPLITUDE * math.pi / SPACING * np.cos(math.pi * fine / SPACING)
    ds = np.sqrt(1 + dz ** 2)
    arc = np.concatenate([[0.0], np.cumsum(0.5 * (ds[1:] + ds[:-1]) * np.diff(fine))])
    woven_angle = np.arctan(dz)
    phase = (fine / SPACING) % 2.0  # within one wavelength; crossings at 0.5 and 1.5
    # G = -F/2 after a crossing of force F; the first crossing's force is +R_p (upwards: the
    # warp above the weft pushes it up), M' = -G
    moment = -preload * SPACING / 4 * (1 - np.abs(2 * (phase % 1.0) - 1)) \
        * np.where(phase < 1.0, 1.0, -1.0)
    curvature_change = moment / BEAM_EI
    turned = np.concatenate([[0.0], np.cumsum(0.5 * (curvature_change[1:] +
                                                     curvature_change[:-1]) * np.diff(arc))])
    rest_angle = woven_angle - turned
    x = np.concatenate([[0.0], np.cumsum(0.5 * (np.cos(rest_angle[1:]) + np.cos(rest_angle[:-1]))
                                         * np.diff(arc))])
    z = np.concatenate([[0.0], np.cumsum(0.5 * (np.sin(rest_angle[1:]) + np.sin(rest_angle[:-1]))
                                         * np.diff(arc))])
    return np.stack([np.interp(s, arc, x), np.interp(s, arc, z)], axis=1)


def pressed_beam_contact(per_spacing: int, preload: float) -> np.ndarray:
    """Contact forces [N] of a warp whose rest shape is `beam_rest_shape` (sampled at its
    woven nodes' arc lengths), pressed into its sine by held wefts (a warp against rigid
    crossing yarns, as the one-yarn model's)."""
    warp = dict(length=SPACINGS * SPACING, segments=SPACINGS * per_spacing, amplitude=AMPLITUDE,
                EA=BEAM_EA, EI=BEAM_EI, kawabata_C=0.2e-3, kawabata_K=0.2)
    weft = dict(length=2 * SPACING, segments=2 * per_spacing, amplitude=AMPLITUDE, EA=BEAM_EA,
                EI=BEAM_EI, kawabata_C=0.2e-3, kawabata_K=0.2)
    scene = fabric_scene(warp, weft, 2, SPACINGS, crossing={"preload": preload},
                         load=dict(control="force", values=[0.0], weft_values=[0.0]))
    model = held_family(scene, "weft")
    s = model.structure
    warp_nodes = slice(0, warp["segments"] + 1)
    woven = s.rest_position[warp_nodes]
    arc = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(woven, axis=0).T))])
    rest = beam_rest_shape(arc, preload)
    e = np.diff(rest, axis=0)
    l0 = np.hypot(e[:, 0], e[:, 1])
    turn = np.zeros(rest.shape[0])
    turn[1:-1] = np.arctan2(e[:-1, 0] * e[1:, 1] - e[:-1, 1] * e[1:, 0],
                            np.sum(e[:-1] * e[1:], axis=1))
    lbar = np.concatenate([[l0[0] / 2], 0.5 * (l0[:-1] + l0[1:]), [l0[-1] / 2]])
    bend = BEAM_EI / lbar
    bend[[0, -1]] = 0.0
    segments = warp["segments"]
    s = s._replace(rest_length=np.concatenate([l0, s.rest_length[segments:]]),
                   stretch_stiffness=np.concatenate([BEAM_EA / l0, s.stretch_stiffness[segments:]]),
                   rest_angle=np.concatenate([turn, s.rest_angle[segments + 1:]]),
                   bend_stiffness=np.concatenate([bend, s.bend_stiffness[segments + 1:]]))
    solver = StaticSolver(FabricModel.from_scene(scene, s), tolerance=1e-13)
    _, record = solver.step(solver.initial_state(), (0.0, 0.0))
    # only the first warp is the one under test (the second, the mirror image, the same)
    return np.asarray(record["contact_force"])[0]


def test_a_yarn_set_by_beam_theory_presses_its_crossings_with_the_preload():
    # Beam theory of the woven-in contact: the yarn's stress-free shape is the woven sine's
    # curvature less M / EI, M the triangle wave of (10.13) (a beam with alternating point
    # loads R_p and no horizontal force). Built on that continuum rest shape and pressed into
    # its sine by rigid crossing yarns, the chain's contact forces tend to R_p at second order
    # in its segment length h (the chain's bending is the beam's to O(h^2), section 11.2).
    preload = 0.05
    meshes = (4, 8, 16, 32)
    errors = np.array([np.abs(pressed_beam_contact(n, preload) - preload).max()
                       for n in meshes])
    order = -np.polyfit(np.log(meshes), np.log(errors), 1)[0]
    assert 1.7 < order < 2.3, (errors, order)
    assert errors[-1] < 2e-3 * preload


def test_dynfab_plot_draws_the_contact_after_step_0_and_its_free_end_band(tmp_path):
    # The band of section 10's free ends, drawn (`dynfab plot`: contact_field.png): over the
    # specimen, and the median against the rank from a free yarn end.
    from dynfab.plots.figures import plot_results
    from dynfab.results.file import read_results
    from dynfab.plots.specimen import plot_contact_field

    out = tmp_path / "bias.h5"
    run(parse_scene_text(scene_text(BIAS, [1e-3])), solver="static", out=out)
    written = plot_results(out, tmp_path / "figures")
    assert tmp_path / "figures" / "contact_field.png" in written
    field, band = plot_contact_field(read_results(out)).axes[:2]
    assert field.get_xlabel() == "x [mm]" and field.get_aspect() == 1.0
    assert band.get_xlabel() == "crossings from a free yarn end [-]"
    assert band.get_ylabel() == "contact force / preload [-]"
    median = band.lines[0].get_ydata()
    assert median[0] < 0.9 and abs(median[-1] - 1) < 0.05  # the last crossing, the interior
    assert [t.get_text() for t in band.get_xticklabels()][-1] == "7+"
