"""The kernel layer for any structure (`dynfab.kernels.structure_relaxation`): its forces against
the static references' gradients, term by term, its layouts bit for bit, its groups
(docs/model.md sections 2-5, 10).

Structures: the paper's yarn as two chains tied to ground (geometry.yarns = 2, N = 32, four
crossings, friction, gravity), the periodic 2 x 2 cell (tied cell lengths, wrap springs, moving
planes, friction) and a clamped 3 x 3 patch with "affine" planes (friction, gravity). Every
kernel here is built with friction and the boundary couplings compiled in (float64): one
variant for all three structures; the yarn's force test and the relaxation tests
(tests/test_kernels_structure_relax.py) share it.
"""

import math
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
import warp as wp
from independent import PAPER_FRICTION, PAPER_WARP, PAPER_WEFT, make_scene

from dynfab.model import assembly
from dynfab.model.builders import build_structure
from dynfab.model.fabric import assembly as fabric_assembly
from dynfab.model.fabric import contact as tie_contact
from dynfab.solvers.newton_sparse import SparseNewton
from dynfab.kernels import status, structure_arrays, structure_explicit, structure_variants
from dynfab.kernels.structure_relaxation import StructureRelaxation
from dynfab.model.yarn import chain_view
from dynfab.scene import load_scene
from dynfab.model.structure import GROUND, chain_count
from dynfab.model.terms import friction as gralen
from dynfab.model.terms import registry

EPS = np.finfo(float).eps
FAMILY = dict(EA=13.72, EI=1.47e-7, kawabata_C=0.2e-3, kawabata_K=0.2)
RUNS = Path(__file__).resolve().parent.parent / "runs"
PITCH = 0.1 / 16
"""The paper yarn's crossing pitch [m]: the fabric scenes' yarns are the paper's."""


def yarn_scene(**more):
    """Two paper yarns of phases +-1 (N = 32, four crossings), friction and gravity."""
    return make_scene(geometry={"length": 0.1, "segments": 32, "crossings": 4,
                                "amplitude": 0.5e-3, "yarns": 2},
                      warp=PAPER_WARP, weft=PAPER_WEFT, friction=PAPER_FRICTION,
                      gravity={"g": 9.81}, load={"values": [0.1]}, **more)


def fabric_scene(n: int, boundary: str, planes: str = "fixed", gravity: bool = False,
                 load=(0.2, 0.1), control: str = "force"):
    """An n x n fabric of the paper's yarns (14 segments per crossing pitch), friction on."""
    geometry = {"model": "fabric", "boundary": boundary, "length": n * PITCH,
                "segments": 14 * n, "crossings": n, "amplitude": 0.5e-3}
    if boundary == "clamped":
        geometry["planes"] = planes
    tables = dict(geometry=geometry, warp=FAMILY,
                  weft=dict(count=n, length=n * PITCH, segments=14 * n, amplitude=0.5e-3,
                            **FAMILY),
                  friction=PAPER_FRICTION,
                  load={"control": control, "values": [load[0]], "weft_values": [load[1]]})
    if gravity:
        tables["gravity"] = {"g": 9.81}
    return make_scene(**tables)


SCENES = {"yarn": yarn_scene, "periodic": lambda: fabric_scene(2, "periodic"),
          "affine": lambda: fabric_scene(3, "clamped", "affine", gravity=True)}


@pytest.fixture(scope="module")
def structures():
    return {name: build_structure(make()) for name, make in SCENES.items()}


TUNING = ("chunk", "check_interval", "cg_tolerance", "backtracks", "secant", "direct")
"""`StructureRelaxation`'s tuning, attributes set after construction."""


def relaxation(structure, **options) -> StructureRelaxation:
    """The kernels of the tests' one variant (friction and boundary compiled in); `options`
    its keywords and tuning attributes (`TUNING`)."""
    tuning = {name: options.pop(name) for name in TUNING if name in options}
    kernels = StructureRelaxation(structure, friction=True, boundary=True, **options)
    for name, value in tuning.items():
        setattr(kernels, name, value)
    return kernels


def static_solver(structure, scene=None) -> SparseNewton:
    """The static solver's sparse backend on any structure (its energy, gradient and Hessian
    read the structure alone: docs/model.md sections 6, 10)."""
    scene = make_scene(geometry={"length": 0.1, "segments": 4, "crossings": 0, "amplitude": 0.0},
                       warp=PAPER_WARP, load={"values": [0.1]}) if scene is None else scene
    return SparseNewton(SimpleNamespace(structure=structure, scene=scene))


