"""Crossings that slide along the yarns (docs/model.md 11.13; issue 37): the planar fabric's
sliding term set against finite differences, a rigid motion, straight yarns (where sliding and
fixed crossings are one model), a yarn pulled through crossings that hold their contact
forces (its force the sum of their friction limits, each departure dropping it by its own,
zero once the yarn has left), the path's energy balance, a resumed run past a departure, the
pull-out of runs/fabric_pullout.toml to full extraction on a 4 x 4 patch, and the refusals;
the same term set over the spatial fabric's on a bias specimen (finite differences, a rigid
motion, the fixed crossings as woven and where they hold, edge yarns sliding out past their
last crossings, a resumed run, a failing step made of halves).
"""

from __future__ import annotations

import numpy as np
import pytest

from dynfab.errors import UserError
from dynfab.model.builders.sliding import woven_dofs
from dynfab.model.fabric import assembly, sliding
from dynfab.model.fabric.model import FabricModel
from dynfab.model.structure import chain_of_node
from dynfab.model.terms import contact as contact_law
from dynfab.model.terms import friction as gralen
from dynfab.model.terms.kinematics import woven_anchors
from dynfab.run import run, run_to_file
from dynfab.kernels.structure_relaxation import StructureRelaxation
from dynfab.scene import Dynamic, parse_scene_text
from dynfab.solvers.dynamic import DynamicSolver
from dynfab.solvers.static import StaticSolver
from independent import fabric_scene, pullout_text
from test_fabric_scenes import RUNS, assert_same_steps, run_interrupted

WARP = dict(length=0.04, segments=12, amplitude=0.5e-3, EA=13.72, EI=1.47e-7, kawabata_C=0.2e-3,
            kawabata_K=0.2)
WEFT = dict(length=0.03, segments=12, amplitude=0.4e-3, EA=10.0, EI=2e-7, kawabata_C=0.15e-3,
            kawabata_K=0.3)
FRICTION = dict(alpha=0.2, beta=1e3, contact_length=2e-3, fiber_radius=1e-3)


def patch(motion: str = "sliding", **more):
    """A crimped 3 x 3 clamped patch with a woven-in preload and the paper's friction."""
    return fabric_scene(WARP, WEFT, 3, 3, friction=FRICTION,
                        crossing=dict(preload=0.01, motion=motion),
                        load=dict(control="force", values=[0.01]), **more)


@pytest.fixture(scope="module")
def structure():
    return FabricModel.from_scene(patch()).structure


def perturbed(s, seed=0):
    """Dofs off the as-woven state by up to 10 um (material coordinates too), anchors off the
    woven ones by 10 um with the stretches at the dofs beside them, and friction limits so
    that some crossings stick, some slide and some are open (F_T = 0)."""
    rng = np.random.default_rng(seed)
    dofs = woven_dofs(s) + 1e-5 * rng.standard_normal(s.rest_position.shape) \
        * ~s.fixed.reshape(s.rest_position.shape)
    anchors = sliding.with_stretches(dofs, s, woven_anchors(s))
    anchors[:, :2] += 1e-5 * rng.standard_normal((s.tie_a.size, 2))
    limit = np.where(np.arange(s.tie_a.size) % 3 == 0, 0.0, 0.01)
    return dofs, anchors, limit


def loads(s):
    return np.full(s.chain_start.size - 1, 0.02)


def energy(s, dofs, anchors, limit):
    return sliding.total_energy(dofs, s, loads(s), anchors, limit, np.zeros(len(sliding.TERMS)))


def gradient(s, dofs, anchors, limit):
    grad = np.zeros_like(dofs)
    sliding.gradient(dofs, s, loads(s), anchors, limit, grad)
    return grad


def test_the_as_woven_state_has_the_fixed_crossings_energies(structure):
    """As woven, every bay's material is its as-woven length (L = f (u_R - u_L) = l0) and the
    nodes are where the fixed crossings' are: each term's energy equals the fixed structure's
    at its rest positions, to rounding (a few ulps of each term)."""
    fixed = FabricModel.from_scene(patch("fixed")).structure
    limit = np.full(fixed.tie_a.size, 0.01)
    P = loads(fixed)
    dofs = woven_dofs(structure)
    anchors = sliding.with_stretches(dofs, structure, woven_anchors(structure))
    np.testing.assert_allclose(
        sliding.energy_vector(structure, dofs, P, anchors, limit),
        assembly.energy_vector(fixed, fixed.rest_position, P, woven_anchors(fixed), limit),
        rtol=1e-12)


def on_a_boundary(**geometry):
    """`patch` as a 2 x 2 patch with the boundary `geometry` (a periodic cell or moving
    planes), its end loads as forces."""
    return FabricModel.from_scene(fabric_scene(
        WARP, WEFT, 2, 2, friction=FRICTION, crossing=dict(preload=0.01, motion="sliding"),
        load=dict(control="force", values=[0.01]), geometry=geometry)).structure


@pytest.fixture(scope="module", params=["clamped_patch", "periodic_cell", "moving_planes"])
def term_case(request, structure):
    """(structure, dofs, anchors, limits) of `perturbed` on the 3 x 3 patch, a periodic cell
    (its wrap springs bent by lifting each chain's node 1 by 0.2 mm, so that their material
    terms, E_w / lbar_0 and 2 E_w / lbar_0^2, stand above the differences' error) and a patch
    whose planes move with its mean stretch (each crossing's node on its plane, X + w U: the
    plane nodes' share of every force on it)."""
    if request.param == "clamped_patch":
        return (structure, *perturbed(structure))
    return perturbed_on_a_boundary(request.param)


def perturbed_on_a_boundary(kind: str):
    """`perturbed` on a periodic cell (kind "periodic_cell", its wrap springs bent by lifting
    each chain's node 1 by 0.2 mm) or a patch with moving planes ("moving_planes"):
    (structure, dofs, anchors, limits)."""
    s = on_a_boundary(**({"boundary": "periodic"} if kind == "periodic_cell"
                         else {"planes": "affine"}))
    dofs, anchors, limit = perturbed(s)
    if kind == "periodic_cell":
        dofs[s.chain_start[:-1] + 1, 1] += 2e-4
    return s, dofs, anchors, limit


