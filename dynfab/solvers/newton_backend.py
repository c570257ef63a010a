"""What the static solver's two backends share: a load step solved group by group, each by
the friction chain and certified (docs/model.md section 6).

`dynfab.solvers.static.StaticSolver` hands a step's start to its backend (`NewtonBackend.solve`):
`dynfab.solvers.newton_banded.BandedNewton` where every tie is to ground (each chain its own group,
with a banded Hessian), `dynfab.solvers.newton_sparse.SparseNewton` otherwise (the whole structure
one group, a sparse Hessian). For each group (`problems`): the friction chain
(`dynfab.solvers.friction_chain`) reaches an equilibrium consistent with the contact and friction
laws, the certificate (`dynfab.solvers.certificate`: the inertia, the lowest eigenvalue, the error
bound; banded LDL^T or sparse factorisation) checks it, a saddle is left along a direction
of negative curvature and the group solved again (at most MAX_ESCAPES times, unless
`certify` is off), and the error bound is held to `accuracy` of the step's displacements.

A backend provides, per group `problem` (an object with `positions`, solved in place):
`strategies(problem)` (the names of `friction_chain.CHAIN` it offers, in that order), the
strategies that are its own (`unilateral`, `relaxed`, `semismooth`: (problem, budget) ->
`NewtonInfo`), the active set's primitives (`dynfab.solvers.active_set`: `closures_of`, `set_solve`,
`law_residual_of`, `onset`), the failure message's words (`group_name`, `crossing_name`,
`friction_constant`, `worst_crossing`), the certificate (`certify`, `escape`,
`check_accuracy`) and the step's solution (`solution`).
"""

from __future__ import annotations

import numpy as np

from dynfab.solvers.certificate import MAX_ESCAPES, StepStability
from dynfab.solvers.friction_chain import friction_chain
from dynfab.solvers.newton_info import NewtonInfo
from dynfab.model.step import StepSolution, StepStart


class NewtonBackend:
    """A static solver's backend (module docstring); the subclasses give the primitives."""

    reports: tuple[str, ...] = ()
    """Record entries the backend adds to the common ones ("friction_solves",
    "negative_eigenvalues")."""

    def __init__(self, model, *, tolerance: float | None = None,
                 max_iterations: int | None = None, accuracy: float | None = None,
                 certify: bool = True, status=None):
        static = model.scene.static
        self.model = model
        """The model (`dynfab.solvers.contract.RunModel`, or anything with `structure` and
        `scene`)."""
        self.structure = model.structure
        self.tolerance = static.tolerance if tolerance is None else tolerance
        """Newton's residual tolerance [N] (docs/model.md section 6), or the rounding floor
        where higher."""
        self.max_iterations = static.max_iterations if max_iterations is None else max_iterations
        self.accuracy = static.accuracy if accuracy is None else accuracy
        """Largest accepted error bound of a step relative to its largest displacement
        (docs/model.md, "Stability and accuracy of a converged step")."""
        self.certify_escapes = certify
        """Leave a saddle along a direction of negative curvature (the step still reports its
        stability without)."""
        self.status = status
        """Called as status(text) within a step (progress), or None."""

    def say(self, text: str) -> None:
        """Pass `text` to `status`, if set."""
        if self.status is not None:
            self.status(text)

    def solve(self, start: StepStart) -> StepSolution:
        """The step that `start` begins, every group solved and certified (module docstring);
        raises `dynfab.errors.SolverError` (one line) where a group cannot be."""
        problems = self.problems(start)
        count = len(problems)
        residual, iterations = np.zeros(count), np.zeros(count, np.int64)
        at_floor, solves = np.zeros(count, np.bool_), np.zeros(count, np.int64)
        negatives, stability = np.zeros(count, np.int64), StepStability(count)
        for k, problem in enumerate(problems):
            info, checked, escapes = self.certified(problem)
            residual[k], iterations[k], at_floor[k] = info.residual, info.iterations, info.at_floor
            solves[k], negatives[k] = info.solves, checked.negatives
            stability.record(k, checked.result, info.residual)
            stability.buckled[k] = escapes > 0
            self.check_accuracy(problem, checked, stability, k, info)
            if self.status is not None:  # the line is built only for a listener
                of = f" of {count}" if count > 1 else ""
                self.say(f"{self.group_name(problem)}{of} solved, {info.iterations} Newton "
                         f"iterations, residual {info.residual:.3g} N")
        fields = {"residual": residual, "iterations": iterations, "rounding_floor": at_floor,
                  "friction_solves": solves, "negative_eigenvalues": negatives,
                  **stability.fields()}
        fields = {name: value for name, value in fields.items()
                  if name not in ("friction_solves", "negative_eigenvalues")
                  or name in self.reports}
        return self.solution(start, problems, fields)

    def certified(self, problem) -> tuple[NewtonInfo, object, int]:
        """The group's equilibrium (`friction_chain`) and its certificate; from a saddle, the
        escape and the chain again, at most MAX_ESCAPES times (if no direction lowers the
        energy the state is accepted and reported as a saddle). Returns (the last chain's info
        with every chain's iterations, the certificate, the escapes taken)."""
        info = friction_chain(self, problem)
        checked = self.certify(problem, info)
        escapes = 0
        while self.certify_escapes and checked.negatives > 0 and escapes < MAX_ESCAPES:
            escaped = self.escape(problem, checked)
            if escaped is None:
                break
            problem.positions[:, :] = escaped
            escapes += 1
            more = friction_chain(self, problem)
            more.iterations += info.iterations
            more.solves += info.solves
            info = more
            checked = self.certify(problem, info)
        return info, checked, escapes
