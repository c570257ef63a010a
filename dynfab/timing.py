"""Wall-clock timing shared by the reports and the benchmarks: the fastest of repeated calls."""

from __future__ import annotations

import math
from time import perf_counter
from typing import Callable


def best_time(call: Callable, repeats: int = 1, *, warm: bool = False, until: float = 0.0,
              most: int | None = None) -> tuple[float, object]:
    """(fastest wall time [s], last result) of timed calls of `call`.

    At least `repeats` calls are timed; after them, more (up to `most`) while the timed
    calls add up to less than `until` [s], so that a short call gets enough tries that one
    of them runs while no other process holds the CPU. `warm`: one untimed call first
    (compiles, fills caches).
    """
    most = repeats if most is None else max(most, repeats)
    result = call() if warm else None
    best, total, count = math.inf, 0.0, 0
    while count < repeats or (total < until and count < most):
        began = perf_counter()
        result = call()
        elapsed = perf_counter() - began
        best, total, count = min(best, elapsed), total + elapsed, count + 1
    return best, result
