"""A first run's setup said step by step: what compiled, for how long, what comes next; and
the setup's seconds split into compiling, loading and building (`host.run.firstrun`)."""

import time

import numba

from host.run.firstrun import STEPS, Setup
from meshnode.engine.kernelcache import compile_clock


class FakeClock:
    """Compile seconds as a step's function says it compiled."""

    seconds = 0.0


def test_each_step_that_compiled_is_said_with_its_seconds_and_the_steps_after_it():
    clock, said = FakeClock(), []
    setup = Setup(clock, said.append)

    def compiles(seconds):
        def step():
            clock.seconds += seconds
            return seconds

        return step

    assert setup.run("structure build", compiles(5.0)) == 5.0
    setup.run("tracing kernel", compiles(0.0))  # loaded from the cache: nothing said
    setup.run("primary rays", compiles(0.7))
    assert said == [
        "compiled the structure build in 5.0 s; then the tracing kernel, the primary rays",
        "compiled the primary rays in 0.7 s",
    ]
    split = setup.seconds()
    assert split["compile_seconds"] == 5.7
    # the steps' own time apart from compiling (the fake compiles took no time: none left)
    assert split["build_seconds"] == 0.0 and 0 <= split["load_seconds"] < 0.5
    assert set(setup.steps) == set(STEPS)


def test_the_structure_builds_own_kernel_loading_counts_as_loading_not_building():
    clock = FakeClock()
    setup = Setup(clock)

    def build():
        time.sleep(0.03)
        return {"structure_load_seconds": 0.02}

    setup.run("structure build", build, loading=lambda out: out["structure_load_seconds"])
    split = setup.seconds()
    assert split["load_seconds"] == 0.02 and 0.0 < split["build_seconds"] < 0.5
    # compiling happens while they load (a first run): it is neither, and nothing goes below 0
    setup = Setup(clock)

    def compiles():
        clock.seconds += 5.0
        return {"structure_load_seconds": 5.01}

    setup.run("structure build", compiles, loading=lambda out: out["structure_load_seconds"])
    split = setup.seconds()
    assert split["compile_seconds"] == 5.0
    assert split["load_seconds"] == 0.0 and split["build_seconds"] == 0.0  # took no time


def test_the_clock_counts_compiling_and_not_what_was_compiled_before():
    @numba.njit(cache=False)
    def add_one(x):
        return x + 1

    with compile_clock() as first:
        add_one(1)
    with compile_clock() as again:
        add_one(2)  # compiled already: no compile event
    assert first.seconds > 0 and again.seconds == 0
