"""dynfab.timing.best_time: how many calls it times, on a fake clock (no wall-clock limits)."""

from __future__ import annotations

import itertools

import pytest

from dynfab import timing


@pytest.fixture
def clock(monkeypatch):
    """The perf_counter dynfab.timing reads: 0, 1, 2, ... (each timed call takes 1 s)."""
    ticks = itertools.count()
    monkeypatch.setattr(timing, "perf_counter", lambda: float(next(ticks)))


def counting():
    calls = []
    return calls, lambda: calls.append(len(calls) + 1) or len(calls)


@pytest.mark.parametrize("repeats, warm, until, most, calls", [
    (3, False, 0.0, None, 3),    # exactly `repeats` timed calls
    (3, True, 0.0, None, 4),     # plus one untimed warm-up call
    (2, False, 5.0, 200, 5),     # more until the timed calls add up to `until` (1 s each)
    (2, False, 5.0, 4, 4),       # ... but at most `most`
    (6, False, 5.0, 4, 6),       # `repeats` wins over a smaller `most`
])
def test_best_time_times_as_many_calls_as_its_rule_asks(clock, repeats, warm, until, most, calls):
    made, call = counting()
    best, result = timing.best_time(call, repeats, warm=warm, until=until, most=most)
    assert len(made) == calls and result == calls  # the last call's result
    assert best == 1.0  # the fake clock's duration of each call
