"""The outcome of a Newton solve or of a friction strategy, for both backends of the static
solver (`dynfab.solvers.static`: `dynfab.solvers.newton_banded`, `dynfab.solvers.newton_sparse`),
and the budget of Newton iterations the fallbacks share (`dynfab.solvers.friction_chain`,
docs/model.md section 6).
"""

from __future__ import annotations

from dataclasses import dataclass

CYCLING, ONSET, STALLED = "cycling", "onset", "stalled"
"""Why a solve failed, in `NewtonInfo.reason` ("" for no convergence within the iterations):
a crossing that keeps opening and closing at g = 0, no open/closed state consistent with the
laws at the friction onset (docs/model.md section 4), a line search that found no lower
energy above the rounding floor (docs/model.md section 6)."""


@dataclass
class NewtonInfo:
    """What a Newton solve (or a strategy of solves) reached."""

    residual: float = float("inf")
    """Largest free force component [N] at the end."""
    iterations: int = 0
    """Newton iterations spent."""
    converged: bool = False
    at_floor: bool = False
    """Stopped at the rounding floor above the tolerance (docs/model.md section 6)."""
    floor: float = 0.0
    """The residual's rounding floor [N] at the last iteration where the backend knows it
    (the sparse one: 4 eps max|H_ii| max|r|); 0 where it does not report it."""
    crossing: int = -1
    """A failure's crossing to blame (the backend's tie index within the solved group), -1
    if none."""
    reason: str = ""
    """A failure's kind: CYCLING, ONSET, STALLED or "" (no convergence)."""
    solves: int = 0
    """Newton solves (frozen F_T or coupled) the strategy took (the sparse backend's
    `friction_solves`)."""


def within(residual: float, info: NewtonInfo, tolerance: float) -> bool:
    """A residual [N] within the tolerance, or within the rounding floor the solve of `info`
    stopped at."""
    return residual <= max(tolerance, info.floor if info.at_floor else 0.0)


def started(info: NewtonInfo) -> NewtonInfo:
    """An intermediate continuation stage's outcome: a start for the next stage."""
    info.converged = True
    return info


class Budget:
    """Newton iterations left to a load step's fallbacks (`dynfab.solvers.friction_chain`)."""

    def __init__(self, iterations: float):
        self.left = iterations

    def spend(self, iterations: int) -> None:
        self.left -= iterations

    @property
    def spent(self) -> bool:
        return self.left <= 0