def test_the_gradient_is_the_derivative_of_the_energy(term_case):
    """Central differences on every free dof (material coordinates included), h = 1e-8 m:
    truncation h^2 |V'''| and rounding eps V / h both below 1e-9 N; 1e-6 of the largest
    force component still fails on a term scattered to a wrong dof or a missing material
    part (the stretch's dE/dL alone is 1e-2 N here; a moving plane's share 3e-2 N, the wrap
    springs' material part 2e-5 N)."""
    s, dofs, anchors, limit = term_case
    grad = gradient(s, dofs, anchors, limit).ravel()
    h = 1e-8
    for dof in np.flatnonzero(~s.fixed):
        plus, minus = dofs.copy().ravel(), dofs.copy().ravel()
        plus[dof] += h
        minus[dof] -= h
        fd = (energy(s, plus.reshape(dofs.shape), anchors, limit)
              - energy(s, minus.reshape(dofs.shape), anchors, limit)) / (2 * h)
        assert fd == pytest.approx(grad[dof], abs=1e-6 * np.abs(grad).max())


def test_the_sparse_hessian_is_the_derivative_of_the_gradient(term_case):
    """Every entry of the assembled Hessian on the free dofs (`sliding.full_hessian`) against
    central differences of the gradient, h = 1e-9 m: error h^2 |V''''| + eps |grad| / h, the
    sliding Huber branch's F_T / |S|^3 term the largest, 1e13 N/m^3 at |S| = 10 um: h^2 times
    it is 1e-5 N/m (against entries of 1e4), so 2e-5 N/m (a periodic cell's wrap material
    block, 2 E_w / lbar_0^2 dlbar_0/du^2, is 2e-3 N/m here)."""
    s, dofs, anchors, limit = term_case
    H = sliding.full_hessian(s, dofs, anchors, limit)
    free = np.flatnonzero(~s.fixed)
    h = 1e-9
    for dof in free:
        plus, minus = dofs.copy().ravel(), dofs.copy().ravel()
        plus[dof] += h
        minus[dof] -= h
        column = (gradient(s, plus.reshape(dofs.shape), anchors, limit)
                  - gradient(s, minus.reshape(dofs.shape), anchors, limit)).ravel() / (2 * h)
        np.testing.assert_allclose(H[free, dof], column[free], rtol=0, atol=2e-5)


def test_a_rigid_motion_moves_no_material_coordinate_and_costs_no_energy(structure):
    """The planar fabric's rigid motion, every node lifted along z: the material coordinates
    (the crossings' slots) do not move, and no term's energy nor any force changes (to
    rounding: 1e-12 of the terms, 1e-9 of the largest force)."""
    s = structure
    dofs, anchors, limit = perturbed(s, seed=2)
    lifted = dofs.copy()
    lifted[:, 1] += 3e-3
    material = s.tie_material.ravel()
    np.testing.assert_array_equal(lifted.reshape(-1)[material], dofs.reshape(-1)[material])
    P = loads(s)
    before = sliding.energy_vector(s, dofs, P, anchors, limit)
    after = sliding.energy_vector(s, lifted, P, anchors, limit)
    np.testing.assert_allclose(after, before, rtol=1e-9, atol=1e-12 * np.abs(before).sum())
    g0, g1 = gradient(s, dofs, anchors, limit), gradient(s, lifted, anchors, limit)
    np.testing.assert_allclose(g1, g0, atol=1e-9 * np.abs(g0).max())


def straight_patch(motion: str):
    """A frictionless 3 x 3 patch of straight yarns under end forces (no contact force: the
    yarns do not touch)."""
    warp, weft = dict(WARP, amplitude=0.0, segments=24), dict(WEFT, amplitude=0.0, segments=24)
    return fabric_scene(warp, weft, 3, 3, crossing=dict(motion=motion),
                        load=dict(control="force", values=[0.01, 0.02],
                                  warp_factors=[1.0, 0.5, 0.2]))


def test_straight_yarns_slide_as_the_fixed_crossings_let_them():
    """Straight yarns without contact or friction: a fixed crossing's node and a sliding
    crossing's material both move freely, so both models are each yarn a chain of springs
    under its end force: the yarns' ends (their end displacements and end nodes) agree within
    the two steps' error bounds (`steps/error_estimate`). (Between its ends a yarn's nodes
    differ: the sliding crossings' stay on the planes, the material flowing through.)"""
    runs = {motion: StaticSolver(FabricModel.from_scene(straight_patch(motion))).run()[1]
            for motion in ("fixed", "sliding")}
    for fixed, moving in zip(runs["fixed"], runs["sliding"]):
        bound = float(fixed["error_estimate"]) + float(moving["error_estimate"])
        np.testing.assert_allclose(moving["end_displacement"], fixed["end_displacement"],
                                   rtol=0, atol=bound)
        for name in ("positions", "weft_positions"):
            np.testing.assert_allclose(np.asarray(moving[name])[:, [0, -1]],
                                       np.asarray(fixed[name])[:, [0, -1]], rtol=0, atol=bound)


def held_pullout(wefts: int, step: float, steps: int, R: float = 0.05):
    """A straight warp pulled (its end displaced `step` per step) through `wefts` held wefts
    with sliding crossings, each pressed with the contact force R [N] held (the wefts' dofs
    and the warp's crossing nodes' z held, the closure set by the tie's offset), its first
    node free: (model, F_T of one crossing [N])."""
    warp = dict(WARP, amplitude=0.0, length=0.005 * wefts, segments=10 * wefts)
    weft = dict(WEFT, amplitude=0.0, length=0.005, segments=10)
    scene = fabric_scene(warp, weft, 1, wefts, friction=FRICTION, crossing=dict(motion="sliding"),
                         pullout=dict(warp=1), load=dict(
                             control="displacement", values=list(step * np.arange(1, steps + 1))))
    s = FabricModel.from_scene(scene).structure
    weft_nodes = s.chain_family[chain_of_node(s)] == 1
    fixed = s.fixed | np.repeat(weft_nodes, 2)
    fixed[2 * s.tie_a + 1] = True
    closure = contact_law.closure_from_force(R, s.tie_contact_law[0])
    s = s._replace(fixed=fixed, tie_gap_offset=s.tie_gap_offset + closure)
    limit = np.zeros(1)
    gralen.tie_limits(np.array([R]), s.tie_friction_law[:1], -1.0, limit)
    return FabricModel.from_scene(scene, structure=s), float(limit[0])


