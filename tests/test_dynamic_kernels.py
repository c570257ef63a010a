"""The dynamic solver's Warp force and stiffness kernels against the numba terms
(docs/model.md sections 2-4).

Each term's Warp gradient and banded tangent stiffness against its numba twin in
`dynfab.terms` at random states, the total force and energies against `dynfab.assembly`
with F_T from `dynfab.assembly.contact_state`, to float64 rounding; and the
kernel variants: a variant without a term compiles none of its code, and asking
twice for a configuration returns the same kernel. (Each term against finite
differences of its energy, on both twins: tests/test_conformance.py.)
"""

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import warp as wp

from dynfab import assembly
from dynfab.banded import zeros_band
from dynfab.kernels import diagnostics, explicit, forces, yarn_arrays
from dynfab.kernels.configuration import Configuration, built_variants
from dynfab.model import build_model, initial_state
from dynfab.scene import Gravity, load_scene, validate_scene, with_key
from dynfab.terms import bending, contact, friction, gravity, load, registry, stretch

RUNS = Path(__file__).resolve().parent.parent / "runs"
EPS = np.finfo(np.float64).eps
LOAD = 0.3
"""End load P [N] of the force-controlled test scene."""
CONFIGURATION = Configuration(terms=registry.NAMES)
"""The variant with every term: friction, gravity and the end load."""
STRETCH, BENDING, CONTACT, FRICTION, GRAVITY, LOAD = (diagnostics.TERM_INDEX[name] for name in
                                                      ("stretch", "bending", "contact",
                                                       "friction", "gravity", "load"))


@pytest.fixture(scope="module")
def model():
    """The Fig. 5 scene (friction on and off) with gravity added, under force control."""
    scene = load_scene(RUNS / "paper_fig5.toml")
    scene = validate_scene(replace(scene, gravity=Gravity()))
    return build_model(with_key(scene, "load.control", "force"))


@pytest.fixture(scope="module")
def random_state(model):
    """Positions 20 um around the as-woven ones (strains of a few %, every contact closed,
    prestressed) and anchors 2 um around the crossing nodes (some crossings stick, some slide)."""
    rng = np.random.default_rng(2007)
    positions = initial_state(model).positions + rng.normal(0.0, 2e-5, (model.yarn_count,
                                                                        model.segments + 1, 2))
    nodes = model.yarns[0].crossing_node
    anchors = positions[:, nodes, 0] + rng.normal(0.0, 2e-6, (model.yarn_count, model.crossings))
    return positions, anchors


def warp_term(model, positions, anchors, term):
    """At the solver's evaluation (R, dR/dg and F_T at `positions`): Warp's gradient
    (yarns, N+1, 2) [N] of one term (the solver's force for ALL_TERMS: -dV/dr on the free
    dofs), band (yarns, 2 (N+1), 11) [N/m], (R, dR/dg, F_T) and energies (yarns, 6) [J]."""
    yarns, nodes, crossings = model.yarn_count, model.segments + 1, model.crossings
    force, grad = (wp.zeros((yarns, nodes), dtype=wp.vec2d) for _ in range(2))
    band = wp.zeros((yarns, 2 * nodes, 11), dtype=wp.float64)
    energy = wp.zeros((yarns, len(registry.NAMES)), dtype=wp.float64)
    contact_state = [wp.zeros((yarns, crossings), dtype=wp.float64) for _ in range(3)]
    wp.launch(diagnostics.term_kernel(CONFIGURATION), dim=yarns,
              inputs=[yarn_arrays.upload(model, wp.float64, "cpu"), wp.array(positions, dtype=wp.vec2d),
                      wp.array(anchors, dtype=wp.float64), LOAD, term, 1, force, grad, band, energy,
                      *contact_state])
    returned = force if term == diagnostics.ALL_TERMS else grad
    return returned.numpy(), band.numpy(), [a.numpy() for a in contact_state], energy.numpy()


def numba_contact_state(yarn, pos):
    """(R [N], F_T [N], dR/dg [N/m]) per crossing from `dynfab.assembly.contact_state`."""
    state = [np.zeros(yarn.crossing_node.size) for _ in range(3)]
    assembly.contact_state(pos, yarn, *state)
    return state


