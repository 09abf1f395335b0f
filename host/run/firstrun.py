"""A one-process render's setup, step by step: on a first run each step's kernels compile for
seconds to tens of seconds with nothing else to show, so each compiled step is said as it ends
(with its seconds and the steps still to come), and the setup's seconds are split into
compiling, loading kernels from the disk cache, and building the engine, for the summary (the
structure build's step loads its build kernels first and says for how long: `Engine.stats`
structure_load_seconds)."""

import sys
import time

from meshnode.engine.kernelcache import CompileClock

STEPS = ("structure build", "tracing kernel", "primary rays")
# A pinhole render's order: its primary rays compile while the tracing kernel compiles aside
# (`host.run.aside`); a lens's primary rays focus by tracing, after the kernel.
PINHOLE_STEPS = ("structure build", "primary rays", "tracing kernel")
SAID = 0.05  # compiling shorter than this is not worth a line


class Setup:
    """Runs the setup's steps under one `kernelcache.compile_clock()` (`clock`), timing each;
    `say(line)` hears of every step that compiled (None: nothing is said); `order`: the
    steps in the order they run (STEPS or PINHOLE_STEPS)."""

    def __init__(self, clock: CompileClock, say=None, order=STEPS):
        self.clock, self.say, self.order = clock, say, order
        # step -> (wall, compiling, loading kernels or compiling them) seconds
        self.steps: dict[str, tuple[float, float, float]] = {}

    def run(self, step: str, fn, loading=None):
        """`fn()` as setup step `step` (one of STEPS); `loading(fn())`: the seconds of it
        spent loading or compiling kernels, where the rest builds (None: all of it loads)."""
        start, before = time.perf_counter(), self.clock.seconds
        out = fn()
        wall, compiled = time.perf_counter() - start, self.clock.seconds - before
        self.steps[step] = (wall, compiled, wall if loading is None else loading(out))
        if compiled >= SAID and self.say is not None:
            later = self.order[self.order.index(step) + 1 :]
            then = f"; then the {', the '.join(later)}" if later else ""
            self.say(f"compiled the {step} in {compiled:.1f} s{then}")
        return out

    def seconds(self) -> dict[str, float]:
        """compile: numba compiling; load: kernels loaded from the disk cache and run once
        (numba's start-up with the first); build: the engine built from the scene (its
        tables, hierarchy or grid)."""
        compiled = sum(c for _, c, _ in self.steps.values())
        load = build = 0.0
        for wall, c, loading in self.steps.values():
            # compiling happens while kernels load (compiles on other threads count too:
            # never below 0)
            rest = max(0.0, wall - c)
            loaded = min(rest, max(0.0, loading - c))
            load, build = load + loaded, build + rest - loaded
        return {"compile_seconds": compiled, "load_seconds": load, "build_seconds": build}


def say_on_stderr(line: str) -> None:
    print(f"host: {line}", file=sys.stderr, flush=True)
