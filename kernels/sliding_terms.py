"""The planar structure's elements where its crossings slide along the yarns (docs/model.md
11.13): `planar_terms` built on a `structure_forces.base` with `sliding` (each node where it
is, each segment's material now, the slides' material and friction forces), and the masses'
Gershgorin rows from the host (`dynfab.model.fabric.sliding.stiffest_rows`: the sliding term
set's exact Hessian, every crossing sticking and every contact at k_s), since the kernels'
band knows no slide.

The relaxation masses of the slides are fictitious as the positions': m = dt^2 / (4 safety^2)
times their Gershgorin rows (section 5); an equilibrium (a zero of the force on every dof, the
slides' included) does not depend on them.
"""

from types import SimpleNamespace

from dynfab.kernels import host_rows, planar_terms

ROWS_FROM_HOST = True
"""The masses' rows come from the host (module docstring)."""
BOUNDARY = False
"""No moving planes, wraps or tied families (the scene refuses them with sliding crossings)."""
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
structure_terms = planar_terms.structure_terms
"""The planar elements; `base.sliding` makes them slide."""


def tangent_terms(scalar, friction: bool, boundary: bool) -> SimpleNamespace:
    """The stiffest tangent's rows and diagonals, from the host
    (`host_rows`); nothing for the kernels to assemble."""
    return host_rows.functions(scalar, 2)
