"""The open/closed active set of the crossings and the continuation in R_0 (docs/model.md
section 4), written once for both backends of the static solver (`dynfab.solvers.newton_banded`,
`dynfab.solvers.newton_sparse`): two strategies of the friction chain
(`dynfab.solvers.friction_chain`).

Every crossing's contact branch (`dynfab.model.terms.contact`: OPEN, CLOSED) is held fixed during a
Newton solve, and the set is updated where the state contradicts it (`update_set`) until
the state agrees with it (`solve_sets`): first at the scene's R_0 from the previous step's
state (`direct_sets`), then, where that fails, with R_0 lowered from CONTINUATION_START to
the scene's value (`continuation`, `onset_stages`).

A backend offers the primitives (the `dynfab.solvers.newton_backend.NewtonBackend` contract):
`closures_of(problem)` (g [m] of the problem's crossings at its positions), `set_solve(problem,
branch, onset, max_iterations, direct)` (the equilibrium with the set held and R_0 = onset,
in place, a `NewtonInfo`), `law_residual_of(problem, onset)` (the unilateral law's residual
with F_T from Gralen's law at R_0 = onset) and `onset(problem)` (the scene's R_0), with its
`tolerance` and `max_iterations`.
"""

from __future__ import annotations

import numpy as np

from dynfab.solvers.newton_info import CYCLING, ONSET, Budget, NewtonInfo, started, within
from dynfab.model.terms import contact

MAX_FLIPS = 12
"""Open/closed switches of one crossing after which the iteration is declared cycling (the
literal jump law, R_0 = 0)."""
MAX_SET_UPDATES = 40
"""Open/closed set updates per continuation stage with an onset force (docs/model.md section 4)."""
DIRECT_SET_UPDATES = 4
"""Set updates tried at the scene's R_0 before the continuation (most steps need 0 or 1)."""
DIRECT_ITERATIONS = 50
"""Newton iterations per set in that first attempt."""
CONTINUATION_FACTORS = (2.0, 1.25, 1.05)
"""R_0 falls by this factor per stage, the next one if the continuation fails (a factor of
10 was tried and dropped: docs/model.md, "Decisions", friction onset)."""
CONTINUATION_START = 1e-3
"""R_0 [N] the continuation starts from (docs/model.md section 4: Newton converges there in about 20
iterations from the previous step's state on the paper's yarn)."""


def update_set(g, branch, seen, all_first: bool = False) -> np.ndarray:
    """Switch the crossings whose branch the closures g [m] contradict; returns their indices.

    A closed crossing needs R >= 0 (g >= 0), an open one g <= 0 (docs/model.md section 4); where
    both hold (g = 0) the two branches agree. The one that contradicts its branch most
    switches, unless that gives a set already tried (`seen`, the sets as bytes): then the
    next ones, one at a time, and last all of them at once; with `all_first`, all of them
    at once first (the lateral contacts, docs/model.md 11.5). Returns an empty array when
    consistent, None when every choice was tried.
    """
    wrong = ((branch == contact.CLOSED) & (g < 0.0)) | ((branch == contact.OPEN) & (g > 0.0))
    indices = np.flatnonzero(wrong)
    if indices.size == 0:
        return indices
    singles = [np.array([j]) for j in indices[np.argsort(-np.abs(g[indices]))]]
    candidates = [indices] + singles if all_first else singles + [indices]
    for switch in candidates:
        trial = branch.copy()
        trial[switch] = contact.OPEN + contact.CLOSED - trial[switch]
        if trial.tobytes() not in seen:
            branch[:] = trial
            seen.add(trial.tobytes())
            return switch
    return None


def onset_stages(target: float, factor: float):
    """The R_0 [N] of the continuation's stages: CONTINUATION_START (or `target` if larger),
    divided by `factor` per stage, ending at `target` > 0 (docs/model.md section 4)."""
    onset = max(CONTINUATION_START, target)
    while onset != target:
        yield onset
        onset = max(target, onset / factor)
    yield target


def natural_set(g) -> np.ndarray:
    """The open/closed set the unilateral law gives at the closures g [m]: CLOSED where g > 0."""
    return np.where(g > 0.0, contact.CLOSED, contact.OPEN).astype(np.int64)


