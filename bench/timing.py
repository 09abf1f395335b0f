"""Interleaved CPU timing: the one rule the ratios in bench/ are measured by.

This machine is shared: under load wall time moves several times over between runs (issue 42:
`bench.embree`'s ratios by up to 7x), and CPU time still moves with the cores' speed spells
(up to 25% within seconds). So a benchmark that compares A with B here:

- times the CPU seconds of the process doing the work (`time.process_time`: every thread of
  it; a child's through `child_cpu`), never the wall;
- takes turns, A B A B ... (`turns`), so each round's A and B share a spell of the machine;
- pins itself to one core (`pin_one_core`) when it compares one thread with one thread;
- prints each figure's median and spread (least to most) over the rounds (`Figure`), and a
  ratio as the median of the rounds' paired ratios, A over B in the same round (`Turns.ratio`),
  with their spread: a pair shares its spell, where two medians may not.
"""

import os
import resource
import statistics
import time
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass


@dataclass(frozen=True)
class Figure:
    """One quantity over the rounds: its median and spread (least and most), and the samples."""

    median: float
    low: float
    high: float
    samples: tuple[float, ...]

    @classmethod
    def of(cls, samples) -> "Figure":
        """The median and spread of `samples` (at least one)."""
        s = tuple(float(v) for v in samples)
        if not s:
            raise ValueError("a figure needs at least one sample")
        return cls(statistics.median(s), min(s), max(s), s)

    def map(self, fn: Callable[[float], float]) -> "Figure":
        """The figure of `fn` of every sample (rays / seconds: a rate's median and spread)."""
        return Figure.of(fn(v) for v in self.samples)

    def text(self, fmt: str = "{:.3f}") -> str:
        """'median (low-high)', each number written with `fmt`."""
        return f"{fmt.format(self.median)} ({fmt.format(self.low)}-{fmt.format(self.high)})"

    def fields(self, name: str) -> dict:
        """The figure as JSON fields: `name` (the median), `name`_low, _high and _all."""
        return {
            name: self.median,
            f"{name}_low": self.low,
            f"{name}_high": self.high,
            f"{name}_all": list(self.samples),
        }


def turns(names: Sequence[str], repeat: int) -> Iterator[tuple[int, str]]:
    """(round, name) in the order they are to be timed: every name once a round, in the order
    given, `repeat` rounds (A B A B ...)."""
    for r in range(repeat):
        for name in names:
            yield r, name


class Turns:
    """Seconds of named subjects gathered round by round (one sample per subject a round)."""

    def __init__(self) -> None:
        self.seconds: dict[str, list[float]] = {}

    def add(self, name: str, seconds: float) -> None:
        """The next round's `seconds` of `name`."""
        self.seconds.setdefault(name, []).append(seconds)

    def figure(self, name: str) -> Figure:
        """Median and spread of `name`'s seconds."""
        return Figure.of(self.seconds[name])

    def ratio(self, a: str, b: str) -> Figure:
        """Each round's `a` seconds over its `b` seconds (paired by round): their median and
        spread."""
        sa, sb = self.seconds[a], self.seconds[b]
        if len(sa) != len(sb):
            raise ValueError(f"{a} has {len(sa)} rounds, {b} {len(sb)}: not paired")
        return Figure.of(x / y if y > 0 else float("nan") for x, y in zip(sa, sb, strict=True))


def interleaved(
    subjects: Mapping[str, Callable[[], object]],
    repeat: int,
    clock: Callable[[], float] = time.process_time,
) -> tuple[Turns, dict[str, object]]:
    """Run every subject once a round, in turns, `repeat` rounds, each call timed on `clock`
    (this process's CPU seconds); (their seconds, each subject's last result)."""
    times, results = Turns(), {}
    for _, name in turns(list(subjects), repeat):
        start = clock()
        results[name] = subjects[name]()
        times.add(name, clock() - start)
    return times, results


def pin_one_core() -> int | None:
    """Pin every thread of this process to one core of those it may use (the last), so do the
    threads it starts from now on; the core, or None where only one is allowed (nothing to
    choose: the work shares that core with the other processes, and CPU time leaves their
    turns out, not what they do to its caches). Linux: elsewhere nothing is pinned (None)."""
    if not hasattr(os, "sched_setaffinity"):
        return None
    allowed = sorted(os.sched_getaffinity(0))
    if len(allowed) < 2:
        return None
    core = allowed[-1]
    # sched_setaffinity(0) pins the calling thread only: pin each of the process's threads
    for tid in os.listdir("/proc/self/task"):
        try:
            os.sched_setaffinity(int(tid), {core})
        except (ProcessLookupError, PermissionError):  # a thread that ended meanwhile
            pass
    return core


def pinned_text(core: int | None) -> str:
    """What `pin_one_core` did, for a benchmark's first line."""
    return f"pinned to core {core}" if core is not None else "not pinned (one core allowed)"


def child_cpu() -> float:
    """User + system CPU seconds of this process's waited-for children so far: take the
    difference around a child's run (`resource.RUSAGE_CHILDREN`)."""
    usage = resource.getrusage(resource.RUSAGE_CHILDREN)
    return usage.ru_utime + usage.ru_stime
