"""The fabric's moving planes, periodic wrap and tied cell length in the Warp kernels
(docs/model.md section 10), and the dynamic solver against the static one on every fabric
scene in runs/.

1. Kernel forces against the static solver's numba gradient (`dynfab.fabric.assembly`,
   itself checked against finite differences in tests/test_fabric_terms.py) at perturbed
   positions, with crossings sliding and sticking: "affine" planes on a clamped patch and
   the periodic cell under force control (tied cell lengths), to rounding.
2. Every fabric scene of runs/ (`dynfab run runs/<scene>.toml --solver dynamic`, with
   `--method explicit` and `semi_implicit`): the dynamic run over the first load steps of
   the scene's own path, each step compared with the static solver's step from the same
   state (positions, anchors), within the bound their residual tolerances allow
   (`agreement_bound` of tests/test_fabric_dynamic.py).

Kernel variants: float64 with friction compiled in, the passes and the persistent kinetic
kernel tests/test_fabric_kernels.py and tests/test_fabric_dynamic.py build (the plane mode
is data, not a variant), plus the per-step layout's kernels those tests build too, and the
semi-implicit kernels tests/test_fabric_semi_implicit.py builds.
"""

from pathlib import Path

import numpy as np
import pytest
import warp as wp

from dynfab.fabric import assembly
from dynfab.fabric.dynamic import FabricDynamicSolver
from dynfab.fabric.model import FabricModel
from dynfab.static import StaticSolver
from dynfab.kernels import fabric_explicit, fabric_forces, status
from dynfab.scene import load_scene
from dynfab.structure import uniform
from independent import PAPER_FRICTION, scene_with
from test_fabric_dynamic import agreement_bound, anchor_bound, paper_patch_model
from test_fabric_scenes import run_interrupted

EPS = np.finfo(float).eps
RUNS = Path(__file__).resolve().parent.parent / "runs"
LOADS = (0.2, 0.1)
"""(warp, weft) end force per yarn [N] of the kernel comparisons."""


def perturbed_state(solver: StaticSolver, seed=3, size=2e-5):
    """As-woven positions moved by up to `size` [m] in every free coordinate, a tied family's
    end nodes by one common amount (they are one dof), the held ones as woven."""
    f = solver.model.structure
    rng = np.random.default_rng(seed)
    move = rng.uniform(-size, size, f.rest_position.size)
    move[f.fixed] = 0.0
    tied = f.dof_tie >= 0
    move[tied] = move[f.dof_tie[tied]]
    return f.rest_position + move.reshape(-1, 2)


def mixed_anchors(solver, pos):
    """Static-convention anchors leaving the even crossings sliding (the slip 1e-5 m, about
    100 F_T / k_t at the paper's k_t) and the odd ones sticking (slip 1e-9 m along x, k_t |s|
    about 1e-5 N below F_T wherever a contact is closed)."""
    f = solver.model.structure
    px, py = assembly.planes(pos, f)
    current = np.stack([pos[f.tie_a, 0] - px, pos[f.tie_b, 0] - py], axis=1)
    anchors = current - 1e-9 * np.array([1.0, 0.0])
    anchors[::2] = current[::2] + np.array([1e-5, -1e-5])
    return anchors


def kernel_forces(dynamic: FabricDynamicSolver, pos, P, anchors):
    """(force (n, 2) [N] on the free dofs, friction forces (C, 2) [N]): the kernels' two
    passes with the solver's own fabric and masks."""
    a = dynamic.arrays
    passes = fabric_forces.kernels(wp.float64, True)
    vectors = lambda values: wp.array(np.asarray(values, float), dtype=wp.vec2d)  # noqa: E731
    pos_wp = vectors(pos)
    contact = wp.zeros(a.crossings, dtype=wp.float64)
    friction = wp.zeros(a.crossings, dtype=wp.vec2d)
    force = wp.zeros(a.nodes, dtype=wp.vec2d)
    wp.launch(passes.crossing_pass, dim=a.crossings,
              inputs=[pos_wp, dynamic.relaxation.fabric, vectors(anchors + dynamic._plane_shift),
                      contact, friction])
    wp.launch(passes.node_pass, dim=a.nodes,
              inputs=[pos_wp, dynamic.relaxation.fabric, contact, friction,
                      vectors(dynamic.external_force(P)), force])
    return force.numpy(), friction.numpy()


