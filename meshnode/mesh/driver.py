"""The part of a Scheduler's driver that does not depend on how messages travel: what each step
means and where a traced batch's output goes.

The asyncio session (`meshnode.service.session`) and the simulated mesh (`simulator`) both
subclass Driver and say only how a message goes and when a batch is traced: so the two decide
alike by construction, and a simulated mesh predicts what a real one does (DESIGN.md 6).
"""

import numpy as np

from meshnode.mesh.node import HOST, Batch, NodeCore
from meshnode.mesh.scheduler import Scheduler
from meshnode.mesh.steps import Enter, Flush, Give, SendEcho, SendProbe, Steal, Trace
from meshnode.mesh.termination import Echo, Probe
from meshnode.mesh.traced import TracedTiles
from protocols.records import Parts
from protocols.state import State

PASS_RAYS = 16384  # rays leaving for one node are sent once this many wait ...
PASS_AGE = 16  # ... or once they have waited this many batches traced here, or the node idles
# (a message costs about 100-250 us of CPU at both ends whatever its size, a ray 0.09 us:
# balls 3x3 sent 600 messages a node of 400 rays each, 0.25 s of its 0.5 s frame CPU;
# 16384 against 4096, `python -m bench.passing --only balls,gears --turns 3` (3x3, a quarter
# of the objects a node, 384x384 at 16 spp): the nodes' CPU 0.90-0.96 on balls (9.1 M rays
# passed), 0.92 on gears (1.5 M), medians in turns. Age 16 with the scheduler's
# PASSED_BATCH 16384 against age 4 and 4096, `--passing 16384/4/4096,16384/16/16384`: half
# the messages on balls, the nodes' CPU 0.83, 0.92, 0.99 of before in three runs on balls,
# 0.94 on gears, 0.97 on tetra, 0.93 on teapot; each change alone 0.97 on balls)


