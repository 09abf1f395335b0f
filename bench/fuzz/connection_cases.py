"""The cases on a fresh connection, before or during the handshake and just after it: noise,
oversized and truncated frames, mutated HELLO and AUTH, one bad frame, and a burst of half-open
connections. Many run at once in several lanes: each is quick and needs no session."""

import asyncio
import time
from typing import TYPE_CHECKING

from bench.fuzz.conn import CASE_TIMEOUT, Conn, Hang
from bench.fuzz.inputs import framed, kind_of, mutate_message, valid_message
from bench.fuzz.node import CLUSTER, SECRET
from protocols.framing import HEADER, MAX_FRAME, FrameDecoder, encode
from protocols.handshake import auth, check_hello, hello, nonce
from protocols.messages import Kind, make, parse

if TYPE_CHECKING:
    from bench.fuzz.fuzzer import Fuzzer

HANDSHAKE_LIMIT = 4096  # meshnode.transport.link.HANDSHAKE_FRAME
CONNECTION_KINDS = {"garbage": 3, "oversized": 1, "truncated": 1, "hello": 3, "auth": 2, "frame": 4}


async def case_garbage(f: "Fuzzer") -> None:
    """Noise on a fresh connection, then our end of file: the node must hang up too."""
    c = await Conn.open(f.node.port)
    data = f.rng.randbytes(f.rng.randint(0, 2048))
    if f.rng.random() < 0.5:  # a plausible small length prefix in front
        data = HEADER.pack(f.rng.randint(0, 64)) + data
    c.send(data)
    c.end()
    await f.after_eof(c, "garbage", data)


async def case_oversized(f: "Fuzzer") -> None:
    """A length prefix over the handshake limit: refused without our end of file."""
    c = await Conn.open(f.node.port)
    size = f.rng.choice(
        [
            HANDSHAKE_LIMIT + 1,
            MAX_FRAME,
            MAX_FRAME + 1,
            2**32 - 1,
            f.rng.randint(HANDSHAKE_LIMIT + 1, 2**32 - 1),
        ]
    )
    data = HEADER.pack(size) + f.rng.randbytes(f.rng.randint(0, 64))
    c.send(data)
    msgs = await c.until_closed()  # no end of file from us: the node must hang up
    f.refusal(msgs[-1] if msgs else None)
    f.count("oversized", "refused", data)
    await c.close()


async def case_truncated(f: "Fuzzer") -> None:
    """A HELLO cut short, then our end of file: the node must hang up too."""
    c = await Conn.open(f.node.port)
    frame = encode(hello(CLUSTER, "host", -1, nonce()))
    data = frame[: f.rng.randint(0, len(frame) - 1)]
    c.send(data)
    c.end()
    await f.after_eof(c, "truncated", data)


async def case_hello(f: "Fuzzer") -> None:
    """A mutated HELLO: fields dropped, added or retyped, a wrong version, cluster or nonce."""
    c = await Conn.open(f.node.port)
    base = hello(
        f.rng.choice([CLUSTER, CLUSTER, "other"]),
        f.rng.choice(["host", "node"]),
        f.rng.randint(-2, 3),
        nonce(),
    )
    message = mutate_message(f.rng, base)
    data = framed(message)
    if data is None:
        await c.close()
        return
    c.send(data)
    outcome = await c.answer()
    f.count("hello", outcome, data)
    await c.close()


async def case_auth(f: "Fuzzer") -> None:
    """A real HELLO, then a wrong secret, a mutated AUTH or another message in its place."""
    c = await Conn.open(f.node.port)
    mine = parse(hello(CLUSTER, "host", -1, nonce()))[1]
    c.send(encode(make(Kind.HELLO, **mine)))
    theirs = check_hello(await c.expect(), CLUSTER)
    await c.expect()  # the node's AUTH
    how = f.rng.choice(["secret", "speaker", "mutate", "other"])
    if how == "secret":
        message = auth(f.rng.randbytes(f.rng.randint(0, 20)), "dialler", mine, theirs["nonce"])
    elif how == "speaker":
        message = auth(SECRET, "listener", mine, theirs["nonce"])
    elif how == "mutate":
        message = mutate_message(f.rng, auth(SECRET, "dialler", mine, theirs["nonce"]))
    else:
        message = mutate_message(
            f.rng, {"k": int(Kind.CONFIG), **parse(FrameDecoder().feed(f.one[0])[0])[1]}
        )
    data = framed(message)
    if data is None:
        await c.close()
        return
    c.send(data)
    m = await c.recv()
    f.refusal(m)
    outcome = "refused" if m is None or m.get("k") == Kind.ERROR else "welcomed"
    f.count("auth", outcome, data)
    await c.close()


async def case_frame(f: "Fuzzer") -> None:
    """A real handshake, then one mutated frame of any kind, or corrupt frame bytes."""
    c = await Conn.open(f.node.port)
    await c.handshake()
    kind = f.rng.choice([k for k in Kind if k is not Kind.CONFIG])
    how = f.rng.random()
    if how < 0.6:
        message = mutate_message(f.rng, valid_message(kind, f.rng))
        if kind_of(message) == Kind.CONFIG:  # no session from this lane
            message["k"] = int(Kind.STATS)
        data = framed(message)
        if data is None:
            await c.close()
            return
    elif how < 0.8:  # a real frame with bytes flipped (the prefix kept)
        raw = bytearray(encode(valid_message(kind, f.rng)))
        for _ in range(f.rng.randint(1, 4)):
            at = f.rng.randrange(HEADER.size, len(raw)) if len(raw) > 4 else 0
            raw[at] = f.rng.randrange(256)
        data = bytes(raw)
    elif how < 0.9:  # over the whole-frame limit
        data = HEADER.pack(f.rng.randint(MAX_FRAME + 1, 2**32 - 1)) + b"\x80" * 32
    else:  # cut short, then end of file
        raw = encode(valid_message(kind, f.rng))
        data = raw[: f.rng.randint(0, len(raw) - 1)]
    c.send(data)
    if how >= 0.9:
        c.end()
    msgs = await c.until_closed()
    f.refusal(msgs[-1] if msgs else None)
    f.count("frame", "refused" if msgs or c.eof else "answered", data)
    await c.close()


async def case_burst(f: "Fuzzer", n: int = 80) -> None:
    """n connections at once that each send half a HELLO and wait: refused at once past
    the node's limit, or dropped by its handshake timeout; all must close in time."""
    frame = encode(hello(CLUSTER, "host", -1, nonce()))

    async def one():
        c = await Conn.open(f.node.port)
        c.send(frame[:10])
        start = time.monotonic()
        await c.until_closed(CASE_TIMEOUT)
        await c.close()
        return time.monotonic() - start

    waits = await asyncio.gather(*(one() for _ in range(n)), return_exceptions=True)
    for w in waits:
        if isinstance(w, Hang):
            f.hangs.append(f"burst: {w}")
            f.outcomes["burst", "hang"] += 1
        elif isinstance(w, BaseException):
            f.outcomes["burst", f"connection: {type(w).__name__}"] += 1
        else:
            f.count("burst", "refused at once" if w < 1.0 else "timed out by the node")


CONNECTION_CASES = {
    "garbage": case_garbage,
    "oversized": case_oversized,
    "truncated": case_truncated,
    "hello": case_hello,
    "auth": case_auth,
    "frame": case_frame,
    "burst": case_burst,
}
