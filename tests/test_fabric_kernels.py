"""The fabric's Warp kernels (docs/model.md section 10): forces against finite differences of the
Warp energy, bit-for-bit repeatable runs in both layouts, and a patch with its wefts held against
the one-yarn static reference.

One kernel configuration (float64, friction compiled in; a patch without friction has
F_T = k_t = 0) is built: the force and energy passes, the per-step node kernel and its
kinetic-damping kernels, and the persistent kernel (viscous and kinetic in both force
orders, FIRE).
"""

import math
from dataclasses import replace

import numpy as np
import pytest
import warp as wp

from dynfab import assembly
from dynfab.banded import zeros_band
from dynfab.fabric.model import FabricModel
from dynfab.kernels import fabric_arrays, fabric_explicit, fabric_forces, status
from dynfab.model import build_model, initial_state
from dynfab.reports.fabric_data import paper_patch_scene
from dynfab.static import StaticSolver
from independent import PAPER_FRICTION, dense, make_scene

EPS = np.finfo(float).eps
SCALAR = wp.float64
K_C = 1e5
"""The core stiffness k_c [N/m] of the patch (a fabric's default)."""


def patch_model(friction=None) -> FabricModel:
    """2 warps x 3 wefts of the paper's yarn, 8 segments per half-wave (N = 24, M = 16);
    `friction` a [friction] table (the paper's: `independent.PAPER_FRICTION`, R_0 = 1e-5 N)
    or None. Its [load] is never read: the kernels take the external force."""
    tables = {} if friction is None else {"friction": friction}
    return FabricModel.from_scene(paper_patch_scene(
        2, 3, load={"control": "force", "values": [0.3]}, contact={"core_stiffness": K_C},
        **tables))


PATCH = patch_model()
"""The patch without friction."""


@pytest.fixture(scope="module")
def arrays():
    return fabric_arrays.build(PATCH.structure)


def perturbed(arrays, seed=1, size=2e-5):
    """As-woven positions moved by up to `size` [m] in every coordinate, every dof free."""
    rng = np.random.default_rng(seed)
    return arrays.rest_position + rng.uniform(-size, size, arrays.rest_position.shape)


def forces_and_energy(arrays, positions, external, anchors=None):
    """(force (n, 2) [N], energy [J]) from the Warp kernels (forces: the two passes)."""
    passes = fabric_forces.kernels(SCALAR, True)
    fabric = fabric_arrays.upload(arrays, SCALAR, "cpu")
    pos = wp.array(positions, dtype=wp.vec2d)
    load = wp.array(external, dtype=wp.vec2d)
    held = wp.array(anchors if anchors is not None else np.zeros((arrays.crossings, 2)), dtype=wp.vec2d)
    contact = wp.zeros(arrays.crossings, dtype=wp.float64)
    friction = wp.zeros(arrays.crossings, dtype=wp.vec2d)
    force = wp.zeros(arrays.nodes, dtype=wp.vec2d)
    wp.launch(passes.crossing_pass, dim=arrays.crossings, inputs=[pos, fabric, held, contact, friction])
    wp.launch(passes.node_pass, dim=arrays.nodes, inputs=[pos, fabric, contact, friction, load, force])
    node_energy = wp.zeros(arrays.nodes, dtype=wp.float64)
    crossing_energy = wp.zeros(arrays.crossings, dtype=wp.float64)
    wp.launch(passes.energy_pass, dim=arrays.nodes,
              inputs=[pos, fabric, held, load, node_energy, crossing_energy])
    terms = np.concatenate([node_energy.numpy(), crossing_energy.numpy()])
    return force.numpy(), math.fsum(terms), math.fsum(np.abs(terms))


