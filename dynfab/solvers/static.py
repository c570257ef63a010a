"""The static reference solver of every model: Newton on the exact Hessian (docs/model.md
section 6).

One solver, two backends, chosen from the structure, not from the model's kind
(`dynfab.model.structure.grounded`): where every tie is to ground and the chains are independent
(the paper's yarns), each chain's Hessian is banded and `dynfab.solvers.newton_banded.BandedNewton`
solves chain by chain in numba; otherwise (the woven fabric, chains tied to each other)
`dynfab.solvers.newton_sparse.SparseNewton` solves the whole structure on its sparse Hessian. Both
reach an equilibrium consistent with the contact and friction laws by one friction chain
(`dynfab.solvers.friction_chain`), certify it (`dynfab.solvers.certificate`: a banded LDL^T per
chain, or the sparse factorisation) and leave a saddle along a direction of negative curvature
(`dynfab.solvers.newton_backend`).
"""

from __future__ import annotations


from dynfab.solvers.contract import SLIDING_HALVINGS, step_in_halves
from dynfab.solvers.newton_backend import NewtonBackend
from dynfab.solvers.newton_banded import BandedNewton
from dynfab.solvers.newton_sparse import SparseNewton
from dynfab.model.structure import grounded, sliding

def backend_for(model, **options) -> NewtonBackend:
    """The backend of `model`'s structure: banded where it is grounded, else sparse (and
    where its crossings slide, whose term set is the sparse one's, docs/model.md 11.13)."""
    structure = model.structure
    kind = BandedNewton if grounded(structure) and not sliding(structure) else SparseNewton
    return kind(model, **options)


class StaticSolver:
    """Solves a model's load steps one after another (docs/model.md section 6): a
    `dynfab.solvers.contract.Solver` for every model.

    Every converged step is certified (`dynfab.solvers.certificate`): a saddle is left along a
    direction of negative curvature and solved again (at most MAX_ESCAPES times), and the
    step's position error bound must be within `accuracy` of its displacements.
    `certify=False` skips the escape (the step still reports its stability). `tolerance`,
    `max_iterations` and `accuracy` default to the scene's `[static]` table. `status`, if
    given, is called as status(text) within a step: after each group solved, and on the
    sparse backend once per Newton iteration and before the stability check (the banded
    backend's Newton runs compiled, in milliseconds, and cannot report).
    """

    name = "static"

    def __init__(self, model, *, tolerance: float | None = None, max_iterations: int | None = None,
                 accuracy: float | None = None, certify: bool = True, status=None):
        self.model = model
        self._options = dict(tolerance=tolerance, max_iterations=max_iterations,
                             accuracy=accuracy, certify=certify, status=status)
        self.backend = backend_for(model, **self._options)
        """`BandedNewton` or `SparseNewton` (module docstring), of the model's structure now
        (made again where a yarn end has left a sliding crossing, docs/model.md 11.13)."""

    @property
    def tolerance(self) -> float:
        return self.backend.tolerance

    @property
    def max_iterations(self) -> int:
        return self.backend.max_iterations

    @property
    def accuracy(self) -> float:
        return self.backend.accuracy

    def attrs(self) -> dict:
        """Root attributes describing the solver, for the result file."""
        return {"solver": self.name, "static_tolerance": self.tolerance,
                "static_max_iterations": self.max_iterations, "static_accuracy": self.accuracy}

    def step(self, state, load, halvings: int = SLIDING_HALVINGS):
        """The equilibrium under `load` from `state` (not modified): (new state, record), or a
        `dynfab.errors.SolverError` (`dynfab.solvers.contract.Solver.step`); where the
        crossings slide and Newton fails, the step in halves
        (`dynfab.solvers.contract.step_in_halves`)."""
        return step_in_halves(self._step, self.model, state, load, halvings,
                              self._options["status"])

    def _step(self, state, load):
        """`step` in one piece."""
        start = self.model.start_of_step(state, load)
        if self.backend.structure is not self.model.structure:
            self.backend = backend_for(self.model, **self._options)
        solution = self.backend.solve(start)
        return self.model.finish_step(state, start, solution)

    def initial_state(self):
        """The model's as-woven state."""
        return self.model.initial_state()

    def run(self, state=None):
        """Every load step of the model in sequence from `state` (default the as-woven one);
        returns (final state, records)."""
        state = self.initial_state() if state is None else state
        records = []
        for index in range(len(self.model.load_values)):
            state, record = self.step(state, self.model.step_load(index))
            records.append(record)
        return state, records
