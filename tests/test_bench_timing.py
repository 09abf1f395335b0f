"""bench.timing, the rule the benchmarks' ratios are measured by: subjects timed in turns
(A B A B ...) on the clock given, medians and spreads of the samples, ratios paired by round,
and pinning that reaches every thread of the process."""

import os
import subprocess
import sys
from pathlib import Path

import pytest

from bench.timing import Figure, Turns, interleaved, turns

ROOT = Path(__file__).resolve().parents[1]


class FakeClock:
    """A clock that moves only when a subject says it worked: each call of a subject costs the
    next of its programmed seconds."""

    def __init__(self, costs: dict[str, list[float]]):
        self.now, self.costs, self.calls = 100.0, {k: list(v) for k, v in costs.items()}, []

    def __call__(self) -> float:
        return self.now

    def subject(self, name: str):
        def work():
            self.calls.append(name)
            self.now += self.costs[name].pop(0)
            return f"{name}{len(self.calls)}"

        return work


def test_turns_take_every_name_once_a_round_in_order():
    assert list(turns(["a", "b", "c"], 2)) == [
        (0, "a"),
        (0, "b"),
        (0, "c"),
        (1, "a"),
        (1, "b"),
        (1, "c"),
    ]
    assert list(turns(["a", "b"], 0)) == []


def test_interleaved_alternates_and_times_each_call_on_the_clock():
    costs = {"a": [2.0, 4.0, 9.0], "b": [1.0, 4.0, 3.0]}
    clock = FakeClock(costs)
    times, last = interleaved({n: clock.subject(n) for n in costs}, 3, clock=clock)
    assert clock.calls == ["a", "b", "a", "b", "a", "b"]
    assert times.seconds == costs
    assert last == {"a": "a5", "b": "b6"}  # each subject's last result
    a = times.figure("a")
    assert (a.median, a.low, a.high) == (4.0, 2.0, 9.0)
    # The ratio is the median of each round's a / b (2, 1, 3), not the ratio of the medians
    # (4 / 3): a round's two sides share a spell of the machine.
    r = times.ratio("a", "b")
    assert (r.median, r.low, r.high) == (2.0, 1.0, 3.0)
    assert r.median != a.median / times.figure("b").median


def test_figure_median_spread_and_mapped_rates():
    f = Figure.of([3.0, 1.0, 10.0, 2.0])
    assert (f.median, f.low, f.high) == (2.5, 1.0, 10.0)  # an even count: the middle two's mean
    assert f.text("{:.1f}") == "2.5 (1.0-10.0)"
    rates = Figure.of([1.0, 2.0, 4.0]).map(lambda s: 8.0 / s)  # falls as seconds rise
    assert (rates.median, rates.low, rates.high) == (4.0, 2.0, 8.0)
    assert Figure.of([5.0]).fields("s") == {"s": 5.0, "s_low": 5.0, "s_high": 5.0, "s_all": [5.0]}
    with pytest.raises(ValueError):
        Figure.of([])


def test_a_ratio_needs_paired_rounds():
    t = Turns()
    t.add("a", 1.0)
    t.add("a", 2.0)
    t.add("b", 1.0)
    with pytest.raises(ValueError, match="not paired"):
        t.ratio("a", "b")


@pytest.mark.skipif(
    not hasattr(os, "sched_getaffinity") or len(os.sched_getaffinity(0)) < 2,
    reason="pinning chooses among two or more allowed cores",
)
def test_pinning_reaches_threads_started_before_and_after():
    # In a child process: pinning this test's worker would slow the rest of the suite.
    code = """
import os, threading
from bench.timing import pin_one_core
stop = threading.Event()
before = threading.Thread(target=stop.wait)
before.start()
core = pin_one_core()
after = threading.Thread(target=stop.wait)
after.start()
masks = [os.sched_getaffinity(t.native_id) for t in (before, after)] + [os.sched_getaffinity(0)]
stop.set()
print(core, all(m == {core} for m in masks))
"""
    out = subprocess.run(
        [sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, check=True
    )
    core, every = out.stdout.split()
    assert int(core) in os.sched_getaffinity(0)
    assert every == "True"