def term_scale(static, pos, P, anchors, limit) -> float:
    """S = sum over the terms of each term's largest gradient component [N]: stretch,
    bending (and the wrap), contact, friction (with the planes' reaction), the load."""
    f = static.model.structure
    without = [f._replace(stretch_stiffness=0 * f.stretch_stiffness),
               f._replace(bend_stiffness=0 * f.bend_stiffness, wrap_stiffness=0 * f.wrap_stiffness),
               f._replace(tie_gap_offset=f.tie_gap_offset - 1.0), f._replace(has_friction=False)]
    full = np.zeros_like(pos)
    assembly.gradient(pos, f, P, anchors, limit, full)
    scale = np.abs(P).max()
    for fabric in without:
        grad = np.zeros_like(pos)
        assembly.gradient(pos, fabric, P, anchors, limit, grad)
        scale += np.abs(full - grad).max()
    return scale


GEOMETRY = {"affine": dict(planes="affine"), "periodic": dict(boundary="periodic")}


@pytest.mark.parametrize("case", sorted(GEOMETRY))
def test_moving_plane_forces_are_the_numba_gradient(case):
    """The kernels' force on every unknown equals -dV/dr of `assembly.gradient` (F_T frozen at
    the law of the current contact forces), reduced to the unknowns (a tied cell length
    carries its family's summed end force, `Pattern.reduce`), to rounding.

    Rounding: a force component sums at most about 16 contributions (two segments, four
    bending springs with the wrap, a contact, a friction force, the planes' reaction over
    the C <= 6 crossings, two tied ends), each within 8 ulps of its size <= S (`term_scale`),
    so the two evaluations differ by at most 2 x 16 x 8 eps S = 256 eps S. Not vacuous: the
    planes' reaction on the end nodes and the wrap springs' forces are far above the bound,
    so leaving either out fails."""
    model = paper_patch_model(2, 2 if case == "periodic" else 3, [LOADS], friction=PAPER_FRICTION,
                              **GEOMETRY[case])
    static, dynamic = StaticSolver(model), FabricDynamicSolver(model)
    f = static.model.structure
    pos = perturbed_state(static)
    anchors = mixed_anchors(static, pos)
    limit = static.backend.friction_limits(pos)
    assert (limit > 0).any()  # closed crossings: friction acts
    P = model.yarn_loads(*LOADS)
    grad = np.zeros_like(pos)
    assembly.gradient(pos, f, P, anchors, limit, grad)
    pattern = static.backend.pattern
    expected = -pattern.expand(pattern.reduce(grad)).reshape(pos.shape)
    force, friction = kernel_forces(dynamic, pos, P, anchors)
    bound = 256 * EPS * term_scale(static, pos, P, anchors, limit)
    assert np.abs(force - expected).max() <= bound, (np.abs(force - expected).max(), bound)
    drag = np.hypot(*friction.T)
    assert (drag[::2] > 0).any() and (drag[1::2] > 0).any()  # sliding and sticking crossings
    weights = dynamic.arrays.crossing_plane_weight
    reaction = np.abs((weights * friction).sum(axis=0)).min()  # each family's planes' reaction
    assert reaction > 1e6 * bound
    if case == "periodic":
        wrap = np.zeros_like(pos)
        assembly._add_wrap_gradient(pos, f, 0, wrap)  # warp 0's wrap spring
        assert np.abs(wrap).max() > 1e6 * bound
        tied = dynamic.arrays.node_tie >= 0
        assert tied.sum() == model.warps + model.wefts  # every end in one of the two cell lengths