def numba_term(yarn, pos, anchors, term):
    """dV_term/dr (N+1, 2) [N] and its banded Hessian [N/m] from `dynfab.terms`, F_T from R."""
    R, limit, _ = numba_contact_state(yarn, pos)
    grad, band = np.zeros_like(pos), zeros_band(pos.size)
    nodes, sides, offsets, law = (yarn.crossing_node, yarn.crossing_side, yarn.gap_offset,
                                  yarn.contact_law)
    if term == STRETCH:
        stretch.add_gradient(pos, yarn.rest_length, yarn.stretch_stiffness, grad)
        stretch.add_hessian(pos, yarn.rest_length, yarn.stretch_stiffness, band)
    elif term == BENDING:
        bending.add_gradient(pos, yarn.bend_stiffness, yarn.rest_angle, grad)
        bending.add_hessian(pos, yarn.bend_stiffness, yarn.rest_angle, band)
    elif term == CONTACT:
        contact.add_gradient(pos, nodes, sides, offsets, law, grad)
        contact.add_hessian(pos, nodes, sides, offsets, law, band)
    elif term == FRICTION:
        friction.add_gradient(pos, nodes, anchors, limit, yarn.stick_stiffness, grad)
        friction.add_hessian(pos, nodes, anchors, limit, yarn.stick_stiffness, band)
    elif term == GRAVITY:
        gravity.add_gradient(yarn.mass, yarn.gravity, grad)
    elif term == LOAD:
        load.add_gradient(LOAD, grad)
    return grad, band


def rounding_scale(yarn, pos, anchors, term):
    """The largest magnitude a term's force components are computed from [N].

    float64 rounds each operation to eps of its operands: the stretch force k (l - l0)
    carries the rounding of l, k l; the bending force the moment's k |phi| (<= k pi)
    over a segment length; friction k_t x (the slip x - xi cancels); contact R; gravity
    m g; the load P.
    """
    lengths = np.hypot(*np.diff(pos, axis=0).T)
    if term == STRETCH:
        return np.max(yarn.stretch_stiffness * lengths)
    if term == BENDING:
        return np.max(yarn.bend_stiffness) * np.pi / lengths.min()
    if term == CONTACT:
        return numba_contact_state(yarn, pos)[0].max()
    if term == FRICTION:
        return yarn.stick_stiffness * np.abs(pos[:, 0]).max()
    if term == GRAVITY:
        return yarn.mass.max() * yarn.gravity
    return LOAD


TERMS = [STRETCH, BENDING, CONTACT, FRICTION, GRAVITY, LOAD]


@pytest.mark.parametrize("term", TERMS, ids=["stretch", "bending", "contact", "friction",
                                             "gravity", "load"])
def test_term_force_and_stiffness_match_numba(model, random_state, term):
    positions, anchors = random_state
    warp_grad, band, _, _ = warp_term(model, positions, anchors, term)
    for k, yarn in enumerate(model.yarns):
        grad, hessian = numba_term(yarn, positions[k], anchors[k], term)
        scale = rounding_scale(yarn, positions[k], anchors[k], term)
        # float64 rounding: a few ulps of the largest operand, summed over <= 3 elements per node.
        assert np.abs(warp_grad[k] - grad).max() <= 16 * EPS * scale
        # Each band entry sums <= 3 element blocks, each rounded to eps of the largest entry.
        assert np.abs(band[k] - hessian).max() <= 16 * EPS * max(np.abs(hessian).max(), 1.0)