def plateau(records, settled: int) -> tuple[np.ndarray, np.ndarray]:
    """(the steps i of a plateau, the count of crossings during each step): those whose
    crossings are the ones of the `settled` steps before and all slide at i - 1 and at i. A
    step runs with the crossings its previous record left, its friction with the stretches
    that step ended with (11.13c): after a change of force those trail the tension by one
    step, the force's error falling about a thousandfold a step (4.7e-5, 4.3e-8, 3.3e-11 N
    after the first pull of the held warp), below the residual's tolerance from the third
    step of a plateau on."""
    present = np.array([r["crossing_present"][0] for r in records])
    during = np.vstack([np.ones_like(present[:1]), present[:-1]])
    slides = np.array([np.all(r["sliding"][0][during[i]]) for i, r in enumerate(records)])
    steps = [i for i in range(settled, len(records))
             if all(np.array_equal(during[i - k], during[i]) for k in range(1, settled + 1))
             and slides[i - 1] and slides[i] and during[i].any()]
    return np.array(steps, int), during.sum(axis=1)


def test_a_yarn_pulled_through_crossings_carries_the_sum_of_their_limits_to_zero():
    """A straight warp pulled through four crossings that hold their contact forces R: once
    all slide, the pull is sum F_T(R) (its material's balance at each crossing: the tension
    jumps by the friction force F_T lambda_0 over the mean stretch there, the slip measured in
    space, docs/model.md 11.13), to the residual's tolerance times the warp's nodes, on every
    step of a plateau (`plateau`); each crossing the free end reaches leaves, in order from
    that end, and drops the force by its own F_T; after the last the pull is 0."""
    model, F_T = held_pullout(wefts=4, step=2.5e-4, steps=88)
    state, records = StaticSolver(model).run()
    tolerance = (model.warp.segments + 1) * model.scene.static.tolerance
    present = np.array([r["crossing_present"][0] for r in records])
    pull = np.array([float(r["end_force"][0]) for r in records])
    assert present[0].all() and not present[-1].any()
    gone = [int(np.argmax(~present[:, j])) for j in range(4)]
    assert gone == sorted(gone)  # the crossing nearest the free end leaves first
    steps, count = plateau(records, settled=2)
    assert steps.size > len(records) // 2 and set(count[steps]) == {1, 2, 3, 4}
    np.testing.assert_allclose(pull[steps], count[steps] * F_T, rtol=0, atol=tolerance)
    assert np.all(np.abs(pull[count == 0]) <= tolerance)


def test_a_pull_outs_work_is_its_stored_energy_and_its_dissipation():
    """Along the pull of three held crossings to extraction, step by step: on every step of a
    plateau (`plateau`), the work of the pull F du is the change of the stored energy
    (stretch, bending, stick springs) plus the friction dissipated, F_T times each
    crossing's slide in space, to the solver (the residual's tolerance times the warp's nodes
    times the step; from the fourth step of a plateau, the trapezoid rule's force of the step
    before settled too, `plateau`). Over the whole path
    the trapezoid work differs from them by what the force's jumps make of the rule, half of
    each jump times its step (the rise from 0, each departure's drop), and by the elastic
    energy a departure releases at once, at most (Delta T)^2 L / (2 EA) over the warp's
    length L."""
    step = 2.5e-4
    model, F_T = held_pullout(wefts=3, step=step, steps=64)
    state, records = StaticSolver(model).run()
    stored = np.array([sum(float(r[f"energy/{k}"]) for k in ("stretch", "bending", "stick"))
                       for r in records])
    work = np.array([float(r["work"]) for r in records])
    dissipated = np.array([float(r["dissipated"]) for r in records])
    pull = np.array([float(r["end_force"][0]) for r in records])
    steps, _ = plateau(records, settled=3)
    assert steps.size > len(records) // 2
    imbalance = np.diff(work) - np.diff(stored) - np.diff(dissipated)  # [i - 1]: step i's
    tolerance = (model.warp.segments + 1) * model.scene.static.tolerance * step
    assert np.all(np.abs(imbalance[steps - 1]) <= tolerance)
    jumps = np.abs(np.diff(np.r_[0.0, pull]))
    L, EA = model.warp.length, model.scene.warp.EA
    bound = 0.5 * step * jumps.sum() + (jumps ** 2).sum() * L / (2 * EA)
    assert abs(work[-1] - stored[-1] - dissipated[-1]) <= bound
    assert stored[-1] == 0.0 and dissipated[-1] > 0.9 * work[-1]


def small_pullout(values: int) -> str:
    """runs/fabric_pullout.toml (crossings sliding) as a 4 x 4 patch of the same segment length
    (0.446 mm), warp 2 pulled after the wefts' two steps, its path the scene's first `values`
    values and on in its 0.25 mm steps to 23 mm."""
    text = pullout_text("sliding", steps=values)
    for old, new in (("segments = 112", "segments = 56"), ("crossings = 8", "crossings = 4"),
                     ("count = 8", "count = 4"), ("warp = 4", "warp = 2"),
                     ("length = 0.05", "length = 0.025")):
        text = text.replace(old, new)
    return text