class Driver:
    """Acts on node `node`'s scheduler's steps with its NodeCore (`core`, set once built).
    Subclasses send: RAYS, PIXELS, STEAL and GIVE are counted messages, so their `post_*`
    tell the scheduler (`Scheduler.message_out`); termination's probes and echoes are not.
    Rays leaving for another node wait here until PASS_RAYS of them or PASS_AGE batches have
    gathered, or the node has nothing in flight (`Flush`); rays for a cell go to the node
    the plan hands them to (`MeshPlan.takers`: its owner, or its nearest holder)."""

    def __init__(self, node: int, sched: Scheduler, core: NodeCore | None = None):
        self.node, self.sched, self.core = node, sched, core
        # (dest, cell) -> [batches of rays, rays, batches waited]
        self.leaving: dict[tuple[int, int], list] = {}
        self.traced = TracedTiles()  # dynamic image space: tiles wholly traced here

    def act(self, step) -> None:
        """Do one step `Scheduler.next()` decided."""
        if isinstance(step, Trace):
            feed = self.core.feed
            if step.tile >= 0:
                self.traced.batch_started(step.tile)
            if step.primary and feed is not None and feed.finished:
                self.post_tiles_done(feed.finished)  # the host deals the next ones meanwhile
                self.traced.all_started(feed.finished)
                feed.finished = []
            self.start(step)
        elif isinstance(step, Enter):
            self.enter(step.state)
        elif isinstance(step, Flush):
            self.send_leaving()
            self.flush()
        elif isinstance(step, Steal):
            self.post_steal(step.to)
        elif isinstance(step, Give):
            self.post_give(step.to, step.chunks)
        elif isinstance(step, SendProbe):
            self.post_probe(step.probe, step.to)
        elif isinstance(step, SendEcho):
            self.post_echo(step.echo, step.to)
        else:
            raise TypeError(f"unknown scheduler step {step!r}")

    def enter(self, state: State) -> None:
        """Act on a state a termination wave brought: set up its primaries, hand adaptive
        sampling's finished pixels over, or report."""
        if state in (State.TRACE, State.REFINE):
            self.sched.primaries = self.core.primaries(state)
        elif state == State.FLUSH and self.core.keeps_pixels:
            self.finished(self.core.finished_pixels())
        elif state == State.DONE:
            self.report()

    def deliver(self, batch: Batch, step: Trace | None = None) -> None:
        """A traced batch's deposits and leaving rays, each toward the node that takes it;
        segments for an engine held here are queued here; `step`: the batch's Trace, whose
        tile (dynamic image space) is then one batch nearer traced."""
        for dest, deposits in batch.deposits.items():
            if dest == HOST:
                self.for_host(deposits)
            elif dest == self.node:
                self.send_pixels(self.core.keep(deposits, traced_here=True))
            else:
                self.post_pixels(dest, deposits)
        for waiting in self.leaving.values():
            waiting[2] += 1
        takers = self.core.takers
        for cell, passed in batch.outgoing.items():
            self._leave(takers[cell], cell, passed)
        due = [k for k, w in self.leaving.items() if w[1] >= PASS_RAYS or w[2] >= PASS_AGE]
        if due:
            self.send_leaving(due)
        for taker, rays in batch.held.items():
            self.sched.rays_in(rays, message=False, taker=taker)
        if step is not None and step.tile >= 0:
            self.traced.batch_traced(step.tile, batch.counts, self.core.stood_for(step.rays))
            if self.traced.done:  # out now, with its deposits: kept if another node is lost
                self.flush()

    def relay(self, sends: list) -> None:
        """Rays passing through this node toward (dest, rays, cell) of `sends`: they join
        this node's own rays leaving for the same node and cell, due at the next batch's end
        or the next flush (a frame each, sent on at once, made a third of a 4x4's messages)."""
        for dest, rays, cell in sends:
            waiting = self._leave(dest, cell, [rays])
            waiting[2] = max(waiting[2], PASS_AGE - 1)
        self.sched.output_waiting()

    def _leave(self, dest: int, cell: int, parts: list) -> list:
        """`parts` (arrays of rays) queued to leave for node `dest` and cell `cell`; the
        queue's entry [batches of rays, rays, batches waited]."""
        waiting = self.leaving.setdefault((dest, cell), [[], 0, 0])
        waiting[0] += parts
        waiting[1] += sum(len(p) for p in parts)
        return waiting

    def send_leaving(self, keys: list | None = None) -> None:
        """Send the rays waiting to leave for each (node, cell) of `keys` (None: every key's),
        not joined: each part goes into the frame from where it lies (`post_rays_set`)."""
        keys = list(self.leaving) if keys is None else keys
        if keys:
            sends = [(d, Parts.of(self.leaving.pop((d, c))[0]), c) for d, c in keys]
            self.post_rays_set(sends)

    def send_pixels(self, routes: dict[int, np.ndarray]) -> None:
        """Adaptive deposits the node's books send on, each toward its pixel's node."""
        for dest, deposits in routes.items():
            self.post_pixels(dest, deposits)

    # ------------------------------------------------------------------ transport
    def start(self, step: Trace) -> None:
        """Trace the batch (now, or on a thread), then `deliver` it and tell the scheduler
        (`batch_done`)."""
        raise NotImplementedError

    def post_rays(self, dest: int, rays: Parts, cell: int) -> None:
        """RAYS for node `dest` to trace with cell `cell`'s engine (its own or a copy)."""
        raise NotImplementedError

    def post_rays_set(self, sends: list) -> None:
        """RAYS for each (dest, rays, cell) of `sends`, sent together: a transport may put
        those that leave over one link in one frame."""
        for dest, rays, cell in sends:
            self.post_rays(dest, rays, cell)

    def post_pixels(self, dest: int, deposits: np.ndarray) -> None:
        raise NotImplementedError

    def post_steal(self, to: int) -> None:
        raise NotImplementedError

    def post_give(self, to: int, chunks: list) -> None:
        raise NotImplementedError

    def post_probe(self, probe: Probe, to: int) -> None:
        raise NotImplementedError

    def post_echo(self, echo: Echo, to: int) -> None:
        raise NotImplementedError

    def post_tiles_done(self, tiles: list[int]) -> None:
        """Tell the host these dealt tiles have all their batches handed out."""
        raise NotImplementedError

    def for_host(self, deposits: np.ndarray) -> None:
        """A batch's deposits for the host (no adaptive sampling)."""
        raise NotImplementedError

    def finished(self, batches) -> None:
        """Adaptive sampling's finished pixels (DEPOSIT batches) for the host."""
        raise NotImplementedError

    def flush(self) -> None:
        """Nothing is being traced: send what `for_host` buffered (nothing by default)."""

    def report(self) -> None:
        """The render is done: report statistics (nothing by default)."""
