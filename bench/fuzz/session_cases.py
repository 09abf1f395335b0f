"""The cases inside a session: a mutated CONFIG and OBJECTS, a small scene with mutated
records rendered to the end, and node 1 of a 1x2 mesh fed mutated neighbour frames. They build
engines and render, a few a second, so they run in one lane of their own at the end."""

import asyncio
import math
import time
from typing import TYPE_CHECKING

import numpy as np

from bench.fuzz.conn import CASE_TIMEOUT, Conn, Hang
from bench.fuzz.inputs import (
    framed,
    kind_of,
    mutate_message,
    mutate_records,
    mutate_tree,
    valid_message,
)
from host.planning.plan import plan_render
from host.planning.request import Request
from host.scene.subset import subset
from protocols import dtypes
from protocols.framing import FrameDecoder, encode
from protocols.messages import OBJECT_TABLES, Kind, make
from protocols.render import EngineSpec, ImageSpec, MeshPlan
from protocols.scene import SceneData

if TYPE_CHECKING:
    from bench.fuzz.fuzzer import Fuzzer

BUILD_TIMEOUT = 90.0  # s: a render's engine build may compile a new kernel variant
RENDER_ID = b"r" * 16  # the render id of the CONFIGs sent here
SESSION_KINDS = {"config": 6, "render": 1, "neighbour": 3}


def session_messages(scene: SceneData, plan: MeshPlan, n: int, image: ImageSpec):
    """A real CONFIG for node n and its objects, as host.run.connections makes them."""
    planned = plan_render(Request(scene, image, EngineSpec(), plan=plan))
    neighbours = {str(m): "127.0.0.1:9" for m in range(plan.nodes)}
    config = make(
        Kind.CONFIG,
        node=n,
        neighbours=neighbours,
        render=planned.spec.to_wire(),
        partition=planned.partition.to_wire(),
        scene=scene.header.to_wire(),
        render_id=RENDER_ID,
    )
    scene = subset(scene, np.ones_like(planned.holders[n]))  # every object: one variant
    tables = scene.tables()
    return encode(config), tables


async def case_config(f: "Fuzzer") -> None:
    """A mutated CONFIG; if accepted, mutated OBJECTS on the same link, then SHUTDOWN."""
    c = await Conn.open(f.node.port)
    await c.handshake()
    fields = FrameDecoder().feed(f.one[0])[0]
    mutate_tree(f.rng, fields)
    fields["k"] = int(Kind.CONFIG)
    try:
        data = encode(fields)
    except (TypeError, ValueError, OverflowError):
        await c.close()
        return
    c.send(data)
    # A refusal comes at once; an accepted CONFIG starts a session, heard within 1 s.
    m = await c.recv()
    f.refusal(m)
    if m is None or m.get("k") == Kind.ERROR:
        f.count("config", "refused", data)
        await c.close()
        return
    f.count("config", "accepted", data)
    await objects_stream(f, c)


async def objects_stream(f: "Fuzzer", c: Conn) -> None:
    """Mutated OBJECTS (never the last) after an accepted CONFIG, then SHUTDOWN: the node
    must refuse by name or take them, and close the link."""
    for _ in range(f.rng.randint(5, 60)):
        data = framed(objects_message(f))
        if data is None:
            continue
        if not c.send(data):
            break
        f.count("objects", "sent", data)
        await asyncio.sleep(0)
    c.send(encode(make(Kind.SHUTDOWN)))
    msgs = await c.until_closed()
    errors = [m for m in msgs if m.get("k") == Kind.ERROR]
    f.refusal(errors[0] if errors else None)
    f.outcomes["objects", "stream refused" if errors else "stream clean"] += 1
    await c.close()


