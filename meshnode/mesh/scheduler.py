"""What a node does next: a pure state machine, no sockets and no clock (DESIGN.md 5 and 6).

The asyncio service and the simulated mesh (the host's cost pre-pass, the tests) drive it
alike, so a simulated mesh decides exactly as a real one. The driver reports events (rays
arrived, a pixel message arrived, messages sent, a termination probe or echo arrived, a batch
finished) and asks `next()` what to do: enter a new state, trace a batch (rays from other
nodes first once PASSED_MIN of them wait, or whenever no primary batch can start: they are
partly traced, and finishing them keeps queues short and cannot deadlock full links; then this
node's primary rays, while its links have room), flush buffered output once idle, pass a
termination wave on or answer it (`termination`), or wait for the next event (None). The
steps are the records of `meshnode.mesh.steps`; primary rays come from a feed
(`meshnode.mesh.feeds`) the driver sets up on entering a state.
"""

from collections import Counter, deque

import numpy as np

from meshnode.mesh.feeds import ChunkFeed, Primaries
from meshnode.mesh.steps import Enter, Flush, Give, SendEcho, SendProbe, Steal, Trace
from meshnode.mesh.termination import Echo, Probe, Termination
from protocols.errors import BadFrame
from protocols.records import joined
from protocols.state import EVERY_STATE, State

INCOMING_HIGH = 1_000_000  # queued incoming rays at which reading stops (~100 MB)
# Queued incoming messages merged into one batch of up to this many rays: a batch costs a
# kernel call, its scratch, its routing and a hand-off to the tracing thread whatever its size
# (with the driver's PASS_AGE: `python -m bench.passing`)
PASSED_BATCH = 16384
# Passed rays wait for a primary batch until this many are queued: a neighbour's batch
# sends a few dozen rays here, and traced one message at a time each paid a kernel call
# (~30 us) for a few microseconds of tracing.
PASSED_MIN = 1024