def perturbed(structure, seed=3, size=2e-5) -> np.ndarray:
    """Rest positions moved by up to `size` [m] in every free coordinate (a tied family's dofs
    by one common amount: they are one dof), then each tie's node a by 2.5 `size` along z,
    toward its partner (closing the tie by at least `size`) on two ties of three, away from it
    on the third."""
    rng = np.random.default_rng(seed)
    move = rng.uniform(-size, size, structure.rest_position.size)
    move[structure.fixed] = 0.0
    tied = structure.dof_tie >= 0
    move[tied] = move[structure.dof_tie[tied]]
    positions = structure.rest_position + move.reshape(-1, 2)
    toward = np.where(np.arange(structure.tie_a.size) % 3 == 2, -1.0, 1.0)
    positions[structure.tie_a, 1] -= 2.5 * size * toward * structure.tie_side
    return positions


def mixed_anchors(structure, positions) -> np.ndarray:
    """Anchors (T, 2) [m] that leave every other closed tie sliding (slip 1e-5 m, about
    100 F_T / k_t) and the others sticking (slip 1e-9 m, k_t |s| below F_T)."""
    px, py = fabric_assembly.planes(positions, structure)
    node_b = np.maximum(structure.tie_b, 0)
    current = np.stack([positions[structure.tie_a, 0] - px,
                        np.where(structure.tie_b >= 0, positions[node_b, 0] - py, 0.0)], axis=1)
    anchors = current - np.array([1e-9, 0.0])
    R = np.zeros(structure.tie_a.size)
    tie_contact.forces(positions, structure, R)
    sliding = np.flatnonzero(R > 0)[::2]
    anchors[sliding] = current[sliding] + np.array([1e-5, -1e-5])
    anchors[structure.tie_b == GROUND, 1] = 0.0
    return anchors


def only(structure, term: str):
    """The structure with one term (the others' parameters zeroed, the ties opened by a large
    negative offset); "friction" keeps the contact, which F_T needs; "all" keeps everything."""
    s = structure
    zero = dict(stretch_stiffness=0 * s.stretch_stiffness, bend_stiffness=0 * s.bend_stiffness,
                wrap_stiffness=0 * s.wrap_stiffness, gravity=0 * s.gravity,
                tie_friction_law=0 * s.tie_friction_law,
                tie_gap_offset=s.tie_gap_offset - 1.0)
    keep = {"stretch": ("stretch_stiffness",), "bending": ("bend_stiffness", "wrap_stiffness"),
            "contact": ("tie_gap_offset",), "friction": ("tie_gap_offset", "tie_friction_law"),
            "gravity": ("gravity",), "load": (), "all": tuple(zero)}[term]
    changed = {name: value for name, value in zero.items() if name not in keep}
    return s._replace(**changed, has_friction=term in ("friction", "all") and s.has_friction)


def contribution_scale(structure, positions, P) -> float:
    """S [N]: the largest single contribution to any force component: segment tensions
    |k (l - l0)|, bending moments over segment lengths |k (phi - phi0)| (1/|a| + 1/|b|) (the
    wrap's alike), contact forces R, friction limits F_T (and their planes' reaction
    sum_t w_t F_T), weights m g and end loads |P|."""
    s = structure
    scale = [np.abs(P).max(initial=0.0), np.max(s.mass * np.abs(s.gravity), initial=0.0)]
    for y in range(chain_count(s)):
        a, b = s.chain_start[y], s.chain_start[y + 1]
        e = np.diff(positions[a:b], axis=0)
        length = np.hypot(*e.T)
        k = s.stretch_stiffness[a - y:b - y - 1]
        scale.append(np.max(np.abs(k * (length - s.rest_length[a - y:b - y - 1]))))
        phi = np.arctan2(e[:-1, 0] * e[1:, 1] - e[:-1, 1] * e[1:, 0], np.sum(e[:-1] * e[1:], 1))
        moment = s.bend_stiffness[a + 1:b - 1] * (phi - s.rest_angle[a + 1:b - 1])
        scale.append(np.max(np.abs(moment) * (1 / length[:-1] + 1 / length[1:])))
        if s.wrap_stiffness[y] > 0:
            turn = fabric_assembly.wrap_angle(positions, s, y) - s.wrap_rest_angle[y]
            scale.append(abs(s.wrap_stiffness[y] * turn) * (1 / length[-1] + 1 / length[0]))
    R = np.zeros(s.tie_a.size)
    tie_contact.forces(positions, s, R)
    limit = np.zeros(s.tie_a.size)
    gralen.tie_limits(R, s.tie_friction_law, -1.0, limit)
    reaction = np.abs(s.tie_plane_weight).sum(axis=0).max(initial=0.0) * limit.max(initial=0.0)
    scale += [R.max(initial=0.0), limit.max(initial=0.0), reaction]
    return max(scale)


