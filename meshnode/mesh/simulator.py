"""A mesh simulated in one process: every node's NodeCore driven by its own Scheduler, as on
a real mesh, with messages held in a queue instead of sent on sockets.

Each round, every node (in a seeded random order) acts until it has traced one batch or has
nothing to do; messages sent in a round arrive at the start of the next (or `delay` rounds
later on one link), so rays and the state packet overtake each other as on a network. The
host's cost pre-pass runs it on a coarse image; the tests check the distributed algorithm
with it (image, counts, termination under delays) against the single-node render.

Rounds give every node one batch a turn whatever the batch costs, so a node with cheap work
never runs ahead of one with dear work, and what stealing and dynamic tiles even out is not
seen. With `clock="work"` every node keeps its own clock in work units instead: a batch
moves its node's clock on by the work it did, the node with the earliest clock acts next,
a message arrives `latency` units after it was sent, and a node with nothing to do waits
for the next message to it. `bench.predict` predicts larger meshes so.
"""

import heapq
from collections import defaultdict
from dataclasses import dataclass, field

import numpy as np

from meshnode.mesh.node import EYE_BATCH, HOST, EngineCache, NodeCore
from meshnode.mesh.scheduler import (
    PASSED_MIN,
    Enter,
    Flush,
    Give,
    Scheduler,
    SendPacket,
    Steal,
    TileDealer,
    Trace,
    deal_order,
)
from meshnode.mesh.stats import add_counts, work_units
from protocols.render import Partition, RenderSpec
from protocols.state import State
from protocols.topology import Torus

MAX_ROUNDS = 1_000_000
# A message's flight under clock="work", in work units: about 0.1 ms on loopback (an event
# of tetra's costs ~3 ns: one node's tracing CPU / its work units, 384x384 at 32 spp).
LATENCY = 30_000


@dataclass
class NodeRecord:
    """What one simulated node did."""

    objects: int = 0
    batches: int = 0
    rays_sent: int = 0
    sent_to: dict = field(default_factory=lambda: defaultdict(int))  # node -> rays sent it
    rays_received: int = 0
    packet_visits: int = 0
    chunks_given: int = 0  # chunks of its rectangle neighbours took (MeshPlan.steal)
    chunks_taken: int = 0  # chunks it took from neighbours
    given_in: dict = field(default_factory=dict)  # chunks given by state (TRACE, REFINE)
    counts: dict = field(default_factory=lambda: defaultdict(int))

    @property
    def cost(self) -> int:
        """Work done, in the engine's own units (`meshnode.mesh.stats.work_units`)."""
        return work_units(self.counts)


@dataclass
class Outcome:
    deposits: list  # DEPOSIT arrays that reached the host
    nodes: list[NodeRecord]
    rounds: int  # rounds; under clock="work" the turns taken
    makespan: float = 0.0  # clock="work": the last node's clock at the end (work units)

    def totals(self) -> dict[str, int]:
        out: dict[str, int] = defaultdict(int)
        for n in self.nodes:
            for k, v in n.counts.items():
                out[k] += v
        return dict(out)


def simulate(
    scenes,
    spec: RenderSpec,
    part: Partition,
    seed: int = 0,
    delay=None,
    eye_batch: int = EYE_BATCH,
    passed_min: int = PASSED_MIN,
    clock: str = "rounds",
    latency: float = LATENCY,
) -> Outcome:
    """Render on a simulated mesh; `scenes[n]` holds node n's objects. `delay` = (src, dst,
    rounds): messages on that link arrive that many rounds (clock "work": latencies) late;
    `eye_batch`: eye rays per primary batch (small ones interleave more); `passed_min`: the
    nodes' Scheduler's; `clock`: "rounds" or "work" (module docstring). Nodes with the same
    objects in the same box (image space) share one engine, so a simulated 16x16 builds it
    once."""
    if clock not in ("rounds", "work"):
        raise ValueError(f"clock must be 'rounds' or 'work', not {clock!r}")
    plan = spec.plan
    engines = EngineCache()
    cores = [NodeCore(n, scenes[n], spec, part, eye_batch, engines) for n in range(plan.nodes)]
    for n, core in enumerate(cores):  # MeshPlan.copies: the very engines the others trace with
        core.copies = {m: cores[m].engine for m in plan.held(n)[1:]}
    if clock == "rounds":
        return _Mesh(cores, spec, seed, delay, passed_min).run()
    return _TimedMesh(cores, spec, seed, delay, passed_min, latency=latency).run()