def test_the_pull_out_runs_to_full_extraction_and_its_figure_draws_it(tmp_path):
    """runs/fabric_pullout.toml on a 4 x 4 patch, pulled to 23 mm: the pull never exceeds the
    sum of the friction limits of the crossings the warp runs through (each one's friction
    carries at most its F_T along the warp; the warp's crimp takes some more of the force into
    the crossings' planes); every crossing of the pulled warp leaves it, one per drop of the
    force, the drop at least half the limit the crossing carried, and between departures the
    force holds within 1 % a step (the crimp straightening); after the last it is 0 N.
    `dynfab plot` draws the file (`pullout.png`)."""
    from dynfab.plots.figures import plot_results, pullout_curves
    from dynfab.results.file import read_results

    out = tmp_path / "pullout.h5"
    scene = parse_scene_text(small_pullout(112))
    run_to_file(scene, "static", out)
    results = read_results(out)
    pull = pullout_curves(results)["force"]
    present = np.asarray(results.steps["crossing_present"], bool)[:, 1]
    limits = np.asarray(results.steps["friction_limit"])[:, 1]
    during = np.vstack([np.ones_like(present[:1]), present[:-1]])
    tolerance = (scene.geometry.segments + 1) * scene.static.tolerance
    assert np.all(pull <= (limits * during).sum(axis=1) + tolerance)
    assert present[0].all() and not present[-1].any() and pull[-1] == 0.0
    left = np.flatnonzero(during[1:].sum(axis=1) < during[:-1].sum(axis=1)) + 1  # first steps
    assert left.size == 4  # without them, one crossing at a time
    for i in left:
        gone = during[i - 1] & ~during[i]
        assert pull[i - 1] - pull[i] >= 0.5 * limits[i - 1][gone].sum()
    holding = np.setdiff1d(np.arange(25, pull.size), left)  # past the rise (step 25)
    holding = holding[pull[holding - 1] > 0]
    assert np.all(np.abs(np.diff(pull)[holding - 1]) <= 0.01 * pull[holding - 1])
    written = plot_results(out, tmp_path / "figures")
    assert tmp_path / "figures" / "pullout.png" in written
    assert all(path.exists() for path in written)


def test_a_resumed_run_past_a_departure_repeats_the_uninterrupted_one(tmp_path):
    """A sliding pull-out stopped after its first departure and resumed writes the uninterrupted
    run's steps exactly: the departures replayed from the file's crossing_present and material
    coordinates rebuild the same structure (docs/model.md 11.13)."""
    scene = parse_scene_text(small_pullout(40))
    whole, part = tmp_path / "whole.h5", tmp_path / "part.h5"
    run_to_file(scene, "static", whole)
    from dynfab.results.file import read_results
    present = np.asarray(read_results(whole).steps["crossing_present"], bool)
    first = int(np.argmax(~present.reshape(present.shape[0], -1).all(axis=1)))
    assert 0 < first < len(scene.load.values) - 3
    run_interrupted(scene, "static", part, steps=first + 2)
    run_to_file(scene, "static", part, resume=True)
    assert_same_steps(whole, part)


def sliding_text(name: str, smaller: dict | None = None) -> str:
    """runs/<name>.toml with its crossings sliding, its `smaller` keys' text replaced."""
    text = (RUNS / f"{name}.toml").read_text()
    for old, new in (smaller or {}).items():
        text = text.replace(old, new)
    return text + '\n[crossing]\nmotion = "sliding"\n'


STRIP_4X4 = {"crossings = 16": "crossings = 4", "count = 16": "count = 4",
             "segments = 224": "segments = 56"}
"""runs/fabric_strip.toml as a 4 x 4 patch of the same segment length (its 0.1 m yarns
kept)."""


@pytest.mark.parametrize("name, smaller", [("fabric_biaxial_2to1", None),
                                           ("fabric_strip", STRIP_4X4)],
                         ids=["periodic_cell", "strip_moving_planes"])
def test_where_no_crossing_slides_the_sliding_crossings_are_the_fixed_ones(name, smaller):
    """A periodic cell (runs/fabric_biaxial_2to1.toml, its planes moving with the cell) and the
    strip test (runs/fabric_strip.toml on a 4 x 4 patch, its planes moving with its mean
    stretch): every crossing lies on its yarns' mirror planes, so none slips or slides
    (docs/model.md section 10), and a fixed crossing's node stays on the plane a sliding
    one's is held on (X + w U, docs/model.md 11.13): the two models have one equilibrium.
    Every step's positions agree within the sum of the two runs' error bounds, every slide is
    within the sliding run's (a crossing held at its woven plane instead would sit off by the
    strain times its distance from the origin, 1e-4 m)."""
    fixed = run(parse_scene_text(sliding_text(name, smaller).replace(
        'motion = "sliding"', 'motion = "fixed"')), "static").steps
    slides = run(parse_scene_text(sliding_text(name, smaller)), "static").steps
    bound = np.asarray(fixed["error_estimate"]) + np.asarray(slides["error_estimate"])
    assert np.all(np.isfinite(bound)) and len(bound) == len(fixed["load"])
    for key in ("positions", "weft_positions"):
        gap = np.abs(np.asarray(fixed[key]) - np.asarray(slides[key]))
        assert np.all(gap.reshape(len(bound), -1).max(axis=1) <= bound), key
    slip = np.abs(np.asarray(slides["slip"])).reshape(len(bound), -1).max(axis=1)
    assert np.all(slip <= np.asarray(slides["error_estimate"]))


PAPER_FRICTION = """
[friction]
alpha = 0.2
beta = 1e3
contact_length = 2e-3
fiber_radius = 1e-3
"""
"""runs/fabric_strip.toml's friction, given to the periodic cell too: one kernel variant
(crossings that slide, friction, moving planes) for both runs below."""


UNEQUAL_WARPS = {**STRIP_4X4, "steps = 10": "steps = 10\nwarp_factors = [1.0, 0.5, 0.25, 1.0]"}
"""The 4 x 4 strip with unequal loads per warp: its crossings slide along the yarns, up to
2.7 mm by the last step, as the warps stretch past and short of the planes' mean stretch."""


