"""The states a render moves through on every node (DESIGN.md 5): carried by termination
waves, reported in PROGRESS and shown by the live view, so both sides read them from here."""

from enum import IntEnum


class State(IntEnum):
    DOWNLOAD = 0  # objects arriving, grids building
    TRACE = 1  # primary rays generated, rays traced and passed
    REFINE = 2  # adaptive sampling's second pass (a pass-through otherwise)
    FLUSH = 3  # last pixel packets on their way to the host
    DONE = 4


EVERY_STATE = tuple(State)


def states_of(adaptive: bool) -> tuple[State, ...]:
    """The states a render goes through: REFINE (the second pass) and FLUSH (the kept
    pixels' last packets) only under adaptive sampling; without it they would hold nothing,
    yet each would cost termination waves (on the ring that came before them, the simulated
    8x8 image space spent more of its frame ending states than tracing)."""
    return EVERY_STATE if adaptive else (State.DOWNLOAD, State.TRACE, State.DONE)
