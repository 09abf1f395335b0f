"""What a node's session sends (`Sends`, a part of `session.Session`): RAYS and PIXELS toward
a node over the torus, each counted as a message for the termination waves; several RAYS
leaving over one link together as one RAYS_SET frame; rays relayed through the node, with its
own leaving rays; STEAL and GIVE, the waves' STATE and
ECHO to neighbours; deposits and TILE_DONE to the host. It uses the session's router,
outboxes, the host's outbox, scheduler and statistics."""

import numpy as np

from meshnode.mesh.termination import Echo, Probe
from protocols.messages import Kind, make
from protocols.records import Parts

# Several RAYS leaving over one link together go as one RAYS_SET frame (False: a frame each;
# `python -m bench.passing` compares both)
RAYS_SETS = True
# Rays relayed through this node wait for its next send over their link, at most a batch
# (False: each message's sent on at once; `python -m bench.passing` compares both)
RELAYS_WAIT = True


class Sends:
    """The driver's sends (`meshnode.mesh.driver.Driver`) over a session's links."""

    def post_data(self, dest: int, kind: Kind, records: np.ndarray | Parts, cell: int = -1) -> None:
        """A RAYS (for cell `cell`'s engine) or PIXELS message toward node `dest`, counted
        as sent."""
        hop = self.router.next_hop(dest)
        if kind is Kind.RAYS:
            message = make(Kind.RAYS, rays=records, dest=dest, cell=cell)
            self.stats.rays_out[hop] += len(records)
        else:
            message = make(Kind.PIXELS, deposits=records, dest=dest)
            self.stats.pixel_packets += 1
        self.sched.message_out()
        self.outboxes[hop].post(message, records.nbytes)

    def to_host(self, deposits: np.ndarray) -> None:
        """Deposits straight to the host, from every node: through node 0 over the torus
        (DESIGN.md 5's pixel packets) node 0 decoded and sent on every other node's, which
        in image space left it no time to trace (0.01-0.05 s of tracing CPU against 1.1 s on
        a 3x3) and in object space made it the busiest node by frame CPU (balls 3x3: 0.39 s
        against the others' 0.21-0.33)."""
        self.host_out.post(make(Kind.PIXELS, deposits=deposits, dest=-1), deposits.nbytes)

    def post_rays(self, dest: int, rays: Parts, cell: int) -> None:
        self.post_data(dest, Kind.RAYS, rays, cell)

    def post_rays_set(self, sends: list) -> None:
        """RAYS for each (dest, rays, cell) of `sends`: those leaving over one link go as one
        RAYS_SET frame, counted as one message (most of a flush's RAYS are a few rays each:
        balls 4x4 under 0.15 simulated, median 5 rays; one frame a link cut them by 38%)."""
        by_hop: dict[int, list] = {}
        for send in sends:
            by_hop.setdefault(self.router.next_hop(send[0]), []).append(send)
        for hop, group in by_hop.items():
            if len(group) == 1 or not RAYS_SETS:
                for dest, rays, cell in group:
                    self.post_data(dest, Kind.RAYS, rays, cell)
                continue
            rays = Parts.of([a for _, r, _ in group for a in _arrays(r)])
            parts = np.array([(d, c, len(r)) for d, r, c in group], np.int64).reshape(-1)
            self.stats.rays_out[hop] += len(rays)
            self.stats.ray_sets += 1
            self.sched.message_out()
            self.outboxes[hop].post(make(Kind.RAYS_SET, rays=rays, parts=parts), rays.nbytes)

    def pass_on(self, sends: list) -> None:
        """Rays relayed toward their nodes: with this node's own leaving rays
        (`Driver.relay`), or each message's at once (RELAYS_WAIT False)."""
        self.stats.relayed += sum(len(rays) for _, rays, _ in sends)
        if RELAYS_WAIT:
            self.relay(sends)
        else:
            self.post_rays_set(sends)

    def post_pixels(self, dest: int, deposits: np.ndarray) -> None:
        self.post_data(dest, Kind.PIXELS, deposits)

    def post_steal(self, to: int) -> None:
        self.outboxes[to].post(make(Kind.STEAL, node=self.node))
        self.sched.message_out()

    def post_give(self, to: int, chunks: list) -> None:
        chunks = [list(map(int, c)) for c in chunks]
        self.outboxes[to].post(make(Kind.GIVE, chunks=chunks))
        self.sched.message_out()

    def post_probe(self, probe: Probe, to: int) -> None:
        self.outboxes[to].post(make(Kind.STATE, wave=probe.wave, state=probe.state))

    def post_echo(self, echo: Echo, to: int) -> None:
        self.outboxes[to].post(
            make(
                Kind.ECHO,
                wave=echo.wave,
                dirty=echo.dirty,
                sent=echo.sent,
                received=echo.received,
            )
        )

    def post_tiles_done(self, tiles: list[int]) -> None:
        self.host_out.post(make(Kind.TILE_DONE, node=self.node, tiles=tiles))


def _arrays(rays) -> tuple:
    """The record arrays of `rays` (a Parts, or one array: a part of a frame passed on)."""
    return rays.arrays if isinstance(rays, Parts) else (rays,)
