"""The host's links to its nodes outside the render loop: dialling each (both sides proving
the cluster secret), sending every node its CONFIG and objects, giving a try of the frame up,
and closing. The loop itself, once every node is configured, is `host.run.collector`'s.
"""

import asyncio
import secrets
import ssl
import time
from dataclasses import dataclass

import numpy as np

from host.planning.plan import Planned
from host.run.errors import MeshError, NodeLost
from host.scene.subset import subset
from meshnode.transport.link import Link, LinkClosed, dial
from protocols.errors import ProtocolError, describe
from protocols.handshake import RENDER_ID_BYTES
from protocols.messages import Kind, make
from protocols.scene import SceneData

OBJECT_BATCH = 20000  # records per OBJECTS message


@dataclass(frozen=True)
class Nodes:
    """Running nodes and how the host reaches them: node i at `addresses[i]` ("host:port"),
    in `cluster`, proving `secret` (None: nodes started without one), over TLS with the
    client context `tls` (`meshnode.transport.tls`; None: plain TCP), every node accepting
    within `wait` seconds in all (nodes still starting), else the first that does not is
    named."""

    addresses: tuple[str, ...]
    cluster: str = "meshtrace"
    secret: bytes | None = None
    tls: ssl.SSLContext | None = None
    wait: float = 5.0

    def __post_init__(self):
        object.__setattr__(self, "addresses", tuple(self.addresses))


async def connect_all(nodes: Nodes) -> tuple[list[Link], list[int]]:
    """One link to every node within `nodes.wait` seconds in all, both sides proving the
    secret; and the memory each has."""
    links: list[Link] = []
    memories: list[int] = []
    deadline = time.monotonic() + nodes.wait
    try:
        for n, address in enumerate(nodes.addresses):
            link, theirs = await _dial_within(
                deadline, address, n, nodes.cluster, nodes.secret, nodes.tls
            )
            links.append(link)
            memories.append(theirs["memory"])
    except (LinkClosed, ProtocolError) as e:
        await close_all(links, shutdown=False)
        raise MeshError(f"setting up the mesh: {describe(e)}") from e
    return links, memories


SATURATED_PAUSE = 0.2  # seconds between tries of a node that is saturated or dropped us


async def _dial_within(deadline: float, address, n: int, cluster, secret, tls):
    """`dial` node n, again while the deadline allows if it says it is saturated (its
    hosts' links all taken) or drops the connection before the handshake is done (a flood
    of strangers filling its pool of handshakes drops the oldest: `meshnode.service.
    admission`); then its refusal, by name. A refused secret is not tried again."""
    while True:
        left = max(deadline - time.monotonic(), 0.1)
        try:
            return await dial(
                address, f"node {n} ({address})", cluster, secret, "host", tls=tls, wait=left
            )
        except LinkClosed as e:
            dropped = isinstance(e.__cause__, LinkClosed)  # lost mid-handshake, not refused
            again = "saturated" in e.reason or dropped
            if not again or time.monotonic() + SATURATED_PAUSE > deadline:
                raise
        await asyncio.sleep(SATURATED_PAUSE)


async def configure(scene, planned: Planned, links: list[Link], addresses) -> None:
    """Every node's CONFIG (all of them first: a node links to its neighbours once its
    objects are in, and they must know the render by then), then its objects."""
    neighbours = {str(n): a for n, a in enumerate(addresses)}
    render, part = planned.spec.to_wire(), planned.partition.to_wire()
    render_id = secrets.token_bytes(RENDER_ID_BYTES)  # links of a given-up try cannot join
    n = 0
    try:
        for n, link in enumerate(links):
            await link.send(
                make(
                    Kind.CONFIG,
                    node=n,
                    neighbours=neighbours,
                    render=render,
                    partition=part,
                    scene=scene.header.to_wire(),
                    render_id=render_id,
                )
            )
        for n, link in enumerate(links):
            held = planned.spec.plan.held(n)
            await download(link, {m: subset(scene, planned.holders[m]) for m in held})
    except LinkClosed as e:
        raise NodeLost(n, f"setting up the mesh: {describe(e)}") from e


async def download(link: Link, scenes: dict[int, SceneData]) -> None:
    """Objects for one node, table by table, in bounded messages: `scenes[m]` node m's (its
    own, and under MeshPlan.copies each linked neighbour's)."""
    parts = []
    for m, scene in scenes.items():
        tables = scene.tables().items()
        own = [
            (m, n, t[i : i + OBJECT_BATCH])
            for n, t in tables
            for i in range(0, len(t), OBJECT_BATCH)
        ]
        parts += own or [(m, "materials", scene.materials)]  # every node named at least once
    for i, (m, name, records) in enumerate(parts):
        last = i == len(parts) - 1
        await link.send(
            make(Kind.OBJECTS, table=name, records=np.ascontiguousarray(records), node=m, last=last)
        )


async def give_up(links: list[Link], error: MeshError, deadline: float) -> dict[int, str]:
    """Tell every node the render is given up (ABORT) and wait up to `deadline` seconds for
    each to answer (ABORTED comes after everything it sent for the render); returns the
    nodes lost (the one the error names, links that broke, nodes that did not answer) with
    the reason for each, their links dropped."""
    lost = {error.node: str(error)} if isinstance(error, NodeLost) else {}

    async def aborted(link: Link) -> None:
        await link.send(make(Kind.ABORT, reason=str(error)))
        while (await link.recv())[0] is not Kind.ABORTED:
            pass  # what the node sent for the given-up render

    waits = {
        asyncio.ensure_future(aborted(link)): i for i, link in enumerate(links) if i not in lost
    }
    if waits:
        done, pending = await asyncio.wait(waits, timeout=deadline)
        for t in pending:
            t.cancel()
            lost[waits[t]] = f"no answer to the host's ABORT within {deadline:g} s"
        await asyncio.gather(*pending, return_exceptions=True)
        for t in done:
            if t.exception() is not None:
                lost[waits[t]] = describe(t.exception())
    for i in lost:
        links[i].abort()
    return lost


async def close_all(links: list[Link], shutdown: bool = True) -> None:
    """Close every link, first telling its node to shut down (`shutdown`) if it still
    listens: the nodes of a local mesh exit with the host."""
    for link in links:
        if shutdown:
            try:
                await link.send(make(Kind.SHUTDOWN))
            except LinkClosed:
                pass
        await link.close()
