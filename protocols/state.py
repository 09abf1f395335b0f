"""The states a render moves through on every node (DESIGN.md 5): carried by the state packet,
reported in PROGRESS and shown by the live view, so both sides read them from here."""

from enum import IntEnum


class State(IntEnum):
    DOWNLOAD = 0  # objects arriving, grids building
    TRACE = 1  # primary rays generated, rays traced and passed
    REFINE = 2  # adaptive sampling's second pass (a pass-through otherwise)
    FLUSH = 3  # last pixel packets on their way to the host
    DONE = 4
