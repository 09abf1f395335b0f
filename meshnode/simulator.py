"""A mesh simulated in one process: every node's NodeCore driven by its own Scheduler, as on
a real mesh, with messages held in a queue instead of sent on sockets.

Each round, every node (in a seeded random order) acts until it has traced one batch or has
nothing to do; messages sent in a round arrive at the start of the next (or `delay` rounds
later on one link), so rays and the state packet overtake each other as on a network. The
host's cost pre-pass runs it on a coarse image; the tests check the distributed algorithm
with it (image, counts, termination under delays) against the single-node render.
"""

from collections import defaultdict
from dataclasses import dataclass, field

import numpy as np

from meshnode.node import EYE_BATCH, HOST, EngineCache, NodeCore
from meshnode.scheduler import (
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
from meshnode.stats import add_counts, work_units
from meshnode.termination import State
from protocols.render import Partition, RenderSpec
from protocols.topology import Torus

MAX_ROUNDS = 1_000_000


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
        """Work done, in the engine's own units (`meshnode.stats.work_units`)."""
        return work_units(self.counts)


@dataclass
class Outcome:
    deposits: list  # DEPOSIT arrays that reached the host
    nodes: list[NodeRecord]
    rounds: int

    def totals(self) -> dict[str, int]:
        out: dict[str, int] = defaultdict(int)
        for n in self.nodes:
            for k, v in n.counts.items():
                out[k] += v
        return dict(out)


def simulate(scenes, spec: RenderSpec, part: Partition, seed: int = 0, delay=None,
             eye_batch: int = EYE_BATCH, passed_min: int = PASSED_MIN) -> Outcome:  # fmt: skip
    """Render on a simulated mesh; `scenes[n]` holds node n's objects. `delay` = (src, dst,
    rounds): messages on that link arrive that many rounds late; `eye_batch`: eye rays per
    primary batch (small ones interleave more); `passed_min`: the nodes' Scheduler's. Nodes
    with the same objects in the same box (image space) share one engine, so a simulated
    16x16 builds it once."""
    plan = spec.plan
    engines = EngineCache()
    cores = [NodeCore(n, scenes[n], spec, part, eye_batch, engines) for n in range(plan.nodes)]
    for n, core in enumerate(cores):  # MeshPlan.copies: the very engines the others trace with
        core.copies = {m: cores[m].engine for m in plan.held(n)[1:]}
    mesh = _Mesh(cores, spec, seed, delay, passed_min)
    return mesh.run()


class _Mesh:
    def __init__(self, cores, spec: RenderSpec, seed, delay, passed_min):
        torus = Torus(spec.plan.rows, spec.plan.cols)
        self.cores = cores
        self.scheds = [Scheduler(n, torus.ring_next(n), torus.size, neighbours=torus.links(n),
                                 steal=spec.steals, passed_min=passed_min)
                       for n in range(torus.size)]  # fmt: skip
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
                self.transit.append((1, n, "tiles", (tiles, last, owners)))

    def run(self) -> Outcome:
        while not all(s.done for s in self.scheds) or self.transit:
            self.round += 1
            if self.round > MAX_ROUNDS:
                states = [s.state.name for s in self.scheds]
                raise RuntimeError(f"simulated mesh did not finish in {MAX_ROUNDS} rounds "
                                   f"(node states {states})")  # fmt: skip
            self._deliver()
            for n in self.rng.permutation(len(self.cores)):
                self._act(int(n))
        for rec, sched in zip(self.records, self.scheds, strict=True):
            rec.chunks_given, rec.chunks_taken = sched.chunks_given, sched.chunks_taken
            rec.given_in = dict(sched.given_in)
        return Outcome(self.deposits, self.records, self.round)

    def _send(self, src: int, dst: int, kind: str, payload) -> None:
        late = self.delay[2] if self.delay and (src, dst) == tuple(self.delay[:2]) else 0
        self.transit.append((self.round + 1 + late, dst, kind, payload))
        if kind != "state":
            self.scheds[src].message_out()

    def _pixels(self, src: int, routes: dict) -> None:
        """Deposits a node's adaptive books send on (`NodeCore.keep`)."""
        for dest, deposits in routes.items():
            self._send(src, dest, "pixels", deposits)

    def _deliver(self) -> None:
        due = [m for m in self.transit if m[0] <= self.round]
        self.transit = [m for m in self.transit if m[0] > self.round]
        for _, dst, kind, payload in due:
            sched = self.scheds[dst] if dst >= 0 else None  # -1: the host
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
                        self.transit.append((self.round + 1, payload[0], "tiles",
                                             (tiles, last, owners)))  # fmt: skip
            else:
                sched.packet_in(payload)

    def _act(self, n: int) -> None:
        """Node n acts until it has traced one batch or must wait."""
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
                    self.transit.append((self.round + 1, -1, "done", (n, feed.finished)))
                    feed.finished = []
                self._trace(n, step)
                return
            elif not isinstance(step, Flush):
                raise TypeError(f"unknown scheduler step {step!r}")

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
        add_counts(rec.counts, batch.counts, len(step.rays) if step.primary else 0)
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