@pytest.mark.parametrize("damping", ["viscous", "kinetic"])
def test_tied_cell_lengths_move_as_one_in_both_layouts(damping):
    """The periodic cell under force control, with friction: each family's end nodes keep
    one in-plane coordinate (one dof: the same force and mass on each, so the same bits) in
    the persistent layout (scatter and gather orders) and the per-step layout, which agree
    bit for bit in the gather order (the per-step layout's sums in the same order)."""
    model = paper_patch_model(2, 2, [LOADS], friction=PAPER_FRICTION, boundary="periodic")
    dynamic = FabricDynamicSolver(model)
    arrays = dynamic.arrays
    external = dynamic.external_force(dynamic.model.yarn_loads(*LOADS))
    anchors = dynamic.initial_state().anchors + dynamic._plane_shift
    runs = {}
    for layout, order in (("persistent", "scatter"), ("persistent", "gather"), ("per_step", "gather")):
        solver = fabric_explicit.FabricExplicit(arrays, layout=layout, damping=damping,
                                                coefficient=0.05, order=order, friction=True)
        positions, outcome = solver.relax(arrays.rest_position, external, 0.0, 400, anchors)
        assert outcome.status == status.MAX_STEPS
        for family in (0, 1):
            ends = positions[arrays.node_tie == family, 0]
            assert np.all(ends == ends[0])
        runs[layout, order] = positions
    assert np.abs(runs["persistent", "scatter"] - arrays.rest_position).max() > 1e-5  # it moved
    assert np.array_equal(runs["persistent", "gather"], runs["per_step", "gather"])


# --- 2. every fabric scene of runs/ ---

SCENES = {"fabric_biaxial": 2, "fabric_biaxial_2to1": 2, "fabric_biaxial_1to2": 2,
          "fabric_strip": 1, "fabric_pullout": 2}
"""Scene -> load steps compared. The load paths are truncated (CI time): every step of a
scene runs the same code (the static solver's start, one relaxation, the certificate and the
return map), so the first steps exercise every term the scene has. Two for the biaxial cells
(2 x 2, under a second each); one for the 16 x 16 strip (7,200 nodes: its first relaxation
takes about 16,000 time steps, several seconds, and its ||J^-1|| a dense inverse of 14,000
unknowns, too slow: see `scene_model`); two for the pull-out, its steps 2 and 3: the end of
the first stage (the wefts tensioned, pressing the crossings) reached in one step, then the
first pull of the warp, where the crossings on it slide (`scene_model`)."""


def scene_model(name: str, steps: int | None = None) -> FabricModel:
    """The scene's model at static.tolerance = TOLERANCE, its load path cut to `steps` steps
    (default SCENES[name]; the pull-out's from its step 2). The strip is
    the same scene on a 4 x 4 patch of the same yarns (pitch, segment length, planes
    "affine", friction, loads per yarn), as tests/test_fabric_scenes.py runs it: the
    bound needs ||J^-1|| by a dense inverse."""
    scene = load_scene(RUNS / f"{name}.toml")
    steps = SCENES[name] if steps is None else steps
    first = 1 if name == "fabric_pullout" else 0  # the pull-out from its step 2
    path = FabricModel.from_scene(scene).load_values[first:first + steps]
    tables = {"static": {"tolerance": TOLERANCE},
              "load": {"values": tuple(map(float, path[:, 0])),
                       "weft_values": tuple(map(float, path[:, 1]))}}
    if name == "fabric_strip":
        g, weft = scene.geometry, scene.weft
        pitch_wa, pitch_we = g.length / g.crossings, weft.length / weft.count
        per_wa, per_we = g.segments // g.crossings, weft.segments // weft.count
        tables["geometry"] = {"crossings": 4, "length": 4 * pitch_wa, "segments": 4 * per_wa}
        tables["weft"] = {"count": 4, "length": 4 * pitch_we, "segments": 4 * per_we}
    return FabricModel.from_scene(scene_with(scene, **tables))