def only(arrays, term):
    """The patch with one term: the others' stiffnesses zeroed, contacts opened by a large
    negative offset (g < 0 at every crossing), friction off (F_T = k_t = 0) but in
    "friction" (which keeps the contact, F_T needs R), whose k_t is 10 N/m: the slips of
    the perturbation then stick, 1e-4 m or more from the Huber kink. Every dof free."""
    open_offset = np.full(arrays.crossings, -1.0)
    zero = np.zeros(arrays.nodes)
    keep = {"stretch": dict(bend_stiffness=zero, crossing_offset=open_offset),
            "bending": dict(stretch_stiffness=zero, crossing_offset=open_offset),
            "contact": dict(stretch_stiffness=zero, bend_stiffness=zero),
            "friction": dict(stretch_stiffness=zero, bend_stiffness=zero,
                             friction_law=np.r_[fabric_arrays.build(patch_model(
                                 PAPER_FRICTION).structure).friction_law[:3], 10.0]),
            "all": {}}[term]
    if term != "friction":
        keep["friction_law"] = np.zeros(4)
    return replace(arrays, free=np.ones_like(arrays.free), **keep)


def friction_anchors(arrays, positions):
    """Anchors (C, 2) [m] that leave every other crossing sliding: xi = 1e-3 m along -s, far
    beyond F_T / k_t (about 2e-4 m at k_t = 10 N/m, F_T about 2e-3 N), and the others at
    the as-woven planes."""
    anchors = np.zeros((arrays.crossings, 2))
    anchors[::2] = -1e-3
    return anchors


@pytest.mark.parametrize("term", ["stretch", "bending", "contact", "friction", "all"])
def test_forces_are_minus_the_energy_gradient(arrays, term):
    """-dE/dr by central differences of the Warp energy against the Warp force, every dof.

    The central difference at step h errs by its truncation, O(h^2 E'''), plus rounding:
    each energy term is evaluated to a few ulps (lengths, atan2, exponentials; 8 taken),
    so the difference of two energies over 2h errs by up to 8 eps sum|E_terms| / h. The
    truncation at h is a third of |D(2h) - D(h)| (it scales as h^2), so the force must lie
    within |D(2h) - D(h)| + 8 eps sum|E| / h of D(h): a wrong force misses that by its own
    error. Closures are kept 10 h away from the
    contact's kink at g = 0 (the perturbation closes about half the crossings).
    Friction is the derivative of its Huber term with F_T frozen (docs/model.md section 4): checked
    along the in-plane dofs of the crossing nodes, on which R, hence F_T, does not depend."""
    patch = only(arrays, term)
    positions = perturbed(arrays)
    external = 0.3 * (arrays.load_direction + arrays.weft_load_direction)
    h = 1e-7
    g = arrays.crossing_offset - arrays.crossing_side * (
        positions[arrays.crossing_warp, 1] - positions[arrays.crossing_weft, 1])
    assert np.abs(g).min() > 10 * h and (g > 0).any() and (g < 0).any()
    anchors = friction_anchors(arrays, positions)
    force, _, scale = forces_and_energy(patch, positions, external, anchors)

    def difference(i, c, step):
        values, coordinates = [], []
        for sign in (1.0, -1.0):
            moved = positions.copy()
            moved[i, c] += sign * step  # the coordinate actually reached, not x +- step
            coordinates.append(moved[i, c])
            values.append(forces_and_energy(patch, moved, external, anchors)[1])
        return -(values[0] - values[1]) / (coordinates[0] - coordinates[1])

    rng = np.random.default_rng(2)
    nodes = rng.choice(arrays.nodes, 24, replace=False).tolist() + list(arrays.crossing_warp[:2])
    components = (0, 1)
    if term == "friction":
        nodes, components = list(arrays.crossing_warp) + list(arrays.crossing_weft), (0,)
    for i in nodes:
        for c in components:
            at_h, at_2h = difference(i, c, h), difference(i, c, 2 * h)
            bound = abs(at_2h - at_h) + 8 * EPS * scale / h
            assert abs(force[i, c] - at_h) <= bound, (term, i, c, force[i, c], at_h, bound)
    assert np.abs(force).max() > 1e3 * 8 * EPS * scale / h  # the check is not vacuous
    if term == "friction":  # friction acts at sliding (even) and sticking (odd) crossings
        drag = np.abs(force[arrays.crossing_warp, 0]) + np.abs(force[arrays.crossing_weft, 0])
        assert (drag[::2] > 1e-4).any() and (drag[1::2] > 1e-5).any()