def objects_message(f: "Fuzzer") -> dict:
    """OBJECTS of a random table for node 0: mutated records, or a mutated message that is
    still neither CONFIG nor SHUTDOWN nor the last batch (the session must stay open)."""
    table = f.rng.choice(sorted(OBJECT_TABLES))
    records = f.one[1][table]
    if f.rng.random() < 0.7:
        return make(
            Kind.OBJECTS,
            node=0,
            table=table,
            records=mutate_records(f.rng, records),
            last=False,
        )
    message = mutate_message(
        f.rng, make(Kind.OBJECTS, node=0, table=table, records=records, last=False)
    )
    if kind_of(message) in (Kind.CONFIG, Kind.SHUTDOWN):
        message["k"] = int(Kind.OBJECTS)
    if message.get("last") is True:
        message["last"] = False
    return message


async def case_render(f: "Fuzzer") -> None:
    """A small scene with mutated records (and sometimes background) rendered to the end."""
    c = await Conn.open(f.node.port)
    await c.handshake()
    config = FrameDecoder().feed(f.one[0])[0]
    if f.rng.random() < 0.2:
        config["scene"]["background"] = f.rng.choice(
            [[], [0.5], [1, 2, 3, 4], [math.nan] * 3, ["x", 0, 0], [[1, 2, 3]]]
        )
    c.send(encode(config))
    inputs = [config]
    tables = list(f.one[1].items())
    for i, (table, records) in enumerate(tables):
        if f.rng.random() < 0.4:
            records = mutate_records(f.rng, records, f.tame)
        if table == "polygons" and f.rng.random() < 0.02:
            records = np.array(records)
            records["count"][:1] = 2**31 - 1  # one record asking for a huge vertex range
        inputs.append((table, records))
        c.send(
            encode(
                make(
                    Kind.OBJECTS,
                    node=0,
                    table=table,
                    records=np.ascontiguousarray(records),
                    last=i == len(tables) - 1,
                )
            )
        )
    f.recent.append(("render", inputs))
    outcome = "wedged"
    deadline = time.monotonic() + BUILD_TIMEOUT
    while time.monotonic() < deadline:
        m = await c.recv(max(0.01, deadline - time.monotonic()))
        if m is None or m.get("k") == Kind.ERROR:
            f.refusal(m)
            outcome = "refused"
            break
        if m.get("k") == Kind.STATS:
            outcome = "rendered"
            break
    f.count("render", outcome)
    if outcome == "wedged":  # heartbeats, but no end: the tracing thread is stuck
        await c.close()
        f.wedged("render")
        return
    c.send(encode(make(Kind.SHUTDOWN)))
    await c.until_closed()
    await c.close()


async def case_neighbour(f: "Fuzzer") -> None:
    """Node 1 of a 1x2 mesh; we are its host and its neighbour node 0, and send mutated
    RAYS, PIXELS, STATE and other frames on the neighbour link."""
    links = await neighbour_session(f)
    if links is not None:
        await neighbour_stream(f, *links)


async def neighbour_session(f: "Fuzzer") -> tuple[Conn, Conn] | None:
    """Node 1's session started (we are its host) and our link as node 0 attached: (host
    link, neighbour link) once the node says it is ready, or None if it refused or wedged."""
    host = await Conn.open(f.node.port)
    await host.handshake()
    host.send(f.two[0])
    tables = list(f.two[1].items())
    for i, (table, records) in enumerate(tables):
        host.send(
            encode(
                make(
                    Kind.OBJECTS,
                    node=1,
                    table=table,
                    records=records,
                    last=i == len(tables) - 1,
                )
            )
        )
    first = await host.recv()
    if first is None or first.get("k") == Kind.ERROR:
        f.refusal(first)
        f.outcomes["neighbour", "session refused"] += 1
        await host.close()
        return None
    peer = await Conn.open(f.node.port)
    await peer.handshake("node", 0, render=RENDER_ID)
    # The node is ready (engine built, our link attached) when its heartbeat says so.
    deadline = time.monotonic() + BUILD_TIMEOUT
    while time.monotonic() < deadline:
        m = await host.recv(max(0.01, deadline - time.monotonic()))
        if m is None or m.get("k") == Kind.ERROR or m.get("ready") is True:
            break
    else:
        f.outcomes["neighbour", "wedged"] += 1
        await host.close()
        await peer.close()
        f.wedged("neighbour")
        return None
    if m is None or m.get("k") == Kind.ERROR:
        f.refusal(m)
        f.outcomes["neighbour", "session refused"] += 1
        await host.close()
        await peer.close()
        return None
    return host, peer