def one_yarn_gradients(structure, positions, P, anchors) -> np.ndarray:
    """-dV/dr (n, 2) [N] by `dynfab.model.assembly` on every chain's Yarn view, F_T frozen at the
    law of its own contact forces, 0 on the held dofs."""
    active = np.ones(len(registry.NAMES), np.bool_)
    out = np.zeros_like(positions)
    for y in range(chain_count(structure)):
        yarn = chain_view(structure, y, active)
        nodes = slice(structure.chain_start[y], structure.chain_start[y + 1])
        pos = np.ascontiguousarray(positions[nodes])
        C = yarn.crossing_node.size
        R, limit, tangent = np.zeros(C), np.zeros(C), np.zeros(C)
        assembly.contact_state(pos, yarn, R, limit, tangent)
        ties = np.flatnonzero((structure.tie_a >= nodes.start) & (structure.tie_a < nodes.stop))
        grad = np.zeros_like(pos)
        assembly.gradient(pos, yarn, P[y], np.ascontiguousarray(anchors[ties, 0]), limit, grad)
        out[nodes] = -grad
    out[structure.fixed.reshape(-1, 2)] = 0.0
    return out


def fabric_gradients(structure, positions, P, anchors) -> np.ndarray:
    """-dV/dr (n, 2) [N] by `dynfab.model.fabric.assembly` on the unknowns (a tied family's summed
    on each of its dofs), F_T frozen at the law of the current contact forces."""
    static = static_solver(structure)
    limit = np.zeros(structure.tie_a.size)
    if structure.has_friction:
        R = np.zeros(structure.tie_a.size)
        tie_contact.forces(positions, structure, R)
        gralen.tie_limits(R, structure.tie_friction_law, -1.0, limit)
    grad = np.zeros_like(positions)
    fabric_assembly.gradient(positions, structure, P, anchors, limit, grad)
    return -static.pattern.expand(static.pattern.reduce(grad)).reshape(positions.shape)


TERMS = ("stretch", "bending", "contact", "friction", "gravity", "load", "all")


@pytest.mark.parametrize("term", TERMS)
@pytest.mark.parametrize("name", sorted(SCENES))
def test_forces_are_the_static_gradient(structures, name, term):
    """Each term's kernel force against the static reference's gradient (the one-yarn
    `dynfab.model.assembly` per chain for the yarn, `dynfab.model.fabric.assembly` for the fabrics)
    at a perturbed state, crossings closed and open, sliding and sticking, to rounding: a force
    component sums at most 16 contributions (two segments, three bending springs and the wrap,
    its ties' contact and friction, the planes' reaction, a tied family's members), each within
    8 ulps of its size, at most S (`contribution_scale`) in both evaluations: 256 eps S. Not
    vacuous: the largest force is far above it."""
    full = structures[name]
    if term == "gravity" and not np.any(full.gravity):
        pytest.skip("no gravity on a periodic cell (docs/model.md section 10)")
    s = only(full, term)
    positions = perturbed(full)
    anchors = mixed_anchors(full, positions)
    chains = chain_count(s)
    P = 0.2 * s.load_factor if term in ("load", "all") else np.zeros(chains)
    kernels = relaxation(s)
    force = kernels.forces(positions, P, anchors)
    if name == "yarn":
        expected = one_yarn_gradients(s, positions, P, anchors)
    else:
        expected = fabric_gradients(s, positions, P, anchors)
    bound = 256 * EPS * contribution_scale(s, positions, P)
    assert np.abs(force - expected).max() <= bound, (np.abs(force - expected).max(), bound)
    assert np.abs(force).max() > 1e4 * bound
    if term in ("friction", "all"):  # ties slide (|f| = F_T) and stick (0 < |f| < F_T)
        _, friction, limit = kernels.tie_forces(positions, anchors)
        drag = np.hypot(*friction.T)
        assert np.any((drag > 0) & (drag >= limit * (1 - 1e-12)))
        assert np.any((drag > 0) & (drag < 0.5 * limit))