@pytest.mark.parametrize("name, smaller, more", [
    ("fabric_biaxial_2to1", None, PAPER_FRICTION), ("fabric_strip", UNEQUAL_WARPS, "")],
    ids=["periodic_cell", "strip_unequal_loads"])
def test_dynamic_relaxation_of_sliding_crossings_on_moving_planes_meets_the_static_reference(
        name, smaller, more):
    """The periodic cell of `test_where_no_crossing_slides_the_sliding_crossings_are_the_fixed_ones`
    (with the paper's friction) and the 4 x 4 strip with unequal loads per warp
    (`UNEQUAL_WARPS`), by the dynamic solver's explicit relaxation (the kernels' crossing
    nodes on the moving planes, X + w U, their forces taken by the plane nodes, a tied
    family's summed; the wrap springs' material part, docs/model.md 11.13) and by the static
    one: every step's positions and slides within the sum of the two runs' error bounds."""
    text = sliding_text(name, smaller) + more
    static, dynamic = (run(parse_scene_text(text), solver).steps
                       for solver in ("static", "dynamic"))
    bound = np.asarray(static["error_estimate"]) + np.asarray(dynamic["error_estimate"])
    assert np.all(np.isfinite(bound)) and len(bound) == len(static["load"])
    for key in ("positions", "weft_positions", "slip"):
        gap = np.abs(np.asarray(static[key]) - np.asarray(dynamic[key]))
        assert np.all(gap.reshape(len(bound), -1).max(axis=1) <= bound), key


@pytest.mark.parametrize("option", [dict(method="semi_implicit"),
                                    dict(mode="transient", duration=1.0, output_interval=0.5),
                                    dict(masses="physical"), dict(precision="float32")],
                         ids=lambda option: "-".join(map(str, option.values())))
def test_what_the_kernels_do_not_run_with_sliding_crossings_is_refused_in_one_line(option):
    """(A transient also names dynamic.mode = "transient", with its duration given.)"""
    name, value = next(iter(option.items()))
    with pytest.raises(UserError, match=rf'^crossings that slide do not run dynamic.{name} = '
                                        rf'"{value}": .* \(docs/model.md 11.13\)$'):
        DynamicSolver(FabricModel.from_scene(patch()), Dynamic(**option))


# ----------------------------------------------------------------------- the kernels


def kernel_case(kind: str):
    """(structure, dofs, anchors, end loads [N], the host's gradient at F_T) of the perturbed
    planar patch or bias specimen, every other crossing sticking (its anchors at its slides
    and, in space, its angle) and the rest sliding."""
    if kind == "planar":
        s = FabricModel.from_scene(patch()).structure
        dofs, anchors, _ = perturbed(s)
        P = loads(s)
    elif kind in ("periodic_cell", "moving_planes"):
        s, dofs, anchors, _ = perturbed_on_a_boundary(kind)
        P = loads(s)
    else:
        s = specimen().structure
        dofs, anchors, _ = spatial_perturbed(s)
        P = np.zeros(s.chain_start.size - 1)
        phi = np.empty(3)
        for c in range(0, s.tie_a.size, 2):  # these stick in rotation too
            six = sliding.physical(dofs, s)[s.tie_stencil[c]]
            sliding.element.crossing_coordinates(six, phi)
            anchors[c, sliding.ROTATION] = phi[2] + 1e-8
    anchors[::2, :2] = dofs.reshape(-1)[s.tie_material[::2]] + 1e-8

    def host_gradient(limit):
        grad = np.zeros_like(dofs)
        sliding.gradient(dofs, s, P, anchors, limit, grad)
        flat, tied = grad.reshape(-1), np.flatnonzero(s.dof_tie >= 0)
        np.add.at(flat, s.dof_tie[tied], flat[tied])  # a tied family: its summed force
        flat[tied] = flat[s.dof_tie[tied]]
        return grad

    return s, dofs, anchors, P, host_gradient


@pytest.mark.parametrize("kind", ["planar", "periodic_cell", "moving_planes", "spatial"])
def test_the_kernels_forces_energy_and_return_map_are_the_sliding_term_sets(kind):
    """The Warp kernels' forces on every free dof (the slides' included: their material force
    -sum_k dV/dL_k dL_k/d delta and the friction lambda H'(S); in space node a's dofs taking
    its crossing's node b's in-plane force; on moving planes the plane nodes taking the force
    on each crossing's node held on its plane, a tied family its summed force; docs/model.md
    11.13a-c), their energy and their return map on the perturbed patch, periodic cell
    (`term_case`), patch with moving planes and bias specimen are the host term set's, evaluated
    with the same F_T (from each crossing's R; the return map finds some sliding, some
    sticking): two evaluations of one formula in float64, apart by the rounding of their sums
    (a few ulps of the largest term)."""
    s, dofs, anchors, P, host_gradient = kernel_case(kind)
    relaxation = StructureRelaxation(s, friction=True)
    force = relaxation.forces(dofs, P, anchors)
    limit = relaxation.tie_forces(dofs, anchors)[2]  # F_T at the kernels' R
    grad = host_gradient(limit) * ~s.fixed.reshape(dofs.shape)
    rounding = 16 * np.finfo(float).eps * np.abs(grad).max()
    np.testing.assert_allclose(force, -grad, rtol=0, atol=rounding)
    assert np.abs(force.reshape(-1)[s.tie_material]).min() > 1e3 * rounding
    nodes, ties = relaxation.energies(dofs, P, anchors)
    host = sliding.energy_vector(s, dofs, P, anchors, limit).sum()
    assert nodes.sum() + ties.sum() == pytest.approx(host, rel=16 * np.finfo(float).eps)
    moved, lost = relaxation.return_map(dofs, anchors)
    expected = np.array(anchors)
    slides = np.zeros(s.tie_a.size, bool)
    expected_lost = sliding.return_map(dofs, expected, s, limit, slides,
                                       np.zeros((slides.size, dofs.shape[1])))
    assert slides.any() and not slides.all()
    np.testing.assert_allclose(moved, expected, rtol=0, atol=16 * np.finfo(float).eps * 1e-3)
    assert lost.sum() == pytest.approx(expected_lost, rel=1e-12)


