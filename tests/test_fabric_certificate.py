"""The fabric's step certificate (`dynfab.solvers.certificate.certify_patch`, docs/model.md
section 6 and "Stability and accuracy of a converged step"), against the dense Hessian.

- A stable friction step of the 3 x 4 test patch ("affine" planes, whose end nodes join
  the crossings' blocks): the record's lowest_eigenvalue is a Rayleigh quotient (at least
  numpy's lowest eigenvalue of the dense Hessian, up to its rounding) and the dense lowest
  lies in its proved bracket [lowest - lowest_eigenvalue_error, lowest]; error_estimate is
  the residual times ||H^-1||_inf within Hager-Higham's factor (a lower bound, in practice
  within 3), and the unknown it names has the largest row of |H^-1|.
- A saddle (held wefts, warps pushed in, Newton's equilibrium before the escape): the same
  bracket around the dense (negative) lowest eigenvalue, from the escape's shift-invert
  Lanczos below the spectrum.
- The bound bounds: a step solved at a loose tolerance lies within its error_estimate (plus
  the tight solve's) of the same step solved at a tight one, statically and dynamically.
- The record: a fabric step holds every name of `dynfab.solvers.contract.STEP_KEYS`, each documented
  in `dynfab.results.file.UNITS`.
"""

import numpy as np
import pytest

from dynfab.solvers import certificate
from dynfab.model.fabric.model import FabricModel
from dynfab.solvers.by_name import make_solver
from dynfab.solvers.static import StaticSolver
from dynfab.results.file import units_of
from dynfab.solvers.contract import STEP_KEYS
from dynfab.model.loading import prescribe_ends
from independent import fabric_scene
from test_fabric_static import FRICTION, K_C, WARP, WEFT, patch_model

EPS = np.finfo(float).eps


def dense(H):
    """(eigenvalues ascending, |H^-1| row sums) of the symmetrised dense H."""
    A = 0.5 * (H + H.T)
    return np.linalg.eigvalsh(A), np.abs(np.linalg.inv(A)).sum(axis=1)


def assert_bracket(lowest, error, eigenvalues, H):
    """The dense lowest eigenvalue in [lowest - error, lowest + its rounding] (a Rayleigh
    quotient's rounding, 1e3 eps ||H||), the bracket within 1 % of |lowest| (of use, as the
    one-yarn model's)."""
    assert lowest - error <= eigenvalues[0] <= lowest + 1e3 * EPS * np.abs(H).max()
    assert 0 <= error <= 1e-2 * abs(lowest)


def assert_stable_step_certified(solver, start, state, record) -> np.ndarray:
    """A stable step's record against the dense Hessian it certified (F_T frozen at its
    limits, the step's own anchors): the lowest eigenvalue positive and in its bracket, the
    error_estimate the residual times ||H^-1||_inf within Hager-Higham's factor 3 (a lower
    bound of the norm). Returns the rows' 1-norms of H^-1."""
    assert record["stable"] and record["negative_eigenvalues"] == 0
    H = solver.backend.hessian(state.positions, start.anchors,
                               record["friction_limit"].ravel()).toarray()
    eigenvalues, rows = dense(H)
    assert eigenvalues[0] > 0
    assert_bracket(record["lowest_eigenvalue"], record["lowest_eigenvalue_error"], eigenvalues, H)
    residual, norm = record["residual"], rows.max()
    assert residual > 0
    assert residual * norm / 3 <= record["error_estimate"] <= residual * norm * (1 + 1e-8)
    return rows


def test_a_stable_step_brackets_the_dense_lowest_eigenvalue_and_bounds_its_error():
    solver = StaticSolver(patch_model("force", (0.2,), FRICTION, weft_values=(0.05,),
                                            planes="affine"))
    start = solver.initial_state()
    state, record = solver.step(start, (0.2, 0.05))
    rows = assert_stable_step_certified(solver, start, state, record)
    checked = certificate.certify_patch(solver.model, state.positions, start.anchors,
                                        record["friction_limit"].ravel())
    assert rows[checked.worst] >= rows.max() / 3


