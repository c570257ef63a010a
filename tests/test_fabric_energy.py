"""Energy balance of the clamped patch with friction (docs/model.md sections 4, 10).

Along a load path the work of the end loads equals the elastic energy (stretch, bending,
contact) plus the energy of the stick springs plus the friction dissipation. The static
solver's incremental form (anchors fixed within a step, F_T at the step's end, the work
by the trapezoid rule on each step's end force and displacement) makes the balance hold
as the load increment falls, at first order (the dissipation F_T |delta xi| is a right-
endpoint rule for the integral of F_T along the slip). The test measures that order on a
patch with non-uniform warp loads (sticking and sliding crossings), under force and
displacement control.
"""

import numpy as np
import pytest

from dynfab.model.fabric import assembly
from dynfab.model.fabric.model import FabricModel
from dynfab.solvers.static import StaticSolver
from independent import fabric_scene

WARP = dict(length=0.04, segments=12, amplitude=0.5e-3, EA=13.72, EI=1.47e-7, kawabata_C=0.2e-3,
            kawabata_K=0.2)
WEFT = dict(length=0.03, segments=12, amplitude=0.4e-3, EA=10.0, EI=2e-7, kawabata_C=0.15e-3,
            kawabata_K=0.3)
FRICTION = dict(alpha=0.2, beta=1e3, contact_length=2e-3, fiber_radius=1e-3)
PATHS = {"force": (0.02, 0.01), "displacement": (2e-5, 0.0)}
"""(warp, weft) end values at the end of the linear load path [N or m]."""


def imbalance(control, steps):
    """work - (elastic + stick + dissipated) [J] at the end of the path in `steps` steps,
    and the dissipation [J]."""
    warp_end, weft_end = PATHS[control]
    fraction = np.arange(1, steps + 1) / steps
    solver = StaticSolver(FabricModel.from_scene(fabric_scene(
        WARP, WEFT, 3, 3, friction=FRICTION,
        load=dict(control=control, values=list(warp_end * fraction),
                  weft_values=list(weft_end * fraction), warp_factors=[1.0, 0.5, 0.2]))))
    state, records = solver.run()
    f = solver.model.structure
    terms = np.zeros(len(assembly.TERMS))
    c = f.tie_a.size
    assembly.energies(state.positions, f, np.zeros(f.load_node.size), state.anchors,
                      np.zeros(c), terms)
    elastic = terms[assembly.STRETCH] + terms[assembly.BENDING] + terms[assembly.CONTACT]
    sx = state.positions[f.tie_a, 0] - f.tie_plane[:, 0] - state.anchors[:, 0]
    sy = state.positions[f.tie_b, 0] - f.tie_plane[:, 1] - state.anchors[:, 1]
    stick = 0.5 * np.sum(f.tie_friction_law[:, 3] * (sx ** 2 + sy ** 2))
    assert records[-1]["sliding"].any() and not records[-1]["sliding"].all()
    return state.work - elastic - stick - state.dissipated[0], state.dissipated[0]


@pytest.mark.parametrize("control", ["force", "displacement"])
def test_work_equals_stored_plus_dissipated_at_first_order(control):
    # The order is the least-squares slope of log |imbalance| against log(increment) over
    # n = 16 ... 128 steps. Pairwise orders scatter by about 0.2 around 1 (crossings switch
    # between stick and slip at different steps on different meshes, changing the error
    # constant), so the fit is asserted, 1 within 0.2; the imbalance must fall at every
    # refinement and end below 1 % of the dissipation. A wrong dissipation or stick energy
    # leaves an O(1) imbalance, order about 0.
    steps = np.array([16, 32, 64, 128])
    results = [imbalance(control, n) for n in steps]
    errors = np.array([abs(e) for e, _ in results])
    order = np.polyfit(np.log(1.0 / steps), np.log(errors), 1)[0]  # e ~ h^order
    assert abs(order - 1.0) <= 0.2
    assert np.all(np.diff(errors) < 0)
    assert errors[-1] < 0.01 * results[-1][1]