async def neighbour_stream(f: "Fuzzer", host: Conn, peer: Conn) -> None:
    """Mutated frames on the neighbour link while both links are read, then SHUTDOWN: the
    node must close both."""
    heard: list[dict] = []

    async def drain(conn):  # keep reading, so the node's sends never block on us
        try:
            while (m := await conn.recv(BUILD_TIMEOUT)) is not None:
                heard.append(m)
        except Hang:
            pass

    readers = [asyncio.create_task(drain(host)), asyncio.create_task(drain(peer))]
    for _ in range(f.rng.randint(10, 120)):
        if any(m.get("k") == Kind.ERROR for m in heard):
            break  # the node failed the session: what follows would go unread
        message = neighbour_message(f)
        data = framed(message)
        if data is None:
            continue
        if not peer.send(data):
            break
        f.count("neighbour", "sent", data)
        await asyncio.sleep(0.001)
    host.send(encode(make(Kind.SHUTDOWN)))
    done, pending = await asyncio.wait(readers, timeout=CASE_TIMEOUT * 2)
    for t in pending:
        t.cancel()
    errors = [m for m in heard if m.get("k") == Kind.ERROR]
    f.refusal(errors[0] if errors else None)
    f.outcomes["neighbour", "stream refused" if errors else "stream clean"] += 1
    await host.close()
    await peer.close()
    if pending:
        raise Hang("neighbour: the node kept a link open after SHUTDOWN")


def neighbour_message(f: "Fuzzer") -> dict:
    """A message node 0 might send node 1: RAYS (mostly), PIXELS, STATE, ECHO or any other kind."""
    rng = f.rng
    r = rng.random()
    if r < 0.5:
        rays = np.zeros(rng.randint(1, 64), dtypes.RAY)
        rays["o"] = (0.0, 0.0, -5.0)
        d = np.random.default_rng(rng.randrange(2**32)).normal(size=(len(rays), 3))
        rays["d"] = d / np.linalg.norm(d, axis=1)[:, None]
        rays["t_max"], rays["w"], rays["origin"], rays["depth"] = np.inf, 1.0, -1, 1
        rays["pixel"] = np.arange(len(rays)) % 64
        dest = rng.choice([1, 1, 1, 0, 2, -1, 2**40])
        if rng.random() < 0.7:
            mutated = mutate_records(rng, rays)
            if f.tame:
                bad = ~np.isfinite(mutated["o"]).all(1) | ~np.isfinite(mutated["d"]).all(1)
                mutated[bad] = rays[bad]
            rays = mutated
        cell = rng.choice([1, 1, 1, 0, 2, -1, 2**40])
        return make(Kind.RAYS, rays=rays, dest=dest, cell=cell)
    if r < 0.65:
        deposits = np.zeros(rng.randint(0, 16), dtypes.DEPOSIT)
        deposits["pixel"] = rng.choice([0, 63, 64, -1, 2**62])
        return make(Kind.PIXELS, deposits=deposits, dest=rng.choice([0, 1, 2, -1]))
    if r < 0.72:
        return make(
            Kind.STATE,
            wave=rng.choice([0, 1, 2, 3, -1, 2**40]),
            state=rng.choice([0, 1, 2, 3, 4, 5, 9, -1, 2**40]),
        )
    if r < 0.8:
        return make(
            Kind.ECHO,
            wave=rng.choice([0, 1, 2, -1, 2**40]),
            dirty=rng.random() < 0.5,
            sent=rng.choice([0, 1, -1, 2**62]),
            received=rng.choice([0, 1, -1, 2**63]),
        )
    return mutate_message(rng, valid_message(rng.choice(list(Kind)), rng))


SESSION_CASES = {
    "config": case_config,
    "render": case_render,
    "neighbour": case_neighbour,
}