@pytest.fixture(scope="module")
def patch_steps():
    """patch()'s load step from the as-woven state, by the static solver, and by the dynamic
    one in the grouped and the node-parallel layouts."""
    model = FabricModel.from_scene(patch())
    runs = {"static": StaticSolver(model).step(model.initial_state(), model.step_load(0))}
    for layout in ("grouped", "node_parallel"):
        runs[layout] = DynamicSolver(model, layout=layout).step(model.initial_state(),
                                                                  model.step_load(0))
    return runs


def test_dynamic_relaxation_of_sliding_crossings_meets_the_static_reference(patch_steps):
    """The dynamic solver's step (kinetic damping, the slides' fictitious masses from their
    rows of the stiffest tangent, docs/model.md 11.13) and the static solver's agree within the
    two steps' error bounds (`steps/error_estimate`, a bound on every dof, the slides among
    them): the end displacements, the nodes and each crossing's slide along each yarn."""
    (_, static), (_, dynamic) = patch_steps["static"], patch_steps["grouped"]
    bound = float(static["error_estimate"]) + float(dynamic["error_estimate"])
    assert bound < 0.01 * np.abs(static["end_displacement"]).max()  # a check that can fail
    for name in ("end_displacement", "positions", "weft_positions", "slip"):
        np.testing.assert_allclose(dynamic[name], static[name], rtol=0, atol=bound,
                                   err_msg=name)


def test_the_dynamic_solver_pulls_a_warp_through_its_crossings_as_the_static_one():
    """A straight warp pulled through two crossings that hold their contact forces, to
    extraction, by both solvers: each crossing leaves at the same step (the structure laid out
    again, the retired tail held in the kernels and moved with its end), and the pull (the
    end's reaction, the sum of the forces along the warp) agrees within the residuals' sum
    over the warp's nodes, (nodes + 1) x the two tolerances; 2 F_T, F_T, then 0."""
    runs, tolerances = {}, []
    for name, kind in (("static", StaticSolver), ("dynamic", DynamicSolver)):
        model, F_T = held_pullout(wefts=2, step=2.5e-4, steps=44)
        solver = kind(model)
        runs[name] = solver.run()[1] if kind is StaticSolver else relax_path(solver)
        tolerances.append(solver.tolerance)
    tolerance = (model.warp.segments + 2) * sum(tolerances)
    for static, dynamic in zip(runs["static"], runs["dynamic"], strict=True):
        np.testing.assert_array_equal(dynamic["crossing_present"], static["crossing_present"])
        assert abs(float(dynamic["end_force"][0]) - float(static["end_force"][0])) <= tolerance
    pull = np.array([float(r["end_force"][0]) for r in runs["dynamic"]])
    after = [int(np.sum(r["crossing_present"])) for r in runs["dynamic"]]
    during = np.array([2] + after[:-1])  # the crossings a step ran with
    assert set(during) == {2, 1, 0} and np.all(pull[during == 0] == 0.0)
    assert pull.max() == pytest.approx(2 * F_T, abs=tolerance)


def relax_path(solver):
    """Every load step's record of a dynamic solver's run from the as-woven state."""
    model = solver.model
    state, records = model.initial_state(), []
    for index in range(len(model.load_values)):
        state, record = solver.step(state, model.step_load(index))
        records.append(record)
    return records


@pytest.mark.parametrize("runs", ["patch_steps", "specimen_steps"])
def test_the_node_parallel_layout_slides_the_grouped_layouts_bits(runs, request):
    """The node-parallel layout (a GPU's) takes the grouped layout's step bit for bit where
    the crossings slide (both gather the slides' forces, and in space node a's gather of its
    crossing's node b's in-plane force), on the planar patch and on a bias specimen:
    `--device cuda` changes the layout, not the answer."""
    steps = request.getfixturevalue(runs)
    (grouped, grouped_record), (parallel, parallel_record) = (steps["grouped"],
                                                              steps["node_parallel"])
    np.testing.assert_array_equal(parallel.positions, grouped.positions)
    np.testing.assert_array_equal(parallel.anchors, grouped.anchors)
    for name in grouped_record:
        np.testing.assert_array_equal(parallel_record[name], grouped_record[name], err_msg=name)


# ----------------------------------------------------------------------- a shear specimen

SMALL_BIAS = 'test = "bias_extension"\nwidth = 0.02\nheight = 0.04'


def specimen_text(motion: str, values, friction: str = "", specimen: str = SMALL_BIAS,
                  segments: int = 4) -> str:
    """A bias specimen of tests/test_shear_specimens.py with its crossings' `motion`."""
    from test_shear_specimens import scene_text

    return (scene_text(specimen, values, friction)
            .replace("[crossing]", f'[crossing]\nmotion = "{motion}"')
            .replace("segments_per_spacing = 4", f"segments_per_spacing = {segments}"))


def specimen(motion: str = "sliding", values=(1e-3,)):
    from dynfab.model.fabric.specimen_model import SpecimenModel

    return SpecimenModel(parse_scene_text(specimen_text(motion, list(values))))


@pytest.fixture(scope="module")
def spatial_structure():
    return specimen().structure


def spatial_perturbed(s, seed=0):
    """`perturbed` in space, the rotation anchors off the woven angle by up to 1 mrad."""
    dofs, anchors, limit = perturbed(s, seed)
    rng = np.random.default_rng(seed + 10)
    anchors[:, sliding.ROTATION] += 1e-3 * rng.standard_normal(s.tie_a.size)
    return dofs, anchors, limit


def spatial_energy(s, dofs, anchors, limit):
    P = np.zeros(s.chain_start.size - 1)
    return sliding.SPATIAL.total_energy(dofs, s, P, anchors, limit,
                                        np.zeros(len(sliding.SPATIAL.TERMS)))


def spatial_gradient(s, dofs, anchors, limit):
    grad = np.zeros_like(dofs)
    sliding.SPATIAL.gradient(dofs, s, np.zeros(s.chain_start.size - 1), anchors, limit, grad)
    return grad