TOLERANCE = 1e-10
"""Residual tolerance [N] of both solvers (as tests/test_fabric_dynamic.py: above the static
residual's rounding floor on these yarns, about 1e-11 N at k_c = 1e5 N/m)."""


@pytest.mark.parametrize("method", ["explicit", "semi_implicit"])
@pytest.mark.parametrize("name", sorted(SCENES))
def test_every_fabric_scene_agrees_with_the_static_solver(name, method):
    """Each step of the dynamic run (explicit with kinetic damping, semi-implicit) against the
    static solver's step from the same state:
    positions within `agreement_bound` (||J^-1|| (r_static + r_dynamic); the same anchors
    held), contact forces within 2 k_c times it, the same open/closed and sliding patterns
    and stability, the return-mapped anchors within `anchor_bound`, the step moving the
    fabric far beyond the bound.

    Why from the same state rather than two independent runs (tests/test_fabric_dynamic.py):
    two runs' anchors differ after a return map by ~1e-11 m, which `agreement_bound` charges
    at the stick stiffness (k_t ~ 3e4 N/m on the pull-out) through the worst direction of
    J^-1 (17 m/N there): a bound of 1e-5 m against a pull of 2e-4 m, where the positions
    differ by 2e-10 m. Started from one state, the steps share their anchors, and the anchors'
    agreement after the return map is checked instead."""
    model = scene_model(name)
    static, dynamic = StaticSolver(model), FabricDynamicSolver(model, method=method)
    state = dynamic.initial_state()
    k_c = uniform(static.model.structure.tie_contact_law)[0]
    for warp_value, weft_value in model.load_values:
        start = state.copy()
        s_state, s_record = static.step(start.copy(), (warp_value, weft_value))
        state, d_record = dynamic.step(start, (warp_value, weft_value))
        assert d_record["residual"] <= TOLERANCE
        bound = agreement_bound(static, s_state, start.anchors, s_record, d_record["residual"], 0.0)
        assert np.abs(s_state.positions - start.positions).max() > 1e3 * bound
        error = np.abs(state.positions - s_state.positions).max()
        assert error <= bound, (error, bound)
        closed = s_record["contact_force"] > 0
        assert np.abs(d_record["contact_force"] - s_record["contact_force"]).max() <= 2 * k_c * bound
        assert np.array_equal(d_record["contact_force"] > 0, closed)
        assert np.array_equal(d_record["sliding"], s_record["sliding"])
        assert d_record["stable"] == s_record["stable"]
        if s_record["sliding"].any():
            gap = np.abs(state.anchors - s_state.anchors).max()
            assert gap <= anchor_bound(static, s_record, bound), gap


@pytest.mark.parametrize("damping, layout", [("fire", "persistent"), ("kinetic", "per_step")])
@pytest.mark.parametrize("name", ["fabric_biaxial_2to1", "fabric_strip"])
def test_the_other_dampings_and_layouts_reach_the_same_step(name, damping, layout):
    """FIRE (persistent layout) and kinetic damping in the per-step layout on the periodic
    cell and the affine strip (4 x 4 copy): the first step within `agreement_bound` of the
    static solver's, as the default configuration in
    `test_every_fabric_scene_agrees_with_the_static_solver`."""
    model = scene_model(name, steps=1)
    static = StaticSolver(model)
    dynamic = FabricDynamicSolver(model, damping=damping, layout=layout)
    start = dynamic.initial_state()
    load = tuple(model.load_values[0])
    s_state, s_record = static.step(start.copy(), load)
    state, d_record = dynamic.step(start, load)
    bound = agreement_bound(static, s_state, start.anchors, s_record, d_record["residual"], 0.0)
    assert np.abs(s_state.positions - start.positions).max() > 1e3 * bound
    assert np.abs(state.positions - s_state.positions).max() <= bound


