"""The core stiffness k_c and Kawabata's wall (docs/model.md section 10).

Without a core spring (k_c = inf) Kawabata's law is a hard wall at g = C_wa + C_we: the
solver must converge with every closure below it (a step reaching it has energy +inf and
is halved). With k_c finite the series compliance 1/k_c adds R/k_c to each closure, so
the solution converges to the wall's one at first order in 1/k_c: the test measures the
order on a patch loaded until the closures reach 80 % of the wall (contact tangents there
about 10 times their value at first touch).
"""

import numpy as np

from dynfab.model.fabric import contact
from dynfab.model.fabric.model import FabricModel
from dynfab.solvers.static import StaticSolver
from independent import without_core_spring
from test_fabric_static import patch_scene


PATH = dict(control="force", values=(1.0, 3.0, 6.0), friction=None, weft_values=(0.5, 1.5, 3.0))
"""The load path: warps and wefts pulled."""


def solve(core_stiffness):
    """(solver, final state, records) of the loaded patch with k_c = `core_stiffness` [N/m];
    inf: no core spring (set on the structure, `independent.without_core_spring`: a scene
    takes finite numbers only)."""
    if core_stiffness == np.inf:
        model = without_core_spring(patch_scene(**PATH))
    else:
        model = FabricModel.from_scene(patch_scene(**PATH, core_stiffness=core_stiffness))
    solver = StaticSolver(model)
    state, records = solver.run()
    return solver, state, records


def test_without_a_core_spring_the_closures_stay_below_the_wall():
    solver, state, records = solve(np.inf)
    f = solver.model.structure
    assert np.all(f.tie_contact_law[:, 0] == np.inf)
    wall = f.tie_contact_law[0, 1] + f.tie_contact_law[0, 3]
    g = np.array([contact.closure(state.positions, f, c) for c in range(f.tie_a.size)])
    assert g.max() < wall and g.max() > 0.75 * wall  # near it, not past it
    assert all(r["residual"] <= solver.tolerance or r["rounding_floor"] for r in records)


def test_a_finite_core_spring_converges_to_the_wall_at_first_order():
    # |x(k_c) - x(inf)| = C / k_c + O(1/k_c^2): orders log10(e(k) / e(10 k)) from 1e5 to
    # 1e7 N/m are 1 within 0.02 (the next term is ~ (tangent / k_c) ~ 1e-2 of the first at
    # 1e5 N/m); the differences (>= 1e-9 m) are far above the solves' tolerance (||H^-1||
    # x 1e-11 N ~ 1e-12 m).
    _, reference, _ = solve(np.inf)
    errors = [np.abs(solve(k)[1].positions - reference.positions).max() for k in (1e5, 1e6, 1e7)]
    orders = np.log10(np.array(errors[:-1]) / np.array(errors[1:]))
    assert np.all(np.abs(orders - 1.0) <= 0.02)