def test_total_force_matches_assembly_gradient(model, random_state):
    positions, anchors = random_state
    force, band, (contact_force, tangent, limit), _ = warp_term(model, positions, anchors,
                                                                diagnostics.ALL_TERMS)
    fixed = model.fixed_dofs()
    for k, yarn in enumerate(model.yarns):
        R, F_T, dR_dg = numba_contact_state(yarn, positions[k])
        grad, hessian = np.zeros_like(positions[k]), zeros_band(positions[k].size)
        assembly.gradient(positions[k], yarn, LOAD, anchors[k], F_T, grad)
        assembly.hessian(positions[k], yarn, anchors[k], F_T, dR_dg, False, hessian)
        # The Newton inversion of the contact law stops within 4e-16 R (dynfab.terms.contact).
        assert np.abs(contact_force[k] - R).max() <= 16 * EPS * R.max()
        assert np.abs(limit[k] - F_T).max() <= 16 * EPS * max(F_T.max(), 1e-300)
        assert np.abs(tangent[k] - dR_dg).max() <= 16 * EPS * dR_dg.max()
        expected = np.where(fixed.reshape(-1, 2), 0.0, -grad)
        scale = max(rounding_scale(yarn, positions[k], anchors[k], t) for t in TERMS)
        assert np.abs(force[k] - expected).max() <= 16 * EPS * scale
        assert np.abs(band[k] - hessian).max() <= 16 * EPS * np.abs(hessian).max()


def test_energies_match_assembly_energies(model, random_state):
    # Every active term's energy, in the slots of `dynfab.assembly.energies` (registry order),
    # F_T from this evaluation's R. Rounding: each energy sums n <= N+1 terms, each rounded to
    # a few eps of itself, and a rounding of eps |r_i| in a coordinate moves E by
    # |dE/dr_i| eps |r_i|: 16 eps S with S = n |E| + sum_i |dE/dr_i| |r_i| (as in
    # tests/test_conformance.py).
    positions, anchors = random_state
    energies = warp_term(model, positions, anchors, diagnostics.ALL_TERMS)[3]
    expected = np.zeros_like(energies)
    for k, yarn in enumerate(model.yarns):
        _, F_T, _ = numba_contact_state(yarn, positions[k])
        assembly.energies(positions[k], yarn, LOAD, anchors[k], F_T, expected[k])
        for term in TERMS:
            grad, _ = numba_term(yarn, positions[k], anchors[k], term)
            S = (model.segments + 1) * abs(expected[k, term]) + np.sum(np.abs(grad * positions[k]))
            assert abs(energies[k, term] - expected[k, term]) <= 16 * EPS * S
    assert (expected != 0.0).any(axis=0).all()  # every term is exercised


def generated_source(kernel) -> str:
    """The C++ Warp generated for a kernel's module, read from the kernel cache after a launch
    (the launch's own module hash names the cache folder)."""
    (loaded,) = kernel.module.execs.values()
    identifier = f"wp_{kernel.module.name}_{loaded.module_hash.hex()[:7]}"
    return (Path(wp.config.kernel_cache_dir) / identifier / f"{identifier}.cpp").read_text()


def test_variant_without_friction_compiles_no_friction_code(model, random_state):
    warp_term(model, *random_state, diagnostics.ALL_TERMS)
    fig3 = build_model(with_key(load_scene(RUNS / "paper_fig3.toml"), "load.values", [0.001]))
    kernel = explicit.relaxation_kernel(Configuration(terms=fig3.terms))
    wp.load_module(kernel.module, device="cpu")
    with_friction = generated_source(diagnostics.term_kernel(CONFIGURATION))
    without = generated_source(kernel)
    for name in ("huber_derivative", "is_sliding"):
        assert name in with_friction
        assert name not in without
    # the gravity term's code (its Python source is in the generated C++ as comments)
    assert "yarn.gravity[y]" in with_friction and "yarn.gravity[y]" not in without


def test_each_configuration_builds_once():
    configuration = Configuration(terms=registry.NAMES)
    first = diagnostics.term_kernel(configuration)
    assert diagnostics.term_kernel(Configuration(terms=registry.NAMES)) is first
    # the terms are kept in registry order, so the same selection in another order is the same
    # variant, and an unknown term is refused
    assert diagnostics.term_kernel(Configuration(terms=registry.NAMES[::-1])) is first
    with pytest.raises(ValueError, match="unknown terms"):
        Configuration(terms=("stretch", "twist"))
    keys = built_variants()
    assert len(keys) == len(set(keys))


