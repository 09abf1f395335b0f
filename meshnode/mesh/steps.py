"""What a Scheduler tells its driver to do next: one frozen record per kind of step.

`Scheduler.next()` returns one of these (or None: wait for the next event); the driver acts on
it and reports back through the scheduler's events.
"""

from dataclasses import dataclass

import numpy as np

from meshnode.mesh.termination import Echo, Probe
from protocols.state import State


@dataclass(frozen=True)
class Enter:
    """The mesh moved to `state`: the driver sets up its primaries (`Scheduler.primaries`),
    flushes finished pixels or reports statistics."""

    state: State


@dataclass(frozen=True)
class Trace:
    """Trace this batch (with the engine of node `taker`: this node's own when None, or a
    copy it holds); call `batch_done` when it is. `tile`: the dealt tile a primary batch
    belongs to (dynamic image space; -1: none)."""

    rays: np.ndarray
    primary: bool
    taker: int | None = None
    tile: int = -1


@dataclass(frozen=True)
class Flush:
    """Nothing is being traced: send buffered output (deposits) now."""


@dataclass(frozen=True)
class Steal:
    """Ask neighbour `to` for unstarted chunks (this node has run out of primary rays)."""

    to: int


@dataclass(frozen=True)
class Give:
    """Answer neighbour `to`'s STEAL with these chunks (maybe none)."""

    to: int
    chunks: list


@dataclass(frozen=True)
class SendProbe:
    """Pass a termination wave on to child `to` in the tree."""

    probe: Probe
    to: int


@dataclass(frozen=True)
class SendEcho:
    """Answer the wave to parent `to`."""

    echo: Echo
    to: int