class Scheduler:
    """One node's decisions. `parent`, `children`: this node's place in the termination
    waves' tree (`protocols.topology.Torus.parent`; the root's parent is None); `threads`:
    batches traced at once; `incoming_high`: queued incoming rays above which the driver
    stops reading (it resumes once `may_read`, at a quarter of that); `passed_min`:
    queued incoming rays that go before a primary batch (PASSED_MIN)."""

    def __init__(
        self,
        node: int,
        parent: int | None = None,
        children: tuple = (),
        threads: int = 1,
        incoming_high: int = INCOMING_HIGH,
        neighbours=(),
        steal: bool = False,
        passed_min: int = PASSED_MIN,
        states: tuple = EVERY_STATE,
    ):
        self.node, self.threads = node, max(1, threads)
        # Stealing (MeshPlan.steal): neighbours asked in turn once this node has run out;
        # one that had nothing is not asked again in this state, but remembers who asked
        # (`hungry`) and gives to them unasked once it holds chunks to spare (a neighbour's
        # it stole): else a node whose neighbours had run out when it asked idled to the
        # end while its diagonal neighbour, which it cannot ask, still had work.
        self.steal, self.neighbours = steal, list(neighbours)
        self.asked: set[int] = set()
        self.steal_from: int | None = None  # the neighbour whose answer is awaited
        self.thieves: deque = deque()  # neighbours waiting for an answer from this node
        self.hungry: deque = deque()  # neighbours this node had nothing for
        self.spare = False  # chunks came in since `hungry` was last offered some
        self.chunks_taken = 0
        self.given_in: Counter = Counter()  # chunks given, by state (TRACE, REFINE)
        self.incoming_high = max(1, incoming_high)
        self.passed_min = passed_min
        # the states this render goes through; the root probes the first wave itself
        self.term = Termination(node, parent, tuple(children), states)
        self.state = State.DOWNLOAD
        self.probe: Probe | None = Probe(1, int(State.DOWNLOAD)) if parent is None else None
        # Queued rays by the engine that takes them (None: this node's own), and the engines
        # with rays queued, first come first: one batch traces one engine's parts.
        self.queued: dict[int | None, deque] = {}
        self.takers: deque = deque()
        self.incoming_rays = 0
        self.primaries = Primaries()
        self.in_flight = 0
        self.unflushed = False
        self.pending: deque = deque()  # decisions made, not yet handed out

    # ------------------------------------------------------------------ events
    def rays_in(self, rays: np.ndarray, message: bool = True, taker: int | None = None) -> bool:
        """Rays to trace here (from a RAYS message, or passed from this node to itself, for
        the engine of node `taker`: a copy it holds, or its own when None); True when the
        driver should stop reading until `may_read`."""
        if message:
            self.term.on_received()
        taker = None if taker == self.node else taker
        if not self.queued.get(taker):
            self.queued[taker] = deque()
            self.takers.append(taker)
        self.queued[taker].append(rays)
        self.incoming_rays += len(rays)
        return self.incoming_rays > self.incoming_high

    def message_in(self) -> None:
        """A counted data message (PIXELS) arrived and was handled."""
        self.term.on_received()

    def message_out(self, messages: int = 1) -> None:
        """Counted data messages (RAYS, PIXELS) left toward other nodes."""
        self.term.on_sent(messages)

    def probe_in(self, probe: Probe) -> None:
        """A wave from this node's parent (taken up by the next `next()`), checked here, as it
        arrives: the wave after the last one, while none is held, in no earlier state (a bad
        one fails the parent's link by name, not the work loop)."""
        if self.probe is not None or probe.state < self.state or probe.wave != self.term.wave + 1:
            raise BadFrame(
                f"STATE: wave {probe.wave} in state {probe.state} came while node "
                f"{self.node} is in state {int(self.state)} with wave {self.term.wave}"
            )
        self.probe = probe

    def echo_in(self, child: int, echo: Echo) -> None:
        """A child's answer to the wave this node holds."""
        self.term.echo_in(child, echo)

    def steal_request(self, thief: int) -> None:
        """A neighbour asked for chunks (a counted message): answered by the next `next()`."""
        self.term.on_received()
        self.thieves.append(thief)

    def given(self, giver: int, chunks: list) -> None:
        """A neighbour's answer (a counted message): chunks to trace here, or none; or its
        unasked gift, once it had chunks to spare after having none when asked."""
        self.term.on_received()
        if giver == self.steal_from:
            self.steal_from = None
        if chunks and isinstance(self.primaries, ChunkFeed):
            self.primaries.add(chunks, giver)
            self.chunks_taken += len(chunks)
            self.spare = bool(self.hungry)
        else:
            self.asked.add(giver)

    @property
    def incoming(self) -> bool:
        """Rays are queued to trace here."""
        return bool(self.takers)

    def _passed_batch(self) -> Trace:
        """The first queued engine's parts in order, merged up to PASSED_BATCH rays: a
        message holds the rays one batch of a neighbour sent here, often a few dozen, and
        every batch costs a kernel call, its scratch and its routing whatever its size."""
        taker = self.takers.popleft()
        queue = self.queued[taker]
        parts = [queue.popleft()]
        n = len(parts[0])
        while queue and n + len(queue[0]) <= PASSED_BATCH:
            parts.append(queue.popleft())
            n += len(parts[-1])
        if queue:
            self.takers.append(taker)  # the rest after the others' turns
        self.incoming_rays -= n
        self.in_flight += 1
        return Trace(joined(parts), False, taker)

    def batch_done(self) -> None:
        self.in_flight -= 1
        self.unflushed = True

    def output_waiting(self) -> None:
        """The driver holds output to send (rays relayed through this node): a flush is due
        before the node next idles or answers a wave."""
        self.unflushed = True

    @property
    def chunks_given(self) -> int:
        """Chunks of this node's rectangle neighbours took (MeshPlan.steal)."""
        return sum(self.given_in.values())

    @property
    def may_read(self) -> bool:
        return self.incoming_rays <= self.incoming_high // 4

    @property
    def done(self) -> bool:
        return self.state == State.DONE and self.probe is None and not self.pending

    # ------------------------------------------------------------------ decisions
    def next(self, room: bool = True):
        """The next thing to do (None: wait for an event). `room`: the links can take more
        output, so new primary rays may start."""
        while True:
            if self.pending:
                return self.pending.popleft()
            if self.probe is not None:
                self._take_probe()
                continue
            if self.thieves:
                thief = self.thieves.popleft()
                chunks = self._take(thief)
                if not chunks and thief not in self.hungry:
                    self.hungry.append(thief)
                return Give(thief, chunks)
            if self.spare:  # chunks came in: those who found none here may use some
                self.spare = False
                for thief in list(self.hungry):
                    if chunks := self._take(thief):
                        self.hungry.remove(thief)
                        self.pending.append(Give(thief, chunks))
                continue
            free = self.in_flight < self.threads
            tracing = self.state in (State.TRACE, State.REFINE) and (
                bool(self.primaries) or self.primaries.waiting
            )
            primary = tracing and free and room and bool(self.primaries)
            if self.incoming and free and (self.incoming_rays >= self.passed_min or not primary):
                return self._passed_batch()
            if primary:
                rays = self.primaries.pop()
                self.in_flight += 1
                return Trace(rays, True, tile=self.primaries.label)
            if (target := self._steal_target()) is not None:
                self.steal_from = target
                return Steal(target)
            if self.in_flight:
                return None
            if self.unflushed:
                self.unflushed = False
                return Flush()
            if not self.term.ready or tracing or self.incoming or self.steal_from is not None:
                return None
            self._answer()

    def _take(self, thief: int) -> list:
        """Chunks of this node's feed for `thief` (none outside a chunked state), counted."""
        feed = self.primaries
        chunks = feed.take(thief) if isinstance(feed, ChunkFeed) else []
        if chunks:
            self.given_in[self.state.name] += len(chunks)
        return chunks

    def _steal_target(self) -> int | None:
        """The neighbour to ask for chunks when out of chunked primaries (TRACE, or adaptive
        sampling's REFINE) with no answer awaited: the first not yet found empty in this
        state (None: nobody to ask)."""
        if (
            not self.steal
            or self.state not in (State.TRACE, State.REFINE)
            or not isinstance(self.primaries, ChunkFeed)
            or self.primaries
            or self.steal_from is not None
        ):
            return None
        return next((m for m in self.neighbours if m not in self.asked), None)

    def _enter(self, state: State) -> Enter:
        self.state = state
        self.asked = set()
        self.hungry = deque()
        self.spare = False
        self.primaries = Primaries()
        return Enter(state)

    def _take_probe(self) -> None:
        """A wave reached this node: on to the children at once (so they start a new
        state's primaries now, not once this node has traced its own), then into its state."""
        probe, self.probe = self.probe, None
        self.term.probe_in(probe)
        self.pending.extend(SendProbe(probe, child) for child in self.term.children)
        if probe.state > self.state:
            self.pending.append(self._enter(State(probe.state)))

    def _answer(self) -> None:
        """Idle, and every child has answered: echo to the parent, or at the root judge
        the wave and begin the next."""
        if self.term.root:
            self.probe = self.term.next_wave(int(self.state))
        else:
            self.pending.append(SendEcho(self.term.answer(), self.term.parent))