class _Mesh:
    def __init__(self, cores, spec: RenderSpec, seed, delay, passed_min):
        torus = Torus(spec.plan.rows, spec.plan.cols)
        self.cores = cores
        self.scheds = [
            Scheduler(
                n,
                torus.ring_next(n),
                torus.size,
                neighbours=torus.links(n),
                steal=spec.steals,
                passed_min=passed_min,
            )
            for n in range(torus.size)
        ]
        self.records = [NodeRecord(objects=c.engine.stats["objects"]) for c in cores]
        self.rng = np.random.default_rng(seed)
        self.delay = delay
        self.transit: list = []  # (arrival round, destination, kind, payload)
        self.deposits: list = []
        self.round = 0
        self.dealer = None
        if spec.plan.dynamic:  # the host deals tiles; its messages take a round each way
            order = deal_order(cores[0].part.rects, spec.plan.order)
            self.dealer = TileDealer(order, torus.size, spec.plan.buffer, spec.adaptive)
            for n, (tiles, last) in self.dealer.first().items():
                owners = self.dealer.owners_with(last)
                self._post((self._stamp(-1), n, "tiles", (tiles, last, owners)))

    def _stamp(self, src: int, late: int = 0) -> float:
        """When a message `src` sends now arrives (-1: the host): the next round."""
        return self.round + 1 + late

    def _post(self, message: tuple) -> None:
        """(arrival, destination, kind, payload) into the network."""
        self.transit.append(message)

    def _worked(self, n: int, units: int) -> None:
        """Node n traced a batch of `units` of work (rounds: one turn whatever it cost)."""

    def _finish(self) -> None:
        for rec, sched in zip(self.records, self.scheds, strict=True):
            rec.chunks_given, rec.chunks_taken = sched.chunks_given, sched.chunks_taken
            rec.given_in = dict(sched.given_in)

    def run(self) -> Outcome:
        while not all(s.done for s in self.scheds) or self.transit:
            self.round += 1
            if self.round > MAX_ROUNDS:
                states = [s.state.name for s in self.scheds]
                raise RuntimeError(
                    f"simulated mesh did not finish in {MAX_ROUNDS} rounds (node states {states})"
                )
            self._deliver()
            for n in self.rng.permutation(len(self.cores)):
                self._act(int(n))
        self._finish()
        return Outcome(self.deposits, self.records, self.round)

    def _send(self, src: int, dst: int, kind: str, payload) -> None:
        late = self.delay[2] if self.delay and (src, dst) == tuple(self.delay[:2]) else 0
        self._post((self._stamp(src, late), dst, kind, payload))
        if kind != "state":
            self.scheds[src].message_out()

    def _pixels(self, src: int, routes: dict) -> None:
        """Deposits a node's adaptive books send on (`NodeCore.keep`)."""
        for dest, deposits in routes.items():
            self._send(src, dest, "pixels", deposits)

    def _deliver(self) -> None:
        due = [m for m in self.transit if m[0] <= self.round]
        self.transit = [m for m in self.transit if m[0] > self.round]
        for message in due:
            self._handle(*message)

    def _handle(self, _: float, dst: int, kind: str, payload) -> None:
        """A message arrives at node `dst` (-1: the host)."""
        sched = self.scheds[dst] if dst >= 0 else None
        if kind == "rays":
            self.records[dst].rays_received += len(payload)
            sched.rays_in(payload)
        elif kind == "pixels":
            sched.message_in()
            self._pixels(dst, self.cores[dst].keep(payload))
        elif kind == "tiles":
            self._pixels(dst, self.cores[dst].add_tiles(*payload))
        elif kind == "steal":
            sched.steal_request(payload)
        elif kind == "give":
            sched.given(*payload)
        elif kind == "done":  # at the host: one more tile for each finished
            for _ in payload[1]:
                tiles, last = self.dealer.finished(payload[0])
                if tiles or last:
                    owners = self.dealer.owners_with(last)
                    self._post((self._stamp(-1), payload[0], "tiles", (tiles, last, owners)))
        else:
            sched.packet_in(payload)

    def _act(self, n: int) -> bool:
        """Node n acts until it has traced one batch (True) or must wait (False)."""
        sched = self.scheds[n]
        while (step := sched.next()) is not None:
            if isinstance(step, Enter):
                self._enter(n, step.state)
            elif isinstance(step, SendPacket):
                self.records[n].packet_visits += 1
                self._send(n, step.to, "state", step.packet)
            elif isinstance(step, Steal):
                self._send(n, step.to, "steal", n)
            elif isinstance(step, Give):
                self._send(n, step.to, "give", (n, step.chunks))
            elif isinstance(step, Trace):
                feed = self.cores[n].feed
                if step.primary and feed is not None and feed.finished:
                    self._post((self._stamp(n), -1, "done", (n, feed.finished)))
                    feed.finished = []
                self._trace(n, step)
                return True
            elif not isinstance(step, Flush):
                raise TypeError(f"unknown scheduler step {step!r}")
        return False

    def _enter(self, n: int, state: State) -> None:
        sched, core = self.scheds[n], self.cores[n]
        if state in (State.TRACE, State.REFINE):
            sched.primaries = core.primaries(state)
        elif state == State.FLUSH:
            self.deposits.extend(core.finished_pixels())

    def _trace(self, n: int, step: Trace) -> None:
        rec, core, sched = self.records[n], self.cores[n], self.scheds[n]
        batch = core.trace(step.rays, step.primary, step.taker)
        rec.batches += 1
        before = rec.cost
        add_counts(rec.counts, batch.counts, len(step.rays) if step.primary else 0)
        self._worked(n, rec.cost - before)  # what it sends leaves once the batch is done
        for dest, deposits in batch.deposits.items():
            if dest == HOST:
                self.deposits.append(deposits)
            elif dest == n:
                self._pixels(n, core.keep(deposits, traced_here=True))
            else:
                self._send(n, dest, "pixels", deposits)
        for dest, passed in batch.outgoing.items():
            rec.rays_sent += len(passed)
            rec.sent_to[dest] += len(passed)
            self._send(n, dest, "rays", passed)
        for taker, rays in batch.held.items():
            sched.rays_in(rays, message=False, taker=taker)
        sched.batch_done()


