"""Termination by the state packet on the ring (DESIGN.md 5), with Safra's message counters.

Pure: the service reports events (a data message sent or received, work done, the packet
arrived, the node fell idle) and forwards the packet when told. A node that was active since
it last passed the packet on marks itself `last_busy`; the packet coming back to its
`last_busy` node unchanged means a whole round saw no activity, and the state advances only if
the data messages counted as sent equal those counted as received, so a ray still on a link
(sent, not yet received) can never be mistaken for the end of a state.
"""

from dataclasses import dataclass, field

import numpy as np

from protocols.state import State


@dataclass
class Packet:
    """The state packet: current state, last busy node, round number, per-node counters."""

    state: int
    last_busy: int
    round: int
    sent: np.ndarray
    received: np.ndarray

    @classmethod
    def start(cls, n_nodes: int, first: int = 0) -> "Packet":
        zeros = np.zeros(n_nodes, np.int64)
        return cls(int(State.DOWNLOAD), first, 0, zeros, zeros.copy())

    def balanced(self) -> bool:
        return int(self.sent.sum()) == int(self.received.sum())


@dataclass
class Termination:
    """One node's side of the protocol; `states`: the states the render goes through, in
    order (`protocols.state.states_of`)."""

    node: int
    states: tuple = tuple(State)
    sent: int = 0
    received: int = 0
    dirty: bool = True  # active since the packet last left; a node starts out busy
    visits: int = 0
    advances: list = field(default_factory=list)

    def on_sent(self, messages: int = 1) -> None:
        self.sent += messages
        self.dirty = True

    def on_received(self, messages: int = 1) -> None:
        self.received += messages
        self.dirty = True

    def on_work(self) -> None:
        self.dirty = True

    def pass_on(self, packet: Packet) -> Packet:
        """Called when the node holds the packet and is idle: returns the packet to forward,
        with the state advanced when a clean round with balanced counters came back here."""
        self.visits += 1
        packet.sent[self.node] = self.sent
        packet.received[self.node] = self.received
        if self.dirty:
            packet.last_busy = self.node
            self.dirty = False
        elif packet.last_busy == self.node and packet.balanced():
            if packet.state < State.DONE:
                packet.state = int(next(x for x in self.states if x > packet.state))
                self.advances.append(packet.state)
        packet.round += 1
        return packet