def test_onset_friction_limit_matches_numba_and_its_derivative(model, random_state):
    # docs/model.md section 4: F_T = alpha R + beta ell r_f (1 - exp(-R / R_0)). With R_0 = 1e-2 N,
    # of the order of this state's contact forces (about 1.1e-2 N), the onset factor is far from 1.
    # Warp's F_T against numba's at the same R, to a few ulps of F_T (the kernel's expm1 is
    # Kahan's, a few ulps); and dF_T/dz through the kernel by central differences against
    # -s_j dF_T/dR dR/dg (numba's slope): h = 1e-9 m, truncation h^2 |d3F/dz3| / 6 with
    # |d3F/dz3| <= (c / R_0^3 + ...) k_we^3, rounding 2 ulps of F_T over 2 h.
    onset = 1e-2
    scene = with_key(model.scene, "friction.onset_force", onset)
    onset_model = build_model(scene)
    positions, anchors = random_state
    _, _, (R, tangent, limit), _ = warp_term(onset_model, positions, anchors, FRICTION)
    h = 1e-9
    for k, yarn in enumerate(onset_model.yarns):
        assert yarn.friction_onset == onset
        if yarn.friction_alpha == 0.0 and yarn.friction_constant == 0.0:
            continue
        expected = np.array([friction.limit(r, yarn.friction_alpha, yarn.friction_constant, onset)
                             for r in R[k]])
        assert np.any((R[k] > 0.3 * onset) & (R[k] < 3 * onset))
        assert np.abs(limit[k] - expected).max() <= 8 * EPS * expected.max()
        for j, node in enumerate(yarn.crossing_node):
            if not R[k, j] > 0:
                continue
            side = yarn.crossing_side[j]
            shifted = []
            for step in (h, -h):
                moved = positions.copy()
                moved[k, node, 1] += step
                shifted.append(warp_term(onset_model, moved, anchors, FRICTION)[2][2][k, j])
            fd = (shifted[0] - shifted[1]) / (2 * h)
            slope = friction.limit_slope(R[k, j], yarn.friction_alpha, yarn.friction_constant, onset)
            exact = -side * slope * tangent[k, j]
            k_we = yarn.contact_law[0]
            bound = h * h * (yarn.friction_constant / onset ** 3) * k_we ** 3 + \
                2 * 8 * EPS * limit[k, j] / (2 * h)
            assert abs(fd - exact) <= bound + 1e-9 * abs(exact)
            break  # one crossing per yarn: each costs two launches


@wp.kernel(module="unique", module_options={"enable_backward": False})
def _residual_of(yarn: yarn_arrays.struct(wp.float64), pos: wp.array2d(dtype=wp.vec2d),
                 anchors: wp.array2d(dtype=wp.float64), force: wp.array2d(dtype=wp.vec2d),
                 contact_force: wp.array2d(dtype=wp.float64),
                 contact_tangent: wp.array2d(dtype=wp.float64),
                 friction_limit: wp.array2d(dtype=wp.float64), residual: wp.array(dtype=wp.float64)):
    y = wp.tid()
    residual[y] = wp.static(forces.functions(wp.float64, CONFIGURATION.terms).evaluate)(
        y, pos, yarn, anchors, wp.float64(LOAD), force, contact_force, contact_tangent,
        friction_limit)


def test_a_non_finite_force_gives_a_non_finite_residual(model, random_state):
    """The residual the relaxation judges is the largest |force component|; one NaN node in
    the middle of the yarn (its force and its neighbours' are NaN, the components compared
    after them finite) must make it NaN, so the step reports a non-finite state instead of
    converging on the finite components."""
    positions, anchors = (a.copy() for a in random_state)
    positions[0, model.segments // 3, 1] = np.nan
    yarns, nodes, crossings = model.yarn_count, model.segments + 1, model.crossings
    residual = wp.zeros(yarns, dtype=wp.float64)
    wp.launch(_residual_of, dim=yarns,
              inputs=[yarn_arrays.upload(model, wp.float64, "cpu"),
                      wp.array(positions, dtype=wp.vec2d), wp.array(anchors, dtype=wp.float64),
                      wp.zeros((yarns, nodes), dtype=wp.vec2d),
                      *(wp.zeros((yarns, crossings), dtype=wp.float64) for _ in range(3)),
                      residual])
    values = residual.numpy()
    assert np.isnan(values[0])
    assert np.all(np.isfinite(values[1:])) and np.all(values[1:] > 0.0)