@pytest.mark.parametrize("name", sorted(SCENES))
def test_energy_is_the_static_energy(structures, name):
    """The energy the nodes and ties own (`energies`) sums to `dynfab.model.fabric.assembly`'s V
    plus the Huber terms (F_T at the current R), to the rounding of the terms' sums (each term
    within a few ulps of its size; 64 eps of every term's size summed)."""
    s = structures[name]
    positions = perturbed(s)
    anchors = mixed_anchors(s, positions)
    P = 0.2 * s.load_factor
    nodes, ties = relaxation(s).energies(positions, P, anchors)
    R, limit = np.zeros(s.tie_a.size), np.zeros(s.tie_a.size)
    tie_contact.forces(positions, s, R)
    gralen.tie_limits(R, s.tie_friction_law, -1.0, limit)
    terms = np.zeros(len(fabric_assembly.TERMS))
    expected = fabric_assembly.total_energy(positions, s, P, anchors, limit, terms)
    parts = np.concatenate([nodes, ties])
    bound = 64 * EPS * (np.abs(parts).sum() + np.abs(terms).sum())
    assert abs(math.fsum(parts) - expected) <= bound
    assert abs(expected) > 1e6 * bound


def test_groups_are_the_connected_chains(structures):
    """A one-yarn scene's chains are independent groups, each its band alone (exact); a fabric
    is one group; a group's nodes, ties and blocks are contiguous and every sum's block lies
    in one group."""
    yarn = structure_arrays.build(structures["yarn"])
    assert yarn.groups == 2 and list(yarn.group_exact) == [1, 1]
    assert list(yarn.group_node) == list(yarn.chain_start)
    for name in ("periodic", "affine"):
        fabric = structure_arrays.build(structures[name])
        assert fabric.groups == 1 and list(fabric.group_exact) == [0]
        assert fabric.group_tie[-1] == fabric.ties and fabric.group_node[-1] == fabric.nodes
        assert np.all(np.diff(fabric.block_start) <= structure_arrays.BLOCK)
    sweep = build_structure(yarn_scene_sweep())
    arrays = structure_arrays.build(sweep)
    assert arrays.groups == 3 and np.array_equal(arrays.tie_group, np.repeat([0, 1, 2], 4))


def yarn_scene_sweep():
    """Three one-yarn sweep entries (N = 32, four crossings, friction), EA 10, 13.72, 20 N."""
    return make_scene(geometry={"length": 0.1, "segments": 32, "crossings": 4,
                                "amplitude": 0.5e-3},
                      warp=PAPER_WARP, weft=PAPER_WEFT, friction=PAPER_FRICTION,
                      load={"values": [0.1]}, sweep={"warp.EA": [10.0, 13.72, 20.0]})


LAYOUT_CASES = {"periodic": (lambda: fabric_scene(2, "periodic"), (0.2, 0.1)),
                "sweep": (yarn_scene_sweep, (0.1,))}


@pytest.mark.parametrize("name", sorted(LAYOUT_CASES))
def test_explicit_layouts_are_bit_identical(name):
    """300 explicit steps with kinetic damping (resets included) from rest: the grouped layout
    in gather order and the node-parallel layout give the same bits (every sum in the same fixed
    order, no atomics); the grouped layout in its scatter order the same motion to the rounding
    of the sums' order (within 1e-12 m, a millionth of the motion; a term wrong in one order
    would change the motion at the term's own relative size). The periodic cell's tied ends
    keep one coordinate."""
    make, values = LAYOUT_CASES[name]
    s = build_structure(make())
    runs = {}
    for layout, order in (("grouped", "scatter"), ("grouped", "gather"),
                          ("node_parallel", "gather")):
        kernels = relaxation(s, layout=layout, order=order, damping="kinetic")
        positions, outcome = kernels.relax(s.rest_position, kernels.chain_loads(values), None,
                                           tolerance=0.0, max_steps=300)
        assert list(outcome.status) == [status.MAX_STEPS] * len(outcome.status)
        runs[layout, order] = positions
    moved = np.abs(runs["grouped", "scatter"] - s.rest_position).max()
    assert moved > 1e-5
    assert np.array_equal(runs["grouped", "gather"], runs["node_parallel", "gather"])
    assert np.abs(runs["grouped", "scatter"] - runs["grouped", "gather"]).max() <= 1e-12
    tied = np.flatnonzero(s.dof_tie >= 0)
    if tied.size:
        flat = runs["grouped", "scatter"].ravel()
        assert np.all(flat[tied] == flat[s.dof_tie[tied]])


