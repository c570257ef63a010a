"""The elements of a structure whose crossings slide along the yarns (docs/model.md 11.13), planar
or spatial: `planar_terms` or `spatial_terms` built on a `structure_forces.base` with `sliding`
(each node where it is, each segment's material now: `material_terms`; the slides' material
and friction forces), and the masses' Gershgorin rows from the host
(`dynfab.model.fabric.sliding.stiffest_rows`: the sliding term set's exact Hessian, every
crossing sticking and every contact at k_s), since the kernels' band knows no slide.

The relaxation masses of the slides are fictitious as the positions': m = dt^2 / (4 safety^2)
times their Gershgorin rows (section 5); an equilibrium (a zero of the force on every dof, the
slides' included) does not depend on them.
"""

from types import SimpleNamespace

from dynfab.kernels import host_rows, planar_terms, spatial_terms

ROWS_FROM_HOST = True
"""The masses' rows come from the host (module docstring)."""
BOUNDARY = True
"""The boundary couplings are the element module's: the planar one's moving planes, wrap
springs and tied families (a spatial structure has none)."""
REFUSALS = (
    ("method", "semi_implicit", "its tangent (the kernels' band and coupling products) has no "
     "row for a crossing's slide; the explicit method relaxes crossings that slide"),
    ("mode", "transient", "a slide has no physical mass yet (the material moving through a "
     "crossing); the relaxation's masses are fictitious"),
    ("masses", "physical", "a slide has no physical mass yet; fictitious masses relax it"),
    ("precision", "float32", "crossings that slide are checked in float64 only"),
)
"""The dynamic options crossings that slide refuse (docs/model.md 11.13)."""
REFUSED_BY = ("crossings that slide do not run", "11.13")
"""What refuses an option (its words, the verb included) and where docs/model.md says why
(`dynfab.solvers.dynamic`)."""
STIFFENS_IN_A_STEP = True
"""A load step can stiffen the elements past the masses at its start: a bay whose material is
drawn through its crossing shortens its segments (EA / L, EI / lbar), so the explicit
relaxation also stops where its residual stalls (`structure_explicit.check_step`) and runs
again with heavier masses (`dynfab.solvers.dynamic`)."""
STALL_MIN_STEPS = {2: 2_000, 3: 20_000}
"""Coordinates per node -> the time steps after which the explicit relaxation stops where its
residual has made no new low during the last half of its steps (`check_progress`): a planar
pull-out's stiffened tail oscillates from the first thousand steps on; a bias specimen's
relaxation, whose residual can rise for its first 8,000 steps (its soft shear mode still
ringing) before it falls to the tolerance, is given ten times as long (docs/model.md 11.13)."""


ELEMENTS = {2: planar_terms, 3: spatial_terms}
"""Coordinates per node -> the element module that slides (its `base.sliding`)."""


def structure_terms(scalar, friction: bool, boundary: bool, base) -> SimpleNamespace:
    """The planar or the spatial elements (`ELEMENTS` of `base.dim`), which `base.sliding`
    makes slide."""
    return ELEMENTS[base.dim].structure_terms(scalar, friction, boundary, base)


def planar_tangent_terms(scalar, friction: bool, boundary: bool) -> SimpleNamespace:
    """The stiffest tangent's rows and diagonals of a planar structure, from the host
    (`host_rows`); nothing for the kernels to assemble."""
    return host_rows.functions(scalar, 2)


def spatial_tangent_terms(scalar, friction: bool, boundary: bool) -> SimpleNamespace:
    """`planar_tangent_terms` in space."""
    return host_rows.functions(scalar, 3)