def test_a_specimen_as_woven_has_the_fixed_crossings_energies(spatial_structure):
    """A specimen's sliding term set over the spatial one (docs/model.md 11.13): as woven each
    term's energy (the lateral contacts and the rotation springs included) equals the fixed
    crossings' at their rest positions, to rounding (a few ulps of each term)."""
    from dynfab.model.fabric import spatial

    s, fixed = spatial_structure, specimen("fixed").structure
    limit = np.full(fixed.tie_a.size, 0.01)
    P = np.zeros(fixed.chain_start.size - 1)
    dofs = woven_dofs(s)
    anchors = sliding.with_stretches(dofs, s, woven_anchors(s))
    np.testing.assert_allclose(
        sliding.energy_vector(s, dofs, P, anchors, limit),
        spatial.energy_vector(fixed, fixed.rest_position, P, woven_anchors(fixed), limit),
        rtol=1e-12, atol=1e-15)


def test_a_specimens_gradient_and_hessian_are_the_derivatives_of_its_energy(spatial_structure):
    """Central differences on every free dof of a 20 x 40 mm bias specimen, the material
    coordinates and the crossings' rotations (11.13c) included, some crossings sticking,
    some sliding, some open: the gradient with h = 1e-8 m within 1e-6 of its largest
    component, the Hessian's columns with h = 1e-9 m within 1e-6 of its largest entry (the
    planar checks' bounds above: truncation h^2 |V'''| and rounding eps V / h below them)."""
    s = spatial_structure
    dofs, anchors, limit = spatial_perturbed(s)
    grad = spatial_gradient(s, dofs, anchors, limit).ravel()
    free = np.flatnonzero(~s.fixed)

    def shifted(dof, h):
        out = dofs.copy().ravel()
        out[dof] += h
        return out.reshape(dofs.shape)

    h = 1e-8
    fd = np.array([(spatial_energy(s, shifted(d, h), anchors, limit)
                    - spatial_energy(s, shifted(d, -h), anchors, limit)) / (2 * h) for d in free])
    np.testing.assert_allclose(grad[free], fd, rtol=0, atol=1e-6 * np.abs(grad).max())
    H = sliding.full_hessian(s, dofs, anchors, limit)
    scale = np.abs(H[np.ix_(free, free)]).max()
    h = 1e-9
    for dof in free:
        column = (spatial_gradient(s, shifted(dof, h), anchors, limit)
                  - spatial_gradient(s, shifted(dof, -h), anchors, limit)).ravel() / (2 * h)
        np.testing.assert_allclose(H[free, dof], column[free], rtol=0, atol=1e-6 * scale)


def test_a_rigid_in_plane_motion_of_a_specimen_moves_no_material_and_costs_no_energy(
        spatial_structure):
    """Every physical coordinate turned by 0.3 rad about e_z and moved by (1, 2, 3) mm: the
    material coordinates stay (their slots hold no position), and no term's energy changes
    (the rotation's anchor is an angle between the yarns), to rounding (1e-9 of each term,
    1e-12 of their sum)."""
    s = spatial_structure
    dofs, anchors, limit = spatial_perturbed(s, seed=2)
    c, sn = np.cos(0.3), np.sin(0.3)
    moved = dofs @ np.array([[c, sn, 0.0], [-sn, c, 0.0], [0.0, 0.0, 1.0]]) + [1e-3, 2e-3, 3e-3]
    material = s.tie_material.ravel()
    moved.reshape(-1)[material] = dofs.reshape(-1)[material]
    P = np.zeros(s.chain_start.size - 1)
    before = sliding.energy_vector(s, dofs, P, anchors, limit)
    after = sliding.energy_vector(s, moved, P, anchors, limit)
    np.testing.assert_allclose(after, before, rtol=1e-9, atol=1e-12 * np.abs(before).sum())


@pytest.fixture(scope="module")
def specimen_steps():
    """A bias specimen's first step (its relaxation as woven, the clamps at rest), by the
    static solver and by the dynamic one in the grouped and the node-parallel layouts."""
    model = specimen(values=(5e-4,))
    runs = {"static": StaticSolver(model).step(model.initial_state(), model.step_load(0))}
    for layout in ("grouped", "node_parallel"):
        runs[layout] = DynamicSolver(model, layout=layout).step(model.initial_state(),
                                                                  model.step_load(0))
    return runs


def test_dynamic_relaxation_of_a_specimens_sliding_crossings_meets_the_static_reference(
        specimen_steps):
    """The dynamic solver's step on a bias specimen whose crossings slide (node b at node a's
    x and y, its dofs the slides; docs/model.md 11.13) and the static solver's agree within
    the two steps' error bounds (`steps/error_estimate`, a bound on every dof, the slides
    among them): the nodes, the crossings' positions and each crossing's slide along each
    yarn (the largest 13 um, the bound 3e-8 m)."""
    (_, static), (_, dynamic) = specimen_steps["static"], specimen_steps["grouped"]
    bound = float(static["error_estimate"]) + float(dynamic["error_estimate"])
    for name in ("positions", "crossing_positions", "slip"):
        np.testing.assert_allclose(dynamic[name], static[name], rtol=0, atol=bound,
                                   err_msg=name)
    assert np.abs(static["slip"]).max() > 10 * bound


def test_a_held_bias_specimen_slides_within_the_fixed_crossings_mesh_error():
    """tests/test_shear_specimens.py's bias specimen held together (`HOLDING_FRICTION`) to
    d = 4 mm: its crossings slide by about 0.1 um, far below half a segment, where fixed
    crossings model the same fabric, so sliding must give their clamp force within the
    fixed model's own error, its change from 4 to 8 segments per spacing (the solvers'
    error bounds are 1e-8 of it). Measured: 2e-4 N against 3e-3 N at 4 mm."""
    from test_shear_specimens import BIAS, HOLDING_FRICTION

    d = [2e-3, 4e-3]

    def clamp_forces(motion, segments=4):
        text = specimen_text(motion, d, HOLDING_FRICTION, BIAS, segments)
        return np.asarray(run(parse_scene_text(text), solver="static").steps["clamp_force"])

    fixed, moving, finer = clamp_forces("fixed"), clamp_forces("sliding"), clamp_forces("fixed", 8)
    assert np.all(np.abs(moving - fixed)[1:] <= np.abs(finer - fixed)[1:])


