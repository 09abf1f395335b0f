"""A mesh simulated in one process: every node's NodeCore driven by its own Scheduler, as on
a real mesh (through the `driver.Driver` the service subclasses too), with messages held in a
queue instead of sent on sockets.

Each round, every node (in a seeded random order) acts until it has traced one batch or has
nothing to do; messages sent in a round arrive at the start of the next (or `delay` rounds
later on one link), so rays and termination waves overtake each other as on a network. The
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

from meshnode.engine.sky import filled
from meshnode.mesh.adaptive import RectIndex
from meshnode.mesh.dealer import TileDealer, deal_order
from meshnode.mesh.driver import Driver
from meshnode.mesh.engines import EngineCache
from meshnode.mesh.node import EYE_BATCH, NodeCore
from meshnode.mesh.scheduler import PASSED_MIN, Scheduler
from meshnode.mesh.stats import add_counts, work_units
from meshnode.mesh.steps import Trace
from meshnode.mesh.termination import Echo, Probe
from protocols.partition import Partition
from protocols.render import RenderSpec
from protocols.state import states_of
from protocols.topology import Torus

MAX_ROUNDS = 1_000_000
# A message's flight under clock="work", in work units: about 0.1 ms on loopback (an event
# of tetra's costs ~3 ns: one node's tracing CPU / its work units, 384x384 at 32 spp).
LATENCY = 30_000


@dataclass
class NodeRecord:
    """What one simulated node did."""

    objects: int = 0
    engine_bytes: int = 0  # of every engine it holds (its own, copies), as the engines count
    cpu: float = 0.0  # seconds its batches spent in the kernels (the tracing threads' CPU)
    batches: int = 0
    rays_sent: int = 0
    sent_to: dict = field(default_factory=lambda: defaultdict(int))  # node -> rays sent it
    rays_received: int = 0
    waves: int = 0  # termination waves that reached it
    chunks_given: int = 0  # chunks of its rectangle neighbours took (MeshPlan.steal)
    chunks_taken: int = 0  # chunks it took from neighbours
    given_in: dict = field(default_factory=dict)  # chunks given by state (TRACE, REFINE)
    counts: dict = field(default_factory=lambda: defaultdict(int))
    primary_cost: int = 0  # of `cost`, in its primary batches (eye rays and all they spawn here)

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
    # per rectangle of the partition: work units of the primary batches made from it, on
    # the node that made them (shared by ray count where a batch spans rectangles): what
    # dealing a rectangle to another holder of its cell moves (`host.planning.replicas`)
    tile_work: np.ndarray | None = None
    host: dict = field(default_factory=dict)  # counts of the tiles the host fills (the sky's)

    def totals(self) -> dict[str, int]:
        out: dict[str, int] = defaultdict(int, self.host)
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
    engines: EngineCache | None = None,
) -> Outcome:
    """Render on a simulated mesh; `scenes[n]` holds node n's objects. `delay` = (src, dst,
    rounds): messages on that link arrive that many rounds (clock "work": latencies) late;
    `eye_batch`: eye rays per primary batch (small ones interleave more); `passed_min`: the
    nodes' Scheduler's; `clock`: "rounds" or "work" (module docstring). Nodes with the same
    objects in the same box (image space) share one engine, so a simulated 16x16 builds it
    once; `engines`: a cache kept across simulations (a plan's: the same boxes simulated
    with other copies or dealing build once), else one for this simulation."""
    if clock not in ("rounds", "work"):
        raise ValueError(f"clock must be 'rounds' or 'work', not {clock!r}")
    plan = spec.plan
    engines = EngineCache() if engines is None else engines
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
                torus.parent(n),
                torus.children(n),
                neighbours=torus.links(n),
                steal=spec.steals,
                passed_min=passed_min,
                states=states_of(spec.adaptive),
            )
            for n in range(torus.size)
        ]
        self.records = [
            NodeRecord(
                objects=c.engine.stats["objects"],
                engine_bytes=sum(e.stats["engine_bytes"] for e in (c.engine, *c.copies.values())),
            )
            for c in cores
        ]
        self.nodes = [_Node(self, n) for n in range(torus.size)]
        part = cores[0].part
        self.tiles = RectIndex(part.rects, spec.sample_grid[0])
        self.tile_work = np.zeros(len(part.rects))
        self.ids_per_cell = spec.ids_per_cell
        self.rng = np.random.default_rng(seed)
        self.delay = delay
        self.transit: list = []  # (arrival round, destination, kind, payload)
        self.deposits: list = []
        self.round = 0
        self.dealer, self.host = None, {}
        if spec.plan.dynamic:  # the host deals tiles; its messages take a round each way
            rects = cores[0].part.rects
            filled = self._sky_tiles(cores[0].sky if not spec.adaptive else None, rects)
            order = [t for t in deal_order(rects, spec.plan.order) if t not in filled]
            self.dealer = TileDealer(
                order, torus.size, spec.plan.buffer, spec.adaptive, count=len(rects)
            )
            for n, (tiles, last) in self.dealer.first().items():
                owners = self.dealer.owners_with(last)
                self._post((self._stamp(-1), n, "tiles", (tiles, last, owners)))

    def _sky_tiles(self, sky, rects) -> set[int]:
        """The tiles all sky, which the host deposits itself and deals to no node
        (`host.planning.skytiles`): their records to the host's deposits, their counts to
        its own."""
        tiles, records, self.host = filled(sky, rects)
        self.deposits.append(records)
        return set(tiles.tolist())

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
            rec.waves = sched.term.wave

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
        return Outcome(
            self.deposits, self.records, self.round, tile_work=self.tile_work, host=self.host
        )

    def _primary_work(self, rays: np.ndarray, units: int) -> None:
        """A primary batch's work, shared over the rectangles its rays came from."""
        tile = self.tiles(rays["pixel"] // self.ids_per_cell)
        made = np.bincount(tile[tile >= 0], minlength=len(self.tile_work))
        if made.sum():
            self.tile_work += units * made / made.sum()

    def _send(self, src: int, dst: int, kind: str, payload) -> None:
        late = self.delay[2] if self.delay and (src, dst) == tuple(self.delay[:2]) else 0
        self._post((self._stamp(src, late), dst, kind, payload))
        if kind not in ("probe", "echo"):
            self.scheds[src].message_out()

    def _deliver(self) -> None:
        due = [m for m in self.transit if m[0] <= self.round]
        self.transit = [m for m in self.transit if m[0] > self.round]
        for message in due:
            self._handle(*message)

    def _handle(self, _: float, dst: int, kind: str, payload) -> None:
        """A message arrives at node `dst` (-1: the host)."""
        sched = self.scheds[dst] if dst >= 0 else None
        if kind == "rays":
            rays, cell = payload
            self.records[dst].rays_received += len(rays)
            sched.rays_in(rays, taker=cell)
        elif kind == "pixels":
            sched.message_in()
            self.nodes[dst].send_pixels(self.cores[dst].keep(payload))
        elif kind == "tiles":
            self.nodes[dst].send_pixels(self.cores[dst].add_tiles(*payload))
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
        elif kind == "echo":
            sched.echo_in(*payload)
        else:
            sched.probe_in(payload)

    def _act(self, n: int) -> bool:
        """Node n acts until it has traced one batch (True) or must wait (False)."""
        node = self.nodes[n]
        while (step := node.sched.next()) is not None:
            node.act(step)
            if isinstance(step, Trace):
                return True
        return False


class _Node(Driver):
    """Node n of a simulated mesh: traces a batch at once, and its messages go into the
    mesh's network (`_Mesh._send`; counted ones are counted there)."""

    def __init__(self, mesh: _Mesh, n: int):
        super().__init__(n, mesh.scheds[n], mesh.cores[n])
        self.mesh, self.record = mesh, mesh.records[n]

    def start(self, step: Trace) -> None:
        rec = self.record
        batch = self.core.trace(step.rays, step.primary, step.taker)
        rec.batches += 1
        before = rec.cost
        rec.cpu += batch.counts.get("cpu_seconds", 0.0)
        add_counts(rec.counts, batch.counts, self.core.stood_for(step.rays) if step.primary else 0)
        if step.primary:
            self.mesh._primary_work(step.rays, rec.cost - before)
            rec.primary_cost += rec.cost - before
        self.mesh._worked(self.node, rec.cost - before)  # its output leaves once it is done
        self.deliver(batch, step)
        self.sched.batch_done()

    def post_rays(self, dest: int, rays, cell: int) -> None:
        self.record.rays_sent += len(rays)
        self.record.sent_to[dest] += len(rays)
        self.mesh._send(self.node, dest, "rays", (rays.joined(), cell))  # as a frame has them

    def post_pixels(self, dest: int, deposits) -> None:
        self.mesh._send(self.node, dest, "pixels", deposits)

    def post_steal(self, to: int) -> None:
        self.mesh._send(self.node, to, "steal", self.node)

    def post_give(self, to: int, chunks: list) -> None:
        self.mesh._send(self.node, to, "give", (self.node, chunks))

    def post_probe(self, probe: Probe, to: int) -> None:
        self.mesh._send(self.node, to, "probe", probe)

    def post_echo(self, echo: Echo, to: int) -> None:
        self.mesh._send(self.node, to, "echo", (self.node, echo))

    def post_tiles_done(self, tiles: list[int]) -> None:
        self.mesh._post((self.mesh._stamp(self.node), -1, "done", (self.node, tiles)))

    def for_host(self, deposits) -> None:
        self.mesh.deposits.append(deposits)

    def finished(self, batches) -> None:
        self.mesh.deposits.extend(batches)


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
        return Outcome(
            self.deposits, self.records, turns, float(self.clock.max()), self.tile_work, self.host
        )

    def _deliver_one(self) -> None:
        """Hand over the earliest message in flight, waking the node it reaches."""
        message = heapq.heappop(self.transit)[2]
        self.now, dst = message[0], message[1]
        if dst in self.asleep:
            self.asleep.discard(dst)
            self.clock[dst] = max(self.clock[dst], self.now)
            heapq.heappush(self.awake, (self.clock[dst], self.rank[dst], dst))
        self._handle(*message)