def test_runs_are_bit_identical_in_both_layouts():
    """With the paper's friction, two runs of each layout give the same bits after the same
    steps (no atomics: every force is the same sum in the same order whatever the
    schedule); the persistent layout
    in the per-step layout's gather order gives exactly its bits, and in its own scatter
    order the same motion up to the rounding of the sums' order: within 1e-12 m, a
    millionth of the motion (about 6e-4 m), where an error in a term would change the
    motion at the term's own relative size (measured: 2e-17 m, a few ulps of 0.01 m)."""
    arrays = fabric_arrays.build(patch_model(PAPER_FRICTION).structure)
    external = 0.3 * (arrays.load_direction + arrays.weft_load_direction)
    results = {}
    for layout, order in (("persistent", "scatter"), ("persistent", "gather"), ("per_step", "gather")):
        for repeat in range(2):
            solver = fabric_explicit.FabricExplicit(arrays, layout=layout, damping="viscous",
                                                    coefficient=0.05, order=order, friction=True)
            positions, outcome = solver.relax(arrays.rest_position, external, 0.0, 300)
            assert outcome.status == status.MAX_STEPS and outcome.steps == 300
            if repeat:
                assert np.array_equal(positions, results[layout, order])
            results[layout, order] = positions
    scattered = results["persistent", "scatter"]
    assert np.abs(scattered - arrays.rest_position).max() > 1e-4  # the patch moved
    assert np.array_equal(results["persistent", "gather"], results["per_step", "gather"])
    assert np.abs(scattered - results["per_step", "gather"]).max() <= 1e-12


def test_kinetic_damping_in_the_per_step_layout_repeats_the_persistent_loop():
    """Kinetic damping in the per-step layout (the energy summed per block of nodes, then
    over blocks, in a fixed order) is repeatable bit for bit and, with one block (this
    patch has 101 nodes < ENERGY_BLOCK), makes the same sums as the persistent loop in
    gather order: the same bits after the same steps, resets included."""
    arrays = fabric_arrays.build(patch_model(PAPER_FRICTION).structure)
    assert arrays.nodes <= fabric_explicit.ENERGY_BLOCK
    external = 0.3 * (arrays.load_direction + arrays.weft_load_direction)
    runs = []
    for layout in ("persistent", "per_step", "per_step"):
        solver = fabric_explicit.FabricExplicit(arrays, layout=layout, damping="kinetic",
                                                order="gather", friction=True)
        positions, outcome = solver.relax(arrays.rest_position, external, 0.0, 600)
        assert outcome.steps == 600
        runs.append(positions)
    assert np.abs(runs[0] - arrays.rest_position).max() > 1e-4
    assert np.array_equal(runs[1], runs[2]) and np.array_equal(runs[0], runs[1])


def one_yarn_model(load, friction=None):
    """The one-yarn model of PATCH's warps (geometry.yarns = 2, phases +-1) with a rigid weft
    spring: contact_law k_s = k_c exactly (docs/model.md section 10: k_we -> infinity); `friction` a
    [friction] table with its k_t given."""
    family = PATCH.warp
    tables = {} if friction is None else {"friction": friction}
    scene = make_scene(**tables,
        geometry={"length": PATCH.warp.length, "segments": PATCH.warp.segments, "crossings": PATCH.wefts,
                  "amplitude": family.amplitude, "yarns": PATCH.warps},
        warp={"EA": family.EA, "EI": family.EI, "kawabata_C": family.kawabata_C,
              "kawabata_K": family.kawabata_K},
        weft={"EI": PATCH.weft.EI, "length": PATCH.weft.length, "count": PATCH.warps,
              "amplitude": PATCH.weft.amplitude, "kawabata_C": PATCH.weft.kawabata_C,
              "kawabata_K": PATCH.weft.kawabata_K},
        contact={"core_stiffness": K_C},
        load={"control": "force", "values": [load]})
    model = build_model(scene)
    yarns = []
    for yarn in model.yarns:
        law = yarn.contact_law.copy()
        law[0] = K_C
        yarns.append(yarn._replace(contact_law=law))
    return replace(model, yarns=tuple(yarns))