def solve_sets(backend, problem, branch, onset: float, max_updates: int, final: bool,
               budget: Budget, max_iterations: int, direct: bool = False) -> NewtonInfo:
    """Newton on fixed sets at R_0 = `onset`, `branch` updated in place between the solves
    (`update_set`) until the state agrees with it (docs/model.md section 4), in place.

    A set is accepted when its solve converged and the unilateral law's residual (F_T from
    the law at R_0 = `onset`) is within the tolerance or the solve's rounding floor, or when
    the converged state contradicts no crossing of the set (the two laws then give the same
    forces). A solve that ends short of the tolerance still updates the set, while its state
    is finite. An intermediate stage (not `final`) is only the next stage's start and always
    succeeds. Each solve is at most `max_iterations` long and spends from `budget`; `direct`:
    the solves start from the previous step's state (the backend may take another first
    Newton there). A failure's info names the crossing switched most often (of equals the
    highest index), else the one nearest g = 0, why (CYCLING where every set the updates
    propose was tried, or they ran out), and the laws' residual at the state reached.
    """
    seen = {branch.tobytes()}
    iterations = solves = 0
    flips = np.zeros(branch.size, np.int64)
    info = NewtonInfo()
    for _ in range(max_updates):
        info = backend.set_solve(problem, branch.copy(), onset, max_iterations, direct)
        budget.spend(info.iterations)
        iterations += info.iterations
        solves += info.solves
        info.iterations, info.solves = iterations, solves
        if not np.isfinite(info.residual):
            break
        residual = backend.law_residual_of(problem, onset)
        if info.converged and within(residual, info, backend.tolerance):
            info.residual = residual
            return info
        if budget.spent:
            break
        switched = update_set(backend.closures_of(problem), branch, seen)
        if switched is None:  # every set the updates propose was tried
            if not final:
                return started(info)
            info.reason = CYCLING
            break
        if switched.size == 0:  # consistent
            if info.converged or not final:
                return started(info)
            break
        flips[switched] += 1
    else:
        if not final:
            return started(info)
        info.reason = CYCLING
    info.converged = False
    info.crossing = (int(flips.size - 1 - np.argmax(flips[::-1])) if flips.any()
                     else int(np.argmin(np.abs(backend.closures_of(problem)))))
    if np.isfinite(info.residual):  # the residual reached: of the laws, not of the set
        info.residual = backend.law_residual_of(problem, onset)
    return info


def direct_sets(backend, problem, budget: Budget) -> NewtonInfo:
    """The active set at the scene's R_0 from the previous step's state (the friction chain's
    "sets"): DIRECT_SET_UPDATES updates with Newton solves of at most DIRECT_ITERATIONS; with
    R_0 = 0 (the literal jump law, no continuation) MAX_FLIPS updates, and a cycle names the
    crossing switched most often."""
    target = backend.onset(problem)
    return solve_sets(backend, problem, natural_set(backend.closures_of(problem)), target,
                      DIRECT_SET_UPDATES if target > 0.0 else MAX_FLIPS, True, budget,
                      min(backend.max_iterations, DIRECT_ITERATIONS), direct=True)


def continuation(backend, problem, budget: Budget) -> NewtonInfo:
    """Solve with R_0 lowered from CONTINUATION_START to the scene's value R_0 > 0 (the friction
    chain's "continuation", docs/model.md section 4), in place: each stage from the last
    one's state and set (`onset_stages`), by the factors CONTINUATION_FACTORS in turn, each
    from the step's start; an intermediate stage is only a start. Stops where the budget is
    spent or a state is not finite. A failure's reason is ONSET, with the laws' residual at
    the scene's R_0."""
    target = backend.onset(problem)
    pos = problem.positions
    start = pos.copy()
    iterations = solves = 0
    info = NewtonInfo()
    for factor in CONTINUATION_FACTORS:
        pos[:, :] = start
        branch = natural_set(backend.closures_of(problem))
        for onset in onset_stages(target, factor):
            info = solve_sets(backend, problem, branch, onset, MAX_SET_UPDATES, onset == target,
                              budget, backend.max_iterations)
            iterations += info.iterations
            solves += info.solves
            if not np.isfinite(info.residual) or budget.spent:
                break
        # solved only by the last stage: an intermediate one is a start, not the answer
        info.converged = info.converged and onset == target
        if info.converged or budget.spent:
            break
    info.iterations, info.solves = iterations, solves
    if not info.converged:
        info.reason = ONSET
        if np.isfinite(info.residual):
            info.residual = backend.law_residual_of(problem, target)
    return info
