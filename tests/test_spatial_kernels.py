"""The spatial terms in the Warp kernel layer against the host's (docs/model.md section 11).

The kernels' force on the free dofs must be -dV/dr of `dynfab.model.fabric.spatial.gradient` with
F_T from Gralen's law at the same positions (the dynamic solver's residual is the static
solver's), their energy `dynfab.model.fabric.spatial.energy_vector`'s sum, and their return map
`dynfab.model.fabric.spatial.return_map`'s anchors. Both sides are float64 evaluations of the same
formulas in different orders, so they agree to rounding: 1e-12 of the largest force (or
energy term) allows ~4,500 eps of accumulated sums over a node's elements, far above what
reordering a handful of terms costs and far below any formula error (a wrong sign or factor
is O(1)).

The states are made to exercise every branch: positions and anchors perturbed so that some
crossings stick and some slide (both counted), and a copy with the lateral contacts' width
raised beyond the spacing so that every lateral contact presses.
"""

from __future__ import annotations

import numpy as np
import pytest

from dynfab.model.fabric import contact, spatial
from dynfab.model.fabric.specimen_model import SpecimenModel
from dynfab.scene import parse_scene_text
from dynfab.model.terms.spatial import crossing_coordinates
from test_shear_specimens import BIAS, FRAME, HOLDING_FRICTION, scene_text

wp = pytest.importorskip("warp")
from dynfab.kernels.structure_relaxation import StructureRelaxation  # noqa: E402

ROUNDING = 1e-12
"""Relative agreement of two float64 evaluations of the same terms (module docstring)."""
SMALL_BIAS = BIAS.replace("width = 0.06\nheight = 0.12", "width = 0.03\nheight = 0.06")


def specimen(text: str) -> SpecimenModel:
    return SpecimenModel(parse_scene_text(text))


def perturbed(model: SpecimenModel, d: float, seed: int):
    """A state off equilibrium at d: the step's start, nodes moved by ~10 um; every other
    crossing's anchor ~10 um and ~0.6 degree from its start (these slide), the others 1 nm
    and 1e-6 rad from the crossing's coordinates at the state (these stick)."""
    rng = np.random.default_rng(seed)
    start = model.start_of_step(model.initial_state(), d)
    pos = start.positions + 1e-5 * rng.standard_normal(start.positions.shape)
    s = model.structure
    anchors = start.anchors + np.array([1e-5, 1e-5, 1e-2]) * rng.standard_normal(
        start.anchors.shape)
    for c in range(0, s.tie_a.size, 2):
        crossing_coordinates(pos[s.tie_stencil[c]], anchors[c])
        anchors[c] += np.array([1e-9, 1e-9, 1e-6]) * rng.standard_normal(3)
    return pos, anchors


def pressing(structure, compacting=False):
    """The structure with every lateral contact's width at 2.5 times the yarn's: all press;
    `compacting`: on Gutowski's law (docs/model.md 11.5), each contact's distance (about the
    spacing, 0.49 of that width) between s_core and the width."""
    law = structure.lateral_law.copy()
    law[:, spatial.WIDTH] *= 2.5
    if compacting:
        law[:, spatial.COMPACTION] = 1e-4
        law[:, spatial.PACKED] = 0.4 * law[:, spatial.WIDTH]
        law[:, spatial.CORE_FROM] = 0.42 * law[:, spatial.WIDTH]
    return structure._replace(lateral_law=law)


@pytest.fixture(scope="module", params=["frame", "bias"])
def case(request):
    if request.param == "frame":
        return specimen(scene_text(FRAME, [6e-3]))
    return specimen(scene_text(SMALL_BIAS, [3e-3], HOLDING_FRICTION))


@pytest.mark.parametrize("lateral", ["as_is", "pressing", "compacting"])
def test_kernel_forces_and_energy_are_the_spatial_terms(case, lateral):
    structure = (case.structure if lateral == "as_is"
                 else pressing(case.structure, lateral == "compacting"))
    pos, anchors = perturbed(case, float(case.load_values[1]), seed=1)
    relaxation = StructureRelaxation(structure)
    assert relaxation.variant.kinematics == "spatial"
    limit = contact.friction_limits(pos, structure)
    grad = np.zeros_like(pos)
    spatial.gradient(pos, structure, np.zeros(1), anchors, limit, grad)
    expected = -grad * ~structure.fixed.reshape(pos.shape)
    force = relaxation.forces(pos, None, anchors)
    assert np.abs(force - expected).max() <= ROUNDING * np.abs(expected).max()
    R, friction, kernel_limit = relaxation.tie_forces(pos, anchors)
    assert np.abs(kernel_limit - limit).max() <= ROUNDING * limit.max()
    # both friction branches met: sticking crossings carry k_t |S| < F_T, sliding ones F_T
    size = np.linalg.norm(friction, axis=1)
    sliding = np.isclose(size, limit, rtol=1e-12)
    assert sliding.any() and (~sliding).any()
    terms = spatial.energy_vector(structure, pos, np.zeros(1), anchors, limit)
    nodes, ties = relaxation.energies(pos, None, anchors)
    laterals = relaxation.lateral_energies(pos)
    assert (laterals > 0).all() if lateral != "as_is" else True
    assert laterals.sum() == pytest.approx(terms[spatial.LATERAL],
                                           rel=ROUNDING, abs=ROUNDING * np.abs(terms).sum())
    total = nodes.sum() + ties.sum() + laterals.sum()
    assert total == pytest.approx(terms.sum(), rel=ROUNDING)


def test_kernel_return_map_is_the_spatial_one(case):
    pos, anchors = perturbed(case, float(case.load_values[1]), seed=2)
    structure = case.structure
    relaxation = StructureRelaxation(structure)
    limit = contact.friction_limits(pos, structure)
    expected = anchors.copy()
    sliding = np.zeros(structure.tie_a.size, np.bool_)
    lost = spatial.return_map(pos, expected, structure, limit, sliding,
                              np.zeros((structure.tie_a.size, 3)))
    assert sliding.any() and not sliding.all()
    mapped, dissipated = relaxation.return_map(pos, anchors)
    scale = np.abs(anchors).max(axis=0)
    assert np.all(np.abs(mapped - expected) <= ROUNDING * scale)
    assert dissipated.sum() == pytest.approx(lost, rel=ROUNDING)


SHARED_TANGENT = {"tie_blocks", "assemble_chain", "coupling_vector", "stiffest_tie",
                  "stiffest_chain", "gershgorin_row", "largest_diagonal"}
"""What the shared kernels (`structure_checks`, `structure_semi_implicit`) ask of a
kinematics' tangent."""


@pytest.mark.parametrize("kinematics", ["planar", "spatial"])
def test_each_kinematics_offers_the_shared_kernels_one_form(kinematics):
    # the shared kernels hold no fork on the kinematics (docs/model.md, "no fork on the
    # kinematics in the shared kernels"): each element module gives the same functions and
    # says as data what it does differently; a missing one would fail only at a launch
    import warp as wp

    from dynfab.kernels import structure_checks, structure_forces

    elements = structure_forces.KINDS[kinematics]
    assert isinstance(elements.ROWS_FROM_HOST, bool) and isinstance(elements.BOUNDARY, bool)
    assert all(len(refusal) == 3 for refusal in elements.REFUSALS)
    tangent = structure_checks.TANGENTS[kinematics](wp.float64, True, elements.BOUNDARY)
    assert SHARED_TANGENT <= set(vars(tangent))