@pytest.mark.parametrize("method", ["explicit", "semi_implicit"])
def test_a_resumed_dynamic_run_of_the_periodic_cell_repeats_the_uninterrupted_one(tmp_path,
                                                                                  method):
    """`--solver dynamic --resume` on the periodic cell (tied cell lengths, moving planes),
    with each dynamic method: a run stopped after 4 steps and resumed writes the same bits as
    the run done in one go, every steps/ dataset but the wall time (each step relaxes from the
    stored positions and anchors, at rest, in a fixed order of sums: docs/model.md section
    10's determinism)."""
    import h5py

    from dynfab.run import run_to_file
    from dynfab.scene import parse_scene_text

    text = (RUNS / "fabric_biaxial_1to2.toml").read_text()
    scene = parse_scene_text(text + f'\n[dynamic]\nmethod = "{method}"\n')
    whole, part = tmp_path / "whole.h5", tmp_path / "part.h5"
    run_to_file(scene, "dynamic", whole)
    run_interrupted(scene, "dynamic", part)
    assert run_to_file(scene, "dynamic", part, resume=True) == 6
    with h5py.File(whole, "r") as a, h5py.File(part, "r") as b:
        assert a.attrs["solver"] == "dynamic" and a.attrs["dynamic_method"] == method
        compared = 0
        for name, dataset in a["steps"].items():
            if isinstance(dataset, h5py.Dataset) and name not in ("wall_time", "relax_time"):
                np.testing.assert_array_equal(dataset[:], b["steps"][name][:], err_msg=name)
                compared += 1
        assert compared > 20 and "warp_planes" in a["steps"]


@pytest.mark.parametrize("boundary, planes", [("periodic", "fixed"), ("clamped", "affine")])
def test_displacement_control_moves_the_planes_with_the_prescribed_ends(boundary, planes):
    """Under displacement control the cell lengths (periodic) or the loaded ends (affine
    planes) are prescribed and the planes move with them: each step of the dynamic run
    against the static step from the same state, positions within `agreement_bound` and the
    end reactions (which carry the planes' friction reaction) within the bound times the end
    dof's stiffness row sum, as tests/test_fabric_dynamic.py bounds them."""
    from dynfab.kernels.fabric_arrays import gershgorin_masses

    values = ((2e-4, 5e-5), (6e-4, 2e-4))
    n = 2 if boundary == "periodic" else 4
    model = paper_patch_model(n, n, values, "displacement", PAPER_FRICTION, boundary=boundary,
                              planes=planes, tolerance=TOLERANCE)
    static, dynamic = StaticSolver(model), FabricDynamicSolver(model)
    state = dynamic.initial_state()
    f = static.model.structure
    for warp_value, weft_value in values:
        start = state.copy()
        s_state, s_record = static.step(start.copy(), (warp_value, weft_value))
        state, d_record = dynamic.step(start, (warp_value, weft_value))
        bound = agreement_bound(static, s_state, start.anchors, s_record, d_record["residual"], 0.0)
        assert np.abs(s_state.positions - start.positions).max() > 1e3 * bound
        assert np.abs(state.positions - s_state.positions).max() <= bound
        px, py = assembly.planes(state.positions, f)
        assert np.abs(px - f.tie_plane[:, 0]).min() > 1e3 * bound  # the planes moved
        rows = gershgorin_masses(dynamic.arrays, 2.0, 1.0)[f.load_node]
        row = rows + np.abs(s_record["end_force"]) / dynamic.arrays.rest_length[f.load_node - 1]
        difference = np.abs(d_record["end_force"] - s_record["end_force"])
        assert (difference <= row * bound).all(), (difference, row * bound)
        assert np.abs(s_record["end_force"]).max() > 1e3 * (row * bound).max()
