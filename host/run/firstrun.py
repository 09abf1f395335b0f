"""A one-process render's setup, step by step: on a first run each step's kernels compile for
seconds to tens of seconds with nothing else to show, so each compiled step is said as it ends
(with its seconds and the steps still to come), and the setup's seconds are split into
compiling, loading kernels from the disk cache, and building the engine, for the summary."""

import sys
import time

from meshnode.engine.kernelcache import CompileClock

STEPS = ("structure build", "tracing kernel", "primary rays")
SAID = 0.05  # compiling shorter than this is not worth a line


class Setup:
    """Runs the setup's steps under one `kernelcache.compile_clock()` (`clock`), timing each;
    `say(line)` hears of every step that compiled (None: nothing is said)."""

    def __init__(self, clock: CompileClock, say=None):
        self.clock, self.say = clock, say
        self.steps: dict[str, tuple[float, float]] = {}  # step -> (wall, compiling) seconds

    def run(self, step: str, fn):
        """`fn()` as setup step `step` (one of STEPS)."""
        start, before = time.perf_counter(), self.clock.seconds
        out = fn()
        wall, compiled = time.perf_counter() - start, self.clock.seconds - before
        self.steps[step] = (wall, compiled)
        if compiled >= SAID and self.say is not None:
            later = STEPS[STEPS.index(step) + 1 :]
            then = f"; then the {', the '.join(later)}" if later else ""
            self.say(f"compiled the {step} in {compiled:.1f} s{then}")
        return out

    def seconds(self) -> dict[str, float]:
        """compile: numba compiling; load: kernels loaded from the disk cache and run once;
        build: the engine built from the scene (its tables, hierarchy or grid)."""
        # (compiles on other threads count too: never below 0)
        wall = {s: max(0.0, w - c) for s, (w, c) in self.steps.items()}
        return {
            "compile_seconds": sum(c for _, c in self.steps.values()),
            "load_seconds": sum(v for s, v in wall.items() if s != "structure build"),
            "build_seconds": wall.get("structure build", 0.0),
        }


def say_on_stderr(line: str) -> None:
    print(f"host: {line}", file=sys.stderr, flush=True)