@pytest.mark.parametrize("name", sorted(LAYOUT_CASES))
def test_semi_implicit_layouts_are_bit_identical(name):
    """Twelve semi-implicit steps (CG, refactorisations, the line search) from rest: the grouped
    layout in gather order and the node-parallel layout (a launch per stage, the loops over CG
    iterations and line-search trials on values read back) give the same bits and the same CG
    iterations."""
    make, values = LAYOUT_CASES[name]
    s = build_structure(make())
    runs = []
    for layout in ("grouped", "node_parallel"):
        kernels = relaxation(s, layout=layout, order="gather", method="semi_implicit")
        positions, outcome = kernels.relax(s.rest_position, kernels.chain_loads(values), None,
                                           tolerance=0.0, max_steps=12)
        runs.append((positions, outcome.cg_iterations))
    assert np.abs(runs[0][0] - s.rest_position).max() > 1e-5
    assert np.array_equal(runs[0][0], runs[1][0])
    assert np.array_equal(runs[0][1], runs[1][1]) and runs[0][1].min() > 0


def test_grounded_chains_take_one_cg_iteration_per_step():
    """On a structure whose ties are all grounded each group's matrix is its chain's band, the
    preconditioner: CG stops after one iteration at every time step (`direct` off), and the
    direct solve (`direct` on, the default) takes the same steps to the same state, to the
    rounding of x = alpha p against x = z."""
    s = build_structure(yarn_scene_sweep())
    runs = []
    for direct in (False, True):
        kernels = relaxation(s, method="semi_implicit", direct=direct)
        positions, outcome = kernels.relax(s.rest_position, kernels.chain_loads([0.1]), None,
                                           tolerance=1e-10, max_steps=1000)
        assert outcome.succeeded
        assert np.array_equal(outcome.cg_iterations, outcome.steps)
        runs.append((positions, outcome.steps))
    assert np.array_equal(runs[0][1], runs[1][1])
    assert np.abs(runs[0][0] - runs[1][0]).max() <= 1e-12


def test_groups_split_over_cores_give_the_same_bits():
    """The grouped layout launched on one core and on a range of groups per core (each range
    one launch, at once): the same bits, each thread computing only its own group."""
    s = build_structure(yarn_scene_sweep())
    runs = []
    for cores in (1, 3):
        kernels = relaxation(s, cores=cores, damping="kinetic")
        assert len(kernels.ranges) == cores
        positions, outcome = kernels.relax(s.rest_position, kernels.chain_loads([0.1]), None,
                                           tolerance=1e-9, max_steps=100_000)
        assert outcome.succeeded
        runs.append(positions)
    assert np.array_equal(runs[0], runs[1])


@pytest.mark.parametrize("precision", ["float64", "float32"])
def test_the_tie_law_is_cancellation_safe(precision):
    """The tie law's expm1 within 2 ulps of numpy's over |x| from 1e-20 to 10, and the contact
    force and energy at closures from 1e-16 m to 1e-4 m (R from about 1e-11 N, where
    1 - exp(-a R) and the energy's 1 - exp(-x)(1 + x) cancel) within a few ulps of the static
    reference's (`dynfab.model.terms.contact`, np.expm1 and its series), relative to their size."""
    import warp as wp

    from dynfab.kernels import tie_law
    from dynfab.kernels.precision import SCALARS, numpy_dtype
    from dynfab.model.terms import contact

    scalar, dtype = SCALARS[precision], numpy_dtype(SCALARS[precision])
    ops = tie_law.functions(scalar)
    vec = wp.types.vector(3, scalar)

    @wp.kernel(module="unique")
    def evaluate(x: wp.array(dtype=scalar), g: wp.array(dtype=scalar),
                 law: wp.array2d(dtype=scalar), out: wp.array(dtype=vec)):
        i = wp.tid()
        R = ops.contact(g[i], law, 0)[0]
        out[i] = vec(ops.expm1(x[i], wp.exp(x[i])), R, ops.contact_energy(R, law, 0))

    law = np.array([[1e5, 0.2e-3, 62.0, 0.2e-3, 62.0]])
    x = np.concatenate([-np.logspace(-20, 1, 500), np.logspace(-20, 1, 500)]).astype(dtype)
    g = np.logspace(-16, -4, 1000).astype(dtype)
    out = wp.zeros(x.size, dtype=vec)
    wp.launch(evaluate, dim=x.size, inputs=[wp.array(x, dtype=scalar), wp.array(g, dtype=scalar),
                                           wp.array(law.astype(dtype), dtype=scalar), out])
    values = out.numpy().astype(float)
    eps = np.finfo(dtype).eps
    exact = np.expm1(x.astype(float))
    assert np.all(np.abs(values[:, 0] - exact) <= 2 * eps * np.abs(exact))
    R = np.array([contact.force_from_closure(float(v), law[0]) for v in g])
    E = np.array([contact.energy_of_force(r, law[0]) for r in R])
    assert np.all(np.abs(values[:, 1] - R) <= 16 * eps * R)
    assert np.all(np.abs(values[:, 2] - E) <= 32 * eps * E)
    assert R.min() < 1e-10  # down where the cancellation would cost every digit


