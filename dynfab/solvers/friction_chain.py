"""The static solver's friction strategy chain: one order for every model (docs/model.md
sections 4 and 6, and "Decisions": the friction chain).

A load step of a group of chains (a yarn on the banded backend, the whole structure on the
sparse one) is solved by the first strategy of CHAIN that its backend offers for it
(`NewtonBackend.strategies`), and where that fails by the next ones in CHAIN's order, each
from the step's start:

1. "unilateral": Newton on the unilateral contact law with F_T from Gralen's law at the
   iterate (the banded backend: its coupled Newton, which names a crossing that keeps
   opening and closing; the sparse one: Newton solves with F_T frozen, then the coupled
   Newton);
2. "relaxed": the fixed point on F_T under-relaxed (the sparse backend, R_0 > 0);
3. "sets": the open/closed active set at the scene's R_0 (`dynfab.solvers.active_set.direct_sets`,
   shared);
4. "continuation": the active set with R_0 lowered from 1e-3 N to the scene's
   (`dynfab.solvers.active_set.continuation`, shared; R_0 > 0);
5. "semismooth": the semismooth Newton with the contact forces as unknowns (the banded
   backend, R_0 > 0).

The banded backend offers (3)-(5) with R_0 > 0 and the sparse one (1)-(4); with R_0 = 0
both offer (1) and (3), without friction (1) alone (docs/model.md says why). Every strategy
after the first spends from one budget, FALLBACK_BUDGET x max_iterations Newton iterations
per step, and stops where it is spent (the active set after its current solve, so that a
failure still says where the onset stopped it). A step no strategy solves raises one
`SolverError` line naming the group, the crossing to blame (as the model counts it:
`crossing_name`) and the residual reached (`failure`).
"""

from __future__ import annotations

import numpy as np

from dynfab.solvers import active_set
from dynfab.errors import SolverError
from dynfab.solvers.newton_info import CYCLING, ONSET, STALLED, Budget, NewtonInfo

CHAIN = ("unilateral", "relaxed", "sets", "continuation", "semismooth")
"""The strategies in the order every backend tries them (module docstring)."""
FALLBACK_BUDGET = 150
"""Newton iterations of a step's fallbacks (every strategy after the first), in units of
`max_iterations`: after them the step stops with its failure (the steps that set it:
docs/model.md, "The friction onset in the fabric's static solver")."""
SHARED = {"sets": active_set.direct_sets, "continuation": active_set.continuation}
"""The strategies written once for both backends; the others are the backend's methods of
the same name."""
FALLBACK_WORDS = {"continuation": "continuation in R_0 from {start:.3g} N",
                  "semismooth": "the semismooth Newton on the contact forces"}
"""How a failure message names the fallbacks tried after the active set."""


def friction_chain(backend, problem) -> NewtonInfo:
    """The equilibrium of `problem` (a group's load step, its positions solved in place) by
    the strategies `backend` offers, in CHAIN's order, each after the first from the step's
    start and within the fallbacks' budget (each strategy stops where it is spent). Returns the converged strategy's info, its
    iterations and solves those of every strategy tried; raises `SolverError` (`failure`)."""
    offered = backend.strategies(problem)
    pos = problem.positions
    start = pos.copy() if len(offered) > 1 else None
    budget = Budget(np.inf)
    iterations = solves = 0
    failures = []
    for index, name in enumerate(offered):
        if index:
            if index == 1:
                budget = Budget(FALLBACK_BUDGET * backend.max_iterations)
            pos[:, :] = start
        shared = SHARED.get(name)
        info = (shared(backend, problem, budget) if shared is not None
                else getattr(backend, name)(problem, budget))
        iterations += info.iterations
        solves += info.solves
        if info.converged:
            info.iterations, info.solves = iterations, solves
            return info
        failures.append((name, info))
    raise SolverError(failure(backend, problem, failures, iterations))


def failure(backend, problem, failures, iterations: int) -> str:
    """The one line of a step no strategy solved: the reason and residual of the last strategy
    that gave a reason (else the last one's), the crossing the last to name one blamed (else
    the one with the largest residual, `worst_crossing`)."""
    info = next((i for _, i in reversed(failures) if i.reason), failures[-1][1])
    crossing = next((i.crossing for _, i in reversed(failures) if i.crossing >= 0), -1)
    where, tolerance = backend.group_name(problem), backend.tolerance
    if not np.isfinite(info.residual):
        return f"{where}: the residual became {info.residual} (non-finite state)"
    reached = f"residual {info.residual:.3g} N, tolerance {tolerance:.3g} N"
    worst, force = backend.worst_crossing(problem)
    crossing = worst if crossing < 0 else crossing
    name = backend.crossing_name(problem, crossing) if crossing >= 0 else "?"
    onset = backend.onset(problem)
    if info.reason == CYCLING:
        return (f"{where}: crossing {name} keeps opening and closing at g = 0, where Gralen's "
                f"friction limit jumps by beta*ell*r_f = "
                f"{backend.friction_constant(problem, crossing):.3g} N (R_0 = {onset:.3g} N); no "
                f"open/closed state consistent with the contact and friction laws was found "
                f"({reached})")
    if info.reason == ONSET:
        tried = " and by ".join(FALLBACK_WORDS[step].format(start=active_set.CONTINUATION_START)
                                for step, _ in failures if step in FALLBACK_WORDS)
        return (f"{where}: crossing {name} at the friction onset (R_0 = {onset:.3g} N): no "
                f"open/closed state consistent with the contact and friction laws was found, "
                f"also by {tried} ({iterations} Newton iterations, at most {FALLBACK_BUDGET} x "
                f"static.max_iterations; {reached})")
    if info.reason == STALLED:
        return (f"{where}: the line search stalled above the rounding floor ({iterations} "
                f"Newton iterations); {reached}")
    at = ("" if worst < 0 else f"; the largest residual at a crossing: {force:.3g} N at "
          f"crossing {backend.crossing_name(problem, worst)}")
    return f"{where}: no convergence in {iterations} Newton iterations; {reached}{at}"
