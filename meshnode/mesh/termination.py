"""Termination by waves on the torus's spanning tree (DESIGN.md 5), with message counters.

The root (node 0) sends a probe down the tree (`protocols.topology.Torus.parent`); a node passes
it to its children at once and, once it is idle and every child has echoed, echoes up: whether
any node of its subtree received a data message since its previous echo (dirty), and the data
messages the subtree has sent and received in all. A wave that comes back clean and balanced
ends the state: the root takes the next one and the next probe carries it down. Otherwise the
next wave starts at once.

One clean wave suffices. Waves follow one another (the root probes only after the last echo
came back), so every echo of wave k comes after every echo of wave k-1. A message sent after
its sender's echo k and received before its receiver's echo k was received after that
receiver's echo k-1, so its receiver is dirty in wave k: in a clean wave no message crosses the
echoes backwards, the counts are those of one consistent cut, and balanced counts mean no
message was in flight across it. Every node was idle at its echo, and within a state an idle
node wakes only for a message (its primaries, dealt tiles and stolen chunks are done before it
echoes): nothing can wake any node after the cut. So a node's own work need not dirty it: a
state whose nodes exchange no messages (image space) ends with the wave that brought it.

A wave costs 2 x `tree_depth` message flights (rows/2 + cols/2 each way) where the ring it
replaces took the size of the mesh: on 16x16, 32 against 256.

Pure: the service reports events (a data message sent or received, work done, a probe or an
echo arrived) and sends what the scheduler decides.
"""

from dataclasses import dataclass, field

from protocols.errors import BadFrame
from protocols.state import State


@dataclass(frozen=True)
class Probe:
    """Down the tree: wave `wave` has begun, in state `state`."""

    wave: int
    state: int


@dataclass(frozen=True)
class Echo:
    """Up the tree: a subtree's answer to wave `wave`: any node active since its last echo,
    and the data messages its nodes have sent and received since the render began."""

    wave: int
    dirty: bool
    sent: int
    received: int


@dataclass
class Termination:
    """One node's side of the protocol. `parent`: its parent in the tree (None at the root);
    `children`: the nodes it waits for; `states`: the states the render goes through, in
    order (`protocols.state.states_of`)."""

    node: int
    parent: int | None = None
    children: tuple = ()
    states: tuple = tuple(State)
    sent: int = 0
    received: int = 0
    dirty: bool = False  # received a data message since its last echo
    wave: int = 0  # the last wave whose probe came here
    holding: bool = False  # that wave awaits this node's echo
    echoes: dict = field(default_factory=dict)  # child -> Echo of this wave
    advances: list = field(default_factory=list)  # states the root moved to

    def on_sent(self, messages: int = 1) -> None:
        self.sent += messages

    def on_received(self, messages: int = 1) -> None:
        self.received += messages
        self.dirty = True

    @property
    def root(self) -> bool:
        return self.parent is None

    def probe_in(self, probe: Probe) -> None:
        """A wave reached this node (the root makes its own); DONE awaits no echo."""
        if probe.wave != self.wave + 1:
            raise BadFrame(f"STATE: wave {probe.wave} after wave {self.wave}")
        self.wave, self.echoes = probe.wave, {}
        self.holding = probe.state < State.DONE

    def echo_in(self, child: int, echo: Echo) -> None:
        """A child's answer to the current wave; anything else is a peer's error."""
        if child not in self.children:
            raise BadFrame(f"ECHO from node {child}, which is not a child of node {self.node}")
        if not self.holding or echo.wave != self.wave or child in self.echoes:
            raise BadFrame(f"ECHO: node {child} answered wave {echo.wave}, not the open one")
        self.echoes[child] = echo

    @property
    def ready(self) -> bool:
        """This node holds a wave and every child has answered it (the scheduler adds: and
        the node is idle)."""
        return self.holding and len(self.echoes) == len(self.children)

    def answer(self) -> Echo:
        """This subtree's echo; the node is clean again from now."""
        echoes = self.echoes.values()
        echo = Echo(
            self.wave,
            self.dirty or any(e.dirty for e in echoes),
            self.sent + sum(e.sent for e in echoes),
            self.received + sum(e.received for e in echoes),
        )
        self.dirty, self.holding, self.echoes = False, False, {}
        return echo

    def next_wave(self, state: int) -> Probe:
        """At the root, once ready: the next wave's probe, with the next state when this one
        came back clean and balanced."""
        echo = self.answer()
        if not echo.dirty and echo.sent == echo.received and state < State.DONE:
            state = int(next(s for s in self.states if s > state))
            self.advances.append(state)
        return Probe(self.wave + 1, state)