def bias_slides_out() -> str:
    """A 40 x 80 mm bias specimen with the paper's friction and the rotation springs of
    tests/test_shear_specimens.py: at its free edges the springs' couples need more in-plane
    force than the crossings' friction limits, and its edge yarns slide out of the fabric."""
    return specimen_text("sliding", list(np.round(np.arange(1, 9) * 0.5e-3, 6)),
                         specimen='test = "bias_extension"\nwidth = 0.04\nheight = 0.08')


def test_a_specimens_edge_yarns_slide_out_and_a_resumed_run_repeats_it(tmp_path):
    """The edge yarns of `bias_slides_out` leave their crossings (docs/model.md 11.13): the
    first crossings to go are each a yarn's last before a free end (rank 1 of
    `woven_rest.crossings_from_free_end`), and the path goes on past them. A run stopped
    two steps after the first departure and resumed writes the uninterrupted run's steps
    exactly (the departures replayed from the file)."""
    from dynfab.results.file import read_results

    scene = parse_scene_text(bias_slides_out())
    whole, part = tmp_path / "whole.h5", tmp_path / "part.h5"
    run_to_file(scene, "static", whole)
    results = read_results(whole)
    present = np.asarray(results.steps["crossing_present"], bool)
    first = int(np.argmax(~present.all(axis=1)))
    assert 0 < first < len(scene.load.values) - 2
    rank = np.asarray(results.reference["free_end_rank"])
    assert np.all(rank[~present[first]] == 1)
    run_interrupted(scene, "static", part, steps=first + 2)
    run_to_file(scene, "static", part, resume=True)
    assert_same_steps(whole, part)


def test_a_failed_step_of_sliding_crossings_is_made_of_halves(monkeypatch):
    """Where Newton fails on a step of sliding crossings, the step is solved in halves
    (`dynfab.solvers.contract.SLIDING_HALVINGS`): with Newton made to fail on any increment
    above 0.3 mm, a step from 0 to 1 mm is solved as 0.25, 0.5, 0.75 and 1 mm, and ends
    where the path of those four steps ends, to the bit."""
    from dynfab.errors import SolverError
    from dynfab.solvers.newton_sparse import SparseNewton

    solve, reached = SparseNewton.solve, [0.0]

    def short_steps_only(self, start):
        d = float(start.load[0])
        if d - reached[0] > 0.3e-3 + 1e-12:
            raise SolverError("a step too long")
        solution = solve(self, start)
        reached[0] = d
        return solution

    monkeypatch.setattr(SparseNewton, "solve", short_steps_only)
    state, records = StaticSolver(specimen(values=[1e-3])).run()
    reached[0] = 0.0
    stepped, _ = StaticSolver(specimen(values=[0.25e-3, 0.5e-3, 0.75e-3, 1e-3])).run()
    assert float(records[-1]["load"][0]) == 1e-3
    np.testing.assert_array_equal(state.positions, stepped.positions)
    assert state.dissipated == stepped.dissipated


def test_a_first_step_of_sliding_crossings_can_be_made_of_halves(monkeypatch):
    """The as-woven state is at zero load, so a failing first step is halved too
    (`dynfab.solvers.contract.step_in_halves`): with Newton made to fail on any increment of
    the end force above 6 mN, patch()'s step from 0 to 10 mN is solved as 5 and 10 mN and
    ends where that two-step path ends, to the bit."""
    from dynfab.errors import SolverError
    from dynfab.solvers.newton_sparse import SparseNewton

    solve, reached = SparseNewton.solve, [0.0]

    def short_steps_only(self, start):
        force = float(np.max(start.load))
        if force - reached[0] > 6e-3:
            raise SolverError("a step too long")
        solution = solve(self, start)
        reached[0] = force
        return solution

    monkeypatch.setattr(SparseNewton, "solve", short_steps_only)
    state, records = StaticSolver(FabricModel.from_scene(patch())).run()
    reached[0] = 0.0
    two = fabric_scene(WARP, WEFT, 3, 3, friction=FRICTION,
                       crossing=dict(preload=0.01, motion="sliding"),
                       load=dict(control="force", values=[0.005, 0.01]))
    stepped, _ = StaticSolver(FabricModel.from_scene(two)).run()
    assert len(records) == 1
    np.testing.assert_array_equal(state.positions, stepped.positions)
    assert state.dissipated == stepped.dissipated


def test_a_departure_keeps_every_segments_rest_length(spatial_structure):
    """docs/model.md 11.13: taking a crossing out merges the bays on its other chain and
    retires the leaving chain's tail, every segment keeping the rest length it has (the
    material does not jump); two departures on different chains one after the other, at
    slides of up to 0.1 mm, each keep every segment's rest length to rounding (1e-12 of a
    segment), the first's retired tail and new end included."""
    from dynfab.model.builders.sliding import Departure, without_crossings

    s = spatial_structure
    rng = np.random.default_rng(3)
    dofs = woven_dofs(s)
    dofs.reshape(-1)[s.tie_material.ravel()] = 1e-4 * rng.uniform(-1, 1, s.tie_material.size)
    before = sliding.rest_lengths(dofs, s)
    chain = chain_of_node(s)  # the nodes keep their chains
    left = []
    for _ in range(2):  # a crossing's warp leaves it at its first end, then another warp's
        tie = int(np.flatnonzero(~np.isin(chain[s.tie_a], left))[0])
        left.append(int(chain[s.tie_a[tie]]))
        s, dofs = without_crossings(s, [Departure(tie, left[-1], 0)], dofs)
        np.testing.assert_allclose(sliding.rest_lengths(dofs, s), before, rtol=0,
                                   atol=1e-12 * before.max())