def inverse_stiffness_norm(model, positions, anchors, coupled=False) -> float:
    """max over yarns of ||K^-1||_inf [m/N], K the Hessian on the free dofs (coupled: the
    Jacobian of the friction problem, F_T following R), with the step's anchors (yarns, C)."""
    free = ~model.fixed_dofs()
    norms = []
    for k, yarn in enumerate(model.yarns):
        contact_force, limit, tangent = (np.zeros(model.crossings) for _ in range(3))
        assembly.contact_state(positions[k], yarn, contact_force, limit, tangent)
        band = zeros_band(positions[k].size)
        assembly.hessian(positions[k], yarn, anchors[k], limit, tangent, coupled, band)
        matrix = dense(band)[np.ix_(free, free)]
        norms.append(np.abs(np.linalg.inv(matrix)).sum(axis=1).max())
    return max(norms)


FRICTION_STICK = 1e3
"""k_t [N/m] of the friction comparison, given to both models (the fabric's default is the
smaller family's EA / segment length, the one-yarn model's its warp's)."""


@pytest.mark.parametrize("with_friction, damping", [(False, "kinetic"), (True, "kinetic"),
                                                    (False, "fire")])
def test_held_wefts_give_the_one_yarn_model_with_a_rigid_weft_spring(arrays, with_friction, damping):
    """Every weft node held: each warp is the one-yarn model with k_s = k_c
    (docs/model.md section 10); with friction, the weft node's slip y - Y_k - xi_y stays 0, so the
    isotropic Huber term is the one-yarn model's on x alone.

    Linearising the residual at the solution, x_fabric - x_static = K^-1 (r_fabric - r_static),
    so |x_fabric - x_static|_inf <= ||K^-1||_inf (r + r_s), K the warp's Hessian on its free
    dofs (with the wefts held the fabric's K is block-diagonal, one one-yarn K per warp; with
    friction, the Jacobian of the coupled problem at the step's anchors). The return-mapped
    anchors then agree to the same bound: xi = x - F_T s / (k_t |s|) at a sliding crossing moves
    with x and with F_T / k_t, whose change alpha dR / k_t <= alpha k_c dz / k_t adds the factor
    (1 + alpha k_c / k_t)."""
    load = 0.3
    friction = dict(PAPER_FRICTION, stick_stiffness=FRICTION_STICK) if with_friction else None
    model = one_yarn_model(load, friction)
    start = initial_state(model)
    state, record = StaticSolver(model).step(start, load)
    patch = fabric_arrays.build(patch_model(friction).structure)
    held = patch.free.copy()
    held[patch.weft_nodes.ravel()] = 0.0
    patch = replace(patch, free=held)
    solver = fabric_explicit.FabricExplicit(patch, damping=damping, friction=True)
    tolerance = 1e-10
    positions, outcome = solver.relax(patch.rest_position, load * patch.load_direction, tolerance,
                                      200_000)
    assert outcome.status == status.CONVERGED, outcome
    assert np.array_equal(positions[patch.weft_nodes], patch.rest_position[patch.weft_nodes])
    norm = inverse_stiffness_norm(model, state.positions, start.anchors, coupled=with_friction)
    bound = norm * (outcome.residual + np.max(record["residual"]))
    error = np.abs(positions[patch.warp_nodes] - state.positions).max()
    moved = np.abs(state.positions - start.positions).max()
    assert moved > 1e3 * bound  # the load moves the warps far beyond the tolerance
    assert error <= bound, (error, bound)
    if with_friction:
        anchors = solver.return_map(positions, np.zeros((patch.crossings, 2)))
        planes = patch.rest_position[patch.crossing_warp, 0]
        fabric_anchors = (planes + anchors[:, 0]).reshape(PATCH.warps, PATCH.wefts)
        slid = np.abs(state.anchors - start.anchors).max()
        law = patch.friction_law
        anchor_bound = bound * (1 + law[0] * patch.contact_law[0] / law[3])
        assert slid > 1e3 * anchor_bound  # crossings slide
        assert np.abs(fabric_anchors - state.anchors).max() <= anchor_bound
        assert np.array_equal(anchors[:, 1], np.zeros(patch.crossings))  # the weft does not slip