def test_a_saddle_brackets_the_dense_negative_lowest_eigenvalue():
    solver = StaticSolver(patch_model("displacement", (-3e-4,), None, hold="weft"))
    start = solver.initial_state()
    pos, anchors = start.positions.copy(), start.anchors.copy()
    prescribe_ends(solver.model.structure, pos, solver.model.yarn_loads(-3e-4, 0.0))
    info, limit = solver.backend.equilibrium(pos, np.zeros(solver.model.yarns), anchors)
    assert info.converged
    H = solver.backend.hessian(pos, anchors, limit).toarray()
    eigenvalues, rows = dense(H)
    checked = certificate.certify_patch(solver.model, pos, anchors, limit)
    result = checked.result
    assert result[certificate.NEGATIVES] == np.count_nonzero(eigenvalues < 0) > 0
    assert_bracket(result[certificate.LOWEST], result[certificate.LOWEST_ERROR], eigenvalues, H)
    assert rows.max() / 3 <= result[certificate.INVERSE_NORM] <= rows.max() * (1 + 1e-8)
    assert checked.vectors.shape[1] == min(result[certificate.NEGATIVES],
                                           certificate.ESCAPE_CANDIDATES)


def frictionless_patch(control, tolerance):
    """The 3 x 4 test patch without friction, one load step, solved to `tolerance` [N]."""
    value = 0.2 if control == "force" else 8e-4
    return FabricModel.from_scene(fabric_scene(
        WARP, WEFT, 3, 4, contact=dict(core_stiffness=K_C), static=dict(tolerance=tolerance),
        load=dict(control=control, values=[value], weft_values=[0.25 * value])))


@pytest.mark.parametrize("control", ["force", "displacement"])
def test_the_error_estimate_bounds_the_distance_to_a_tighter_solve(control):
    """|x - x*|_inf <= ||H^-1||_inf |f|_inf to first order (docs/model.md section 6): a step
    solved to 1e-6 N lies within its error_estimate of the exact equilibrium, and so within
    the sum of both bounds of the same step solved to 1e-10 N (the test patch's floor is
    about 1e-11 N). Frictionless: the Hessian is then the Jacobian of the residual. The
    dynamic relaxation, stopped at 1e-8 N, the same."""
    loose, tight = (make_solver(frictionless_patch(control, tolerance), "static")
                    for tolerance in (1e-6, 1e-10))
    _, rough = loose.step(loose.model.initial_state(), loose.model.load_values[0])
    _, exact = tight.step(tight.model.initial_state(), tight.model.load_values[0])
    assert exact["residual"] < rough["residual"]  # two states
    gap = max(np.abs(rough[name] - exact[name]).max() for name in ("positions", "weft_positions"))
    assert 0 < gap <= rough["error_estimate"] + exact["error_estimate"]
    model = frictionless_patch(control, 1e-8)
    relaxed = make_solver(model, "dynamic")
    _, dynamic = relaxed.step(model.initial_state(), model.load_values[0])
    gap = max(np.abs(dynamic[name] - exact[name]).max() for name in ("positions", "weft_positions"))
    assert 0 < gap <= dynamic["error_estimate"] + exact["error_estimate"]


def test_a_fabric_step_records_every_step_key():
    """The contract's names (`dynfab.solvers.contract.STEP_KEYS`: the certificate's stable, buckled,
    lowest_eigenvalue, lowest_eigenvalue_error and error_estimate among them), each with its
    units, whatever the model; the result file's root attributes say the accuracy the steps
    were held to, as a one-yarn run's."""
    model = frictionless_patch("force", 1e-10)
    solver = make_solver(model, "static")
    assert solver.attrs()["static_accuracy"] == model.scene.static.accuracy == 0.1  # the default
    _, record = solver.step(model.initial_state(), model.load_values[0])
    assert set(STEP_KEYS) <= set(record)
    for name in record:
        units_of(f"steps/{name}", model.control)  # raises for an undocumented name
    assert record["error_estimate"] > 0 and record["lowest_eigenvalue_error"] >= 0


def test_a_periodic_cell_step_brackets_the_dense_lowest_eigenvalue_and_bounds_its_error():
    """The periodic 2 x 4 cell with friction (tests/test_fabric_periodic.py: tied cell lengths,
    wrap springs, moving planes, all in the Hessian the certificate factors): its first load
    step's record brackets the dense lowest eigenvalue as the clamped patch's does, and its
    error_estimate is the residual times ||H^-1||_inf within Hager-Higham's factor."""
    from test_fabric_periodic import PATHS, cell

    solver = cell(2, 4, "force", FRICTION)
    start = solver.initial_state()
    load = (PATHS["force"][0][0], PATHS["force"][1][0])
    state, record = solver.step(start, load)
    assert_stable_step_certified(solver, start, state, record)