class _TimedMesh(_Mesh):
    """The mesh with a clock per node in work units (`simulate(clock="work")`): the node
    with the earliest clock acts next (ties in a seeded order), first taking every message
    that has arrived by then; a node with nothing to do sleeps until a message reaches it."""

    def __init__(self, *args, latency: float):
        self.latency = float(latency)
        self.clock = np.zeros(len(args[0]))
        self.now = 0.0  # the time of the message being handled
        self.sent = 0  # messages posted: keeps equal arrivals in the order they were sent
        super().__init__(*args)
        self.rank = self.rng.permutation(len(self.cores)).tolist()
        self.awake = [(0.0, self.rank[n], n) for n in range(len(self.cores))]
        heapq.heapify(self.awake)
        self.asleep: set[int] = set()

    def _stamp(self, src: int, late: int = 0) -> float:
        return (self.now if src < 0 else self.clock[src]) + self.latency * (1 + late)

    def _post(self, message: tuple) -> None:
        self.sent += 1
        heapq.heappush(self.transit, (message[0], self.sent, message))

    def _worked(self, n: int, units: int) -> None:
        self.clock[n] += units

    def run(self) -> Outcome:
        """Events in time order: every message that arrives no later than the earliest
        awake node's clock is handed over first (it may wake a node with an earlier
        clock), then that node acts."""
        turns, limit = 0, MAX_ROUNDS * len(self.cores)
        while self.awake or self.transit:
            turns += 1
            if turns > limit:
                states = [s.state.name for s in self.scheds]
                raise RuntimeError(
                    f"simulated mesh did not finish in {limit} turns (node states {states})"
                )
            if self.transit and (not self.awake or self.transit[0][0] <= self.awake[0][0]):
                self._deliver_one()
                continue
            _, _, n = heapq.heappop(self.awake)
            if self._act(n):
                heapq.heappush(self.awake, (self.clock[n], self.rank[n], n))
            else:
                self.asleep.add(n)
        if not all(s.done for s in self.scheds):
            states = [s.state.name for s in self.scheds]
            raise RuntimeError(
                f"simulated mesh: every node waits and nothing is in flight (node states {states})"
            )
        self._finish()
        return Outcome(self.deposits, self.records, turns, float(self.clock.max()))

    def _deliver_one(self) -> None:
        """Hand over the earliest message in flight, waking the node it reaches."""
        message = heapq.heappop(self.transit)[2]
        self.now, dst = message[0], message[1]
        if dst in self.asleep:
            self.asleep.discard(dst)
            self.clock[dst] = max(self.clock[dst], self.now)
            heapq.heappush(self.awake, (self.clock[dst], self.rank[dst], dst))
        self._handle(*message)