def generated_source(kernel) -> str:
    """The C++ Warp generated for a kernel's module, read from the kernel cache after its load
    (the load's own module hash names the cache folder)."""
    wp.load_module(kernel.module, device="cpu")
    (loaded,) = kernel.module.execs.values()
    identifier = f"wp_{kernel.module.name}_{loaded.module_hash.hex()[:7]}"
    return (Path(wp.config.kernel_cache_dir) / identifier / f"{identifier}.cpp").read_text()


def test_a_variant_without_friction_or_boundary_compiles_none_of_their_code(structures):
    """Friction and the boundary couplings are compiled only into the variants that have them
    (`wp.static`; a one-yarn scene without friction, the paper's Fig. 3, builds neither): the
    grouped explicit kernel of that structure holds none of the Huber term's or the wrap
    springs' source (Warp writes each line's Python source into the C++ as a comment), the
    tests' variant with both holds both; asking for a variant twice returns the same kernel,
    and the layer's register (`structure_variants.built_variants`) lists each once."""
    paper = build_structure(load_scene(RUNS / "paper_fig3.toml"))
    plain = StructureRelaxation(paper)
    assert (plain.friction, plain.boundary) == (False, False)
    full = relaxation(structures["periodic"])
    without, with_both = generated_source(plain._kernels()), generated_source(full._kernels())
    for code in ("laws.huber_force(", "wrap_forces(pos, data, first)"):
        assert code in with_both and code not in without, code
    assert structure_explicit.grouped_kernel(wp.float64, False, False, "scatter") \
        is plain._kernels()
    assert plain.variant in structure_variants.built_variants()
    built = structure_variants.built_variants()
    assert len(built) == len(set(built))


def test_kinetic_damping_resets_where_the_undamped_motion_peaks():
    """Kinetic damping (Barnes, docs/model.md section 5): the undamped motion until the kinetic
    energy a step would reach falls below the last one's, then x -= dt/2 v and v = 0. The
    reference is the same kernel's viscous damping at c = 0 (keep 1, gain dt: the kinetic
    steps' own arithmetic, so equal bits before the peak), its kinetic energies from its own
    successive positions, sum_i share_i m_i |x_k - x_(k-1)|^2 / (2 dt^2) (the masses the
    start chose, the same in both). A peak test on the wrong energy resets at another step or
    never."""
    s = build_structure(fabric_scene(2, "clamped"))
    undamped = relaxation(s, damping="viscous", damping_coefficient=0.0)
    kinetic = relaxation(s, damping="kinetic")
    loads = undamped.chain_loads((0.2, 0.1))

    def after(kernels, steps):
        return kernels.relax(s.rest_position, loads, None, tolerance=0.0, max_steps=steps)[0]

    path = [after(undamped, k) for k in range(80)]
    mass, dt = undamped.state.mass.numpy(), float(undamped.state.dt.numpy()[0])
    after(kinetic, 1)
    assert np.array_equal(kinetic.state.mass.numpy(), mass)  # the start chose the same masses
    weight = undamped.arrays.share * mass / (2.0 * dt * dt)
    energy = [float(weight @ ((b - a) ** 2).sum(axis=1)) for a, b in zip(path, path[1:])]
    peak = next(k for k in range(1, len(energy)) if energy[k] < energy[k - 1])  # after k steps
    for k in (1, peak // 2, peak):
        assert np.array_equal(after(kinetic, k), path[k])
    expected = path[peak] - 0.5 * (path[peak] - path[peak - 1])
    motion = np.abs(path[peak] - path[0]).max()
    assert motion > 0.0
    # the kernel backs x by dt/2 times its stored v, (x_k - x_(k-1)) / dt to rounding
    np.testing.assert_allclose(after(kinetic, peak + 1), expected, rtol=0, atol=1e-12 * motion)
    assert not np.allclose(path[peak + 1], expected, rtol=0, atol=1e-6 * motion)
