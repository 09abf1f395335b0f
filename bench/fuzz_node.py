"""Fuzz one running node over loopback: bounded in cases and in wall time, every case answered
or refused within a timeout, the node alive and serving at the end.

    python -m bench.fuzz_node [--cases 100000] [--seconds 600] [--seed 0] [--lanes 6]

Starts `python -m meshnode.service.cli serve --listen 127.0.0.1:0 --threads 1` with
MESHTRACE_SECRET in its environment (stderr to a temporary file, address from its
`listening HOST:PORT` line) and sends it cases from several lanes at once:

    garbage     noise on a fresh connection, then end of file: the node must hang up too
    oversized   a length prefix over the handshake limit: refused without our end of file
    truncated   a HELLO cut short, then end of file: the node must hang up too
    hello       a mutated HELLO (fields dropped, added, retyped, wrong version/cluster/nonce)
    auth        a real HELLO, then a wrong secret, a mutated AUTH or another message
    frame       a real handshake, then one mutated frame of any kind, or corrupt frame bytes
    config      (session lane, alone, for the last 2% of the cases)
                a real handshake, then a mutated CONFIG; when accepted, the
    objects       same connection carries mutated OBJECTS batches, then SHUTDOWN
    render      (session lane) a small all-kinds scene with mutated records and background,
                  rendered to the end (STATS) or refused (ERROR)
    neighbour   (session lane) a 1x2 mesh: we are the host and node 0; node 1 (the node under
                  test) gets mutated RAYS, PIXELS, STATE and other frames on its neighbour link
    burst       (once at start and end) 80 half-open connections at once, past the node's limit
                  of 64: refused at once or dropped by the handshake timeout

A case sent on a connection that the node has already refused is not counted. The node runs
under `python -X faulthandler` with an address-space limit (--memory-mb), so an unbounded
allocation is a MemoryError rather than the machine's OOM killer. Its RSS (VmRSS) is sampled
every 0.5 s and its liveness checked; a node that dies is a crash, its last 200 inputs pickled
and the node restarted. A node that still sends heartbeats but never finishes a render or a
build is wedged (its one tracing thread is stuck): it gets SIGABRT, so faulthandler writes
every thread's stack to its stderr, its last inputs are pickled, and it is restarted. At the
end one real 8x8 render runs through host.run.meshclient.render_on_mesh.

Printed: cases sent (and per kind, with outcomes), the node's refusal reasons, crashes, wedges,
tracebacks in the node's stderr (with their last lines), hangs (cases past their timeout),
connections the node left open after our end of file, cases over 5 s, peak and final RSS, the
final render, and where the stderr was kept. Exits 1 on any crash, wedge, traceback, hang or
connection left open, or a failed final render.
"""

import argparse
import asyncio
import collections
import math
import os
import random
import re
import resource
import select
import signal
import subprocess
import sys
import tempfile
import time
from dataclasses import asdict
from pathlib import Path

if __package__ in (None, ""):
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import numpy as np  # noqa: E402

from host.planning.plan import plan_render  # noqa: E402
from host.run.meshclient import render_on_mesh  # noqa: E402
from host.scene.subset import subset  # noqa: E402
from meshnode.service.cli import _all_kinds_scene  # noqa: E402
from protocols import dtypes  # noqa: E402
from protocols.errors import ProtocolError  # noqa: E402
from protocols.framing import HEADER, MAX_FRAME, FrameDecoder, encode  # noqa: E402
from protocols.handshake import auth, check_auth, check_hello, hello, nonce  # noqa: E402
from protocols.messages import FIELDS, OBJECT_TABLES, Kind, make, parse  # noqa: E402
from protocols.render import EngineSpec, ImageSpec, MeshPlan  # noqa: E402

SECRET = b"fuzz-node secret"
CLUSTER = "meshtrace"
CASE_TIMEOUT = 15.0  # s: the node drops a stalled handshake after 10 s
BUILD_TIMEOUT = 90.0  # s: a render's engine build may compile a new kernel variant
EOF_SECONDS = 2.0  # s: after our end of file, the node closes its side within this
EOF_WAITERS = 48  # connections waiting for the node's close at once
SPIN_SECONDS = 40.0  # s of CPU in one tracing thread within ~60 s: stuck, not rendering 8x8
HANDSHAKE_LIMIT = 4096  # meshnode.transport.link.HANDSHAKE_FRAME
ODD_NUMBERS = [
    0,
    1,
    -1,
    2,
    3,
    7,
    255,
    256,
    65535,
    65536,
    2**31 - 1,
    2**31,
    -(2**31) - 1,
    2**63 - 1,
    -(2**63),
    2**64 - 1,
    0.5,
    -0.0,
    5e-324,
    1e-300,
    1e300,
    1e308,
    -1e308,
    math.inf,
    -math.inf,
    math.nan,
    True,
    False,
]


RENDER_ID = b"r" * 16  # the render id of the CONFIGs sent here


class Hang(Exception):
    """A case got neither an answer nor a refusal within its timeout."""


# ------------------------------------------------------------------ random inputs


def odd_scalar(rng: random.Random):
    """A value a hostile peer might send: odd numbers, strings, bytes, None, wire arrays."""
    r = rng.random()
    if r < 0.4:
        return rng.choice(ODD_NUMBERS)
    if r < 0.55:
        return rng.randint(-(2**63), 2**64 - 1)
    if r < 0.65:
        return rng.uniform(-1e6, 1e6)
    if r < 0.75:
        return rng.choice(["", "x", "auto", "even", "nan", "1", "\u00e9\u0000", "a" * 300])
    if r < 0.82:
        return rng.randbytes(rng.randint(0, 40))
    if r < 0.87:
        return None
    return wire_array(rng)


def odd_value(rng: random.Random, depth: int = 0):
    r = rng.random()
    if depth < 2 and r < 0.1:
        return [odd_value(rng, depth + 1) for _ in range(rng.randint(0, 3))]
    if depth < 2 and r < 0.18:
        return {odd_key(rng): odd_value(rng, depth + 1) for _ in range(rng.randint(0, 3))}
    return odd_scalar(rng)


def odd_key(rng: random.Random):
    """A field name: a real one of some kind, "k", or text or bytes (bytes keys included)."""
    r = rng.random()
    if r < 0.5:
        return rng.choice(sorted({f for spec in FIELDS.values() for f in spec} | {"k"}))
    if r < 0.8:
        return rng.choice(["", "x", "node ", "K", "\u00e9"])
    return rng.randbytes(rng.randint(0, 4))


def wire_array(rng: random.Random, dtype=None, n=None) -> np.ndarray:
    """An array of a wire dtype with records of arbitrary bytes (NaN, huge, negative values)."""
    dtype = dtype if dtype is not None else rng.choice(list(dtypes.WIRE_DTYPES.values()))
    n = rng.randint(0, 4) if n is None else n
    return np.frombuffer(rng.randbytes(n * dtype.itemsize), dtype).copy()


def mutate_message(rng: random.Random, message: dict) -> dict:
    """1 to 3 top-level changes: a field dropped, added, retyped, an array of another dtype."""
    m = dict(message)
    for _ in range(rng.randint(1, 3)):
        op = rng.choice(["drop", "add", "retype", "array", "kind"])
        if op == "drop" and m:
            del m[rng.choice(list(m))]
        elif op == "add":
            m[odd_key(rng)] = odd_value(rng)
        elif op == "retype" and m:
            m[rng.choice(list(m))] = odd_value(rng)
        elif op == "array":
            arrays = [k for k, v in m.items() if isinstance(v, np.ndarray)]
            if arrays:
                m[rng.choice(arrays)] = wire_array(rng)
        elif op == "kind":
            m["k"] = rng.choice([*range(0, 16), -1, 2**40, None, "1", 1.0])
    return m


def mutate_tree(rng: random.Random, tree, changes: int = 3):
    """Changes anywhere inside a tree of dicts and lists: a value replaced by an odd one,
    removed, wrapped in a list, a list grown, a key added, an array swapped."""
    for _ in range(rng.randint(1, changes)):
        parent, key, node = None, None, tree
        while isinstance(node, dict | list) and node and (parent is None or rng.random() < 0.7):
            parent, key = (
                node,
                rng.choice(list(node) if isinstance(node, dict) else range(len(node))),
            )
            node = parent[key]
        if parent is None:
            return tree
        op = rng.choice(["replace", "replace", "replace", "drop", "wrap", "grow", "add"])
        if op == "replace":
            parent[key] = odd_value(rng)
        elif op == "drop":
            del parent[key]
        elif op == "wrap":
            parent[key] = [node]
        elif op == "grow" and isinstance(node, list) and node:
            node.extend([node[0]] * rng.choice([1, 2, 1023, 1024, 5000]))
        elif isinstance(parent, dict):
            parent[odd_key(rng)] = odd_value(rng)
        else:
            parent.insert(rng.randint(0, len(parent)), odd_value(rng))
    return tree


def mutate_records(rng: random.Random, records: np.ndarray, tame: bool = False) -> np.ndarray:
    """Records with some fields set to odd values (NaN, infinite, huge, negative, out of any
    table's range), or some bytes replaced; `tame`: floats stay finite and within 1e6 (the
    known wedges come from non-finite and overflowing geometry)."""
    out = np.array(records)
    if len(out) == 0:
        return out
    for _ in range(rng.randint(1, 4)):
        i = rng.randrange(len(out))
        if out.dtype.names is None or (rng.random() < 0.2 and not tame):
            raw = bytearray(out.tobytes())
            at = rng.randrange(len(raw))
            raw[at : at + 8] = rng.randbytes(min(8, len(raw) - at))
            out = np.frombuffer(bytes(raw), out.dtype).copy()
            continue
        name = rng.choice(out.dtype.names)
        kind = out.dtype[name].base.kind
        if kind == "f":
            value = rng.choice(
                [0.0, -1.0, 1e-300, 1e6, -1e6, 0.5]
                if tame
                else [math.nan, math.inf, -math.inf, 1e300, -1e300, 0.0, -1.0, 1e-300]
            )
        else:
            info = np.iinfo(out.dtype[name].base)
            value = rng.choice([info.min, info.max, -1, 0, 1, 2, 3, 7, 1000, 2**31 - 1])
            value = min(max(value, info.min), info.max)
        out[name][i] = value
    return out


# ------------------------------------------------------------------ the node


class Node:
    """The node under test: a `meshnode serve` subprocess, restarted if it dies."""

    def __init__(self, stderr_path: Path, memory_mb: int):
        self.stderr_path, self.memory_mb = stderr_path, memory_mb
        self.proc: subprocess.Popen | None = None
        self.port = 0
        self.crashes: list[dict] = []  # the process died
        self.wedges: list[dict] = []  # alive, but its tracing thread never came back
        self.rss_peak = self.rss_last = 0

    def start(self) -> None:
        env = {**os.environ, "MESHTRACE_SECRET": SECRET.decode()}
        limit = self.memory_mb << 20

        def cap():  # a node that tries to allocate without bound gets MemoryError, not the OOM
            resource.setrlimit(resource.RLIMIT_AS, (limit, limit))

        with open(self.stderr_path, "ab") as err:
            self.proc = subprocess.Popen(
                [
                    sys.executable,
                    "-X",
                    "faulthandler",
                    "-m",
                    "meshnode.service.cli",
                    "serve",
                    "--listen",
                    "127.0.0.1:0",
                    "--threads",
                    "1",
                ],
                stdout=subprocess.PIPE,
                stderr=err,
                text=True,
                env=env,
                preexec_fn=cap if self.memory_mb else None,
            )
        ready, _, _ = select.select([self.proc.stdout], [], [], 120)
        line = self.proc.stdout.readline() if ready else ""
        if not line.startswith("listening "):
            raise RuntimeError(f"meshnode did not start: {line!r}")
        self.port = int(line.split()[1].rsplit(":", 1)[1])

    def alive(self) -> bool:
        return self.proc is not None and self.proc.poll() is None

    def busiest_thread(self) -> float:
        """CPU seconds of the node's busiest thread other than the event loop's."""
        ticks = os.sysconf("SC_CLK_TCK")
        most = 0.0
        for task in Path(f"/proc/{self.proc.pid}/task").glob("*"):
            if task.name == str(self.proc.pid):
                continue
            try:
                fields = (task / "stat").read_text().rsplit(")", 1)[1].split()
            except OSError:
                continue
            most = max(most, (int(fields[11]) + int(fields[12])) / ticks)
        return most

    def sample(self) -> None:
        try:
            text = Path(f"/proc/{self.proc.pid}/status").read_text()
        except OSError:
            return
        m = re.search(r"VmRSS:\s+(\d+) kB", text)
        if m:
            self.rss_last = int(m.group(1)) * 1024
            self.rss_peak = max(self.rss_peak, self.rss_last)

    def stop(self) -> None:
        if self.alive():
            self.proc.terminate()
            try:
                self.proc.wait(10)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()
        if self.proc is not None and self.proc.stdout:
            self.proc.stdout.close()


# ------------------------------------------------------------------ a connection


class Conn:
    """One raw connection to the node, with its own frame decoder (any frame size)."""

    def __init__(self, reader, writer):
        self.reader, self.writer = reader, writer
        self.decoder = FrameDecoder(MAX_FRAME)
        self.ready: list[dict] = []
        self.eof = False

    @classmethod
    async def open(cls, port: int) -> "Conn":
        reader, writer = await asyncio.wait_for(
            asyncio.open_connection("127.0.0.1", port), CASE_TIMEOUT
        )
        return cls(reader, writer)

    def send(self, data: bytes) -> bool:
        """Write unless the node has hung up; False once it has."""
        if self.eof or self.writer.is_closing():
            return False
        try:
            self.writer.write(data)
        except (ConnectionError, RuntimeError):
            self.eof = True
            return False
        return True

    def end(self) -> None:
        try:
            if not self.writer.is_closing():
                self.writer.write_eof()
        except (OSError, RuntimeError):
            pass

    async def recv(self, timeout: float = CASE_TIMEOUT) -> dict | None:
        """The next message, or None once the node has closed the connection."""
        deadline = time.monotonic() + timeout
        while not self.ready:
            if self.eof:
                return None
            left = deadline - time.monotonic()
            if left <= 0:
                raise Hang("no message and no close")
            try:
                data = await asyncio.wait_for(self.reader.read(1 << 20), left)
            except (ConnectionError, OSError):
                data = b""
            except TimeoutError:
                raise Hang("no message and no close") from None
            if not data:
                self.eof = True
                continue
            self.ready.extend(self.decoder.feed(data))
        return self.ready.pop(0)

    async def until_closed(self, timeout: float = CASE_TIMEOUT) -> list[dict]:
        """Every message until the node closes the connection (Hang if it does not)."""
        got = []
        deadline = time.monotonic() + timeout
        while (m := await self.recv(max(0.01, deadline - time.monotonic()))) is not None:
            got.append(m)
        return got

    async def answer(self, timeout: float = CASE_TIMEOUT) -> str:
        """How the node took what we sent: 'refused' (ERROR and/or close) or 'answered'."""
        m = await self.recv(timeout)
        if m is None or m.get("k") == Kind.ERROR:
            return "refused"
        return "answered"

    async def expect(self) -> dict:
        """The next message; ConnectionError if the node hangs up first (a full node)."""
        m = await self.recv()
        if m is None:
            raise ConnectionError("the node closed the connection")
        return m

    async def handshake(
        self, role: str = "host", node: int = -1, secret: bytes = SECRET, render: bytes = b""
    ):
        """The dialler's side of protocols.handshake; returns the node's HELLO fields."""
        mine = parse(hello(CLUSTER, role, node, nonce(), render))[1]
        self.send(encode(make(Kind.HELLO, **mine)))
        theirs = check_hello(await self.expect(), CLUSTER)
        check_auth(await self.expect(), SECRET, "listener", mine, theirs["nonce"])
        self.send(encode(auth(secret, "dialler", mine, theirs["nonce"])))
        welcome = await self.recv()
        if welcome is None or welcome.get("k") != Kind.WELCOME:
            raise ConnectionError(f"handshake refused: {welcome}")
        return theirs

    async def close(self) -> None:
        self.writer.close()
        try:
            await asyncio.wait_for(self.writer.wait_closed(), 5)
        except (OSError, RuntimeError, TimeoutError):
            pass


# ------------------------------------------------------------------ the fuzzer


class Fuzzer:
    def __init__(self, node: Node, rng: random.Random, cases: int, seconds: float, save: Path):
        self.node, self.rng = node, rng
        self.limit, self.deadline = cases, time.monotonic() + seconds
        self.save = save
        self.sent = 0
        self.kinds: collections.Counter = collections.Counter()
        self.outcomes: collections.Counter = collections.Counter()
        self.hangs: list[str] = []
        self.errors: collections.Counter = collections.Counter()  # node ERROR reasons, by shape
        self.recent: collections.deque = collections.deque(maxlen=200)  # inputs, for crashes
        self.scene = _all_kinds_scene()
        self.one = self._session(MeshPlan(1, 1), 0, ImageSpec(width=8, height=8))
        self.two = self._session(MeshPlan(1, 2), 1, ImageSpec(width=8, height=8))
        self.slow: list = []  # (seconds, kind, when) of cases that took over 5 s
        self.tame = False  # set after the first wedge: fuzz past the known ones
        self.left_open = 0  # connections the node kept open after our end of file
        self.in_session = False  # the session lane is in a case (the node refuses hosts)
        self.eof_waiters = asyncio.Semaphore(EOF_WAITERS)
        self.background: set[asyncio.Task] = set()
        self.eof_close: dict = collections.defaultdict(list)  # kind -> s until the node hung up

    def _session(self, plan: MeshPlan, n: int, image: ImageSpec):
        """A real CONFIG for node n and its objects, as host.run.meshclient makes them."""
        planned = plan_render(self.scene, image, EngineSpec(), plan)
        neighbours = {str(m): "127.0.0.1:9" for m in range(plan.nodes)}
        config = make(
            Kind.CONFIG,
            node=n,
            neighbours=neighbours,
            render=planned.spec.to_wire(),
            partition=planned.partition.to_wire(),
            view=asdict(self.scene.view),
            background=list(self.scene.background),
            render_id=RENDER_ID,
        )
        scene = subset(self.scene, np.ones_like(planned.holders[n]))  # every object: one variant
        tables = {
            "materials": scene.materials,
            "lights": scene.lights,
            "spheres": scene.spheres,
            "triangles": scene.triangles,
            "polygons": scene.polygons,
            "vertices": scene.vertices.reshape(-1),
            "cones": scene.cones,
        }
        return encode(config), tables

    def more(self) -> bool:
        return self.sent < self.limit and time.monotonic() < self.deadline

    def count(self, kind: str, outcome: str, data=None, n: int = 1) -> None:
        self.sent += n
        self.kinds[kind] += n
        self.outcomes[kind, outcome] += n
        if data is not None:
            self.recent.append((kind, data))

    def refusal(self, message: dict | None) -> None:
        if message is not None and message.get("k") == Kind.ERROR:
            reason = str(message.get("reason", ""))
            self.errors[re.sub(r"\d+|'[^']*'|\"[^\"]*\"", "#", reason)[:90]] += 1

    # -------------------------------------------------------------- lanes

    async def lane(self, kinds: dict, share: float = 1.0, session: bool = False) -> None:
        """Cases of `kinds` (name: weight) one after another, until `share` of all cases are
        sent. A session makes the node refuse other hosts, so the session lane starts once
        the other lanes are done (and they leave `frame` cases out while it is in a case)."""
        while session and self.more() and self.sent < (1.0 - SESSION_SHARE) * self.limit:
            await asyncio.sleep(0.1)
        while self.more() and self.sent < share * self.limit:
            names = [k for k in kinds if session or k != "frame" or not self.in_session]
            if not names:
                await asyncio.sleep(0.05)
                continue
            kind = self.rng.choices(names, [kinds[k] for k in names])[0]
            port, start = self.node.port, time.monotonic()
            if session:
                self.in_session = True
            try:
                await getattr(self, kind)()
                took = time.monotonic() - start
                if took > 5.0:
                    self.slow.append((round(took, 1), kind, time.strftime("%H:%M:%S")))
            except Hang as e:
                self.hangs.append(f"{kind}: {e}")
                self.outcomes[kind, "hang"] += 1
            except (ConnectionError, OSError, TimeoutError, ProtocolError) as e:
                if self.node.port == port and self.node.alive():
                    self.outcomes[kind, f"connection: {type(e).__name__}"] += 1
                await asyncio.sleep(0.01)
            finally:
                if session:
                    self.in_session = False

    async def garbage(self) -> None:
        c = await Conn.open(self.node.port)
        data = self.rng.randbytes(self.rng.randint(0, 2048))
        if self.rng.random() < 0.5:  # a plausible small length prefix in front
            data = HEADER.pack(self.rng.randint(0, 64)) + data
        c.send(data)
        c.end()
        await self.after_eof(c, "garbage", data)

    async def after_eof(self, c: Conn, kind: str, data: bytes) -> None:
        """After our end of file the node must hang up too; one that keeps its side open for
        EOF_SECONDS leaks the connection (it no longer counts toward its limit). Waited for
        in the background, at most EOF_WAITERS connections at once, so the lane goes on."""
        await self.eof_waiters.acquire()

        async def wait():
            start = time.monotonic()
            try:
                msgs = await c.until_closed(EOF_SECONDS)
                self.eof_close[kind].append(time.monotonic() - start)
                self.refusal(msgs[-1] if msgs else None)
                self.count(kind, "closed", data)
            except Hang:
                self.left_open += 1
                self.count(kind, "left open", data)
            except (ConnectionError, OSError):
                self.count(kind, "closed", data)
            finally:
                await c.close()
                self.eof_waiters.release()

        task = asyncio.create_task(wait())
        self.background.add(task)
        task.add_done_callback(self.background.discard)

    async def oversized(self) -> None:
        c = await Conn.open(self.node.port)
        size = self.rng.choice(
            [
                HANDSHAKE_LIMIT + 1,
                MAX_FRAME,
                MAX_FRAME + 1,
                2**32 - 1,
                self.rng.randint(HANDSHAKE_LIMIT + 1, 2**32 - 1),
            ]
        )
        data = HEADER.pack(size) + self.rng.randbytes(self.rng.randint(0, 64))
        c.send(data)
        msgs = await c.until_closed()  # no end of file from us: the node must hang up
        self.refusal(msgs[-1] if msgs else None)
        self.count("oversized", "refused", data)
        await c.close()

    async def truncated(self) -> None:
        c = await Conn.open(self.node.port)
        frame = encode(hello(CLUSTER, "host", -1, nonce()))
        data = frame[: self.rng.randint(0, len(frame) - 1)]
        c.send(data)
        c.end()
        await self.after_eof(c, "truncated", data)

    async def hello(self) -> None:
        c = await Conn.open(self.node.port)
        base = hello(
            self.rng.choice([CLUSTER, CLUSTER, "other"]),
            self.rng.choice(["host", "node"]),
            self.rng.randint(-2, 3),
            nonce(),
        )
        message = mutate_message(self.rng, base)
        data = _frame(message)
        if data is None:
            await c.close()
            return
        c.send(data)
        outcome = await c.answer()
        self.count("hello", outcome, data)
        await c.close()

    async def auth(self) -> None:
        c = await Conn.open(self.node.port)
        mine = parse(hello(CLUSTER, "host", -1, nonce()))[1]
        c.send(encode(make(Kind.HELLO, **mine)))
        theirs = check_hello(await c.expect(), CLUSTER)
        await c.expect()  # the node's AUTH
        how = self.rng.choice(["secret", "speaker", "mutate", "other"])
        if how == "secret":
            message = auth(
                self.rng.randbytes(self.rng.randint(0, 20)), "dialler", mine, theirs["nonce"]
            )
        elif how == "speaker":
            message = auth(SECRET, "listener", mine, theirs["nonce"])
        elif how == "mutate":
            message = mutate_message(self.rng, auth(SECRET, "dialler", mine, theirs["nonce"]))
        else:
            message = mutate_message(
                self.rng, {"k": int(Kind.CONFIG), **parse(FrameDecoder().feed(self.one[0])[0])[1]}
            )
        data = _frame(message)
        if data is None:
            await c.close()
            return
        c.send(data)
        m = await c.recv()
        self.refusal(m)
        outcome = "refused" if m is None or m.get("k") == Kind.ERROR else "welcomed"
        self.count("auth", outcome, data)
        await c.close()

    async def frame(self) -> None:
        c = await Conn.open(self.node.port)
        await c.handshake()
        kind = self.rng.choice([k for k in Kind if k is not Kind.CONFIG])
        how = self.rng.random()
        if how < 0.6:
            message = mutate_message(self.rng, _valid(kind, self.rng))
            if _kind(message) == Kind.CONFIG:  # no session from this lane
                message["k"] = int(Kind.STATS)
            data = _frame(message)
            if data is None:
                await c.close()
                return
        elif how < 0.8:  # a real frame with bytes flipped (the prefix kept)
            raw = bytearray(encode(_valid(kind, self.rng)))
            for _ in range(self.rng.randint(1, 4)):
                at = self.rng.randrange(HEADER.size, len(raw)) if len(raw) > 4 else 0
                raw[at] = self.rng.randrange(256)
            data = bytes(raw)
        elif how < 0.9:  # over the whole-frame limit
            data = HEADER.pack(self.rng.randint(MAX_FRAME + 1, 2**32 - 1)) + b"\x80" * 32
        else:  # cut short, then end of file
            raw = encode(_valid(kind, self.rng))
            data = raw[: self.rng.randint(0, len(raw) - 1)]
        c.send(data)
        if how >= 0.9:
            c.end()
        msgs = await c.until_closed()
        self.refusal(msgs[-1] if msgs else None)
        self.count("frame", "refused" if msgs or c.eof else "answered", data)
        await c.close()

    async def config(self) -> None:
        """A mutated CONFIG; if accepted, mutated OBJECTS on the same link, then SHUTDOWN."""
        c = await Conn.open(self.node.port)
        await c.handshake()
        fields = FrameDecoder().feed(self.one[0])[0]
        mutate_tree(self.rng, fields)
        fields["k"] = int(Kind.CONFIG)
        try:
            data = encode(fields)
        except (TypeError, ValueError, OverflowError):
            await c.close()
            return
        c.send(data)
        # A refusal comes at once; an accepted CONFIG starts a session, heard within 1 s.
        m = await c.recv()
        self.refusal(m)
        if m is None or m.get("k") == Kind.ERROR:
            self.count("config", "refused", data)
            await c.close()
            return
        self.count("config", "accepted", data)
        for _ in range(self.rng.randint(5, 60)):
            table = self.rng.choice(sorted(OBJECT_TABLES))
            records = self.one[1][table]
            if self.rng.random() < 0.7:
                message = make(
                    Kind.OBJECTS,
                    node=0,
                    table=table,
                    records=mutate_records(self.rng, records),
                    last=False,
                )
            else:
                message = mutate_message(
                    self.rng, make(Kind.OBJECTS, node=0, table=table, records=records, last=False)
                )
                if _kind(message) in (Kind.CONFIG, Kind.SHUTDOWN):
                    message["k"] = int(Kind.OBJECTS)
                if message.get("last") is True:
                    message["last"] = False
            data = _frame(message)
            if data is None:
                continue
            if not c.send(data):
                break
            self.count("objects", "sent", data)
            await asyncio.sleep(0)
        c.send(encode(make(Kind.SHUTDOWN)))
        msgs = await c.until_closed()
        errors = [m for m in msgs if m.get("k") == Kind.ERROR]
        self.refusal(errors[0] if errors else None)
        self.outcomes["objects", "stream refused" if errors else "stream clean"] += 1
        await c.close()

    async def render(self) -> None:
        """A small scene with mutated records (and sometimes background) rendered to the end."""
        c = await Conn.open(self.node.port)
        await c.handshake()
        config = FrameDecoder().feed(self.one[0])[0]
        if self.rng.random() < 0.2:
            config["background"] = self.rng.choice(
                [[], [0.5], [1, 2, 3, 4], [math.nan] * 3, ["x", 0, 0], [[1, 2, 3]]]
            )
        c.send(encode(config))
        inputs = [config]
        tables = list(self.one[1].items())
        for i, (table, records) in enumerate(tables):
            if self.rng.random() < 0.4:
                records = mutate_records(self.rng, records, self.tame)
            if table == "polygons" and self.rng.random() < 0.02:
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
        self.recent.append(("render", inputs))
        outcome = "wedged"
        deadline = time.monotonic() + BUILD_TIMEOUT
        while time.monotonic() < deadline:
            m = await c.recv(max(0.01, deadline - time.monotonic()))
            if m is None or m.get("k") == Kind.ERROR:
                self.refusal(m)
                outcome = "refused"
                break
            if m.get("k") == Kind.STATS:
                outcome = "rendered"
                break
        self.count("render", outcome)
        if outcome == "wedged":  # heartbeats, but no end: the tracing thread is stuck
            await c.close()
            self.wedged("render")
            return
        c.send(encode(make(Kind.SHUTDOWN)))
        await c.until_closed()
        await c.close()

    async def neighbour(self) -> None:
        """Node 1 of a 1x2 mesh; we are its host and its neighbour node 0, and send mutated
        RAYS, PIXELS, STATE and other frames on the neighbour link."""
        host = await Conn.open(self.node.port)
        await host.handshake()
        host.send(self.two[0])
        tables = list(self.two[1].items())
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
            self.refusal(first)
            self.outcomes["neighbour", "session refused"] += 1
            await host.close()
            return
        peer = await Conn.open(self.node.port)
        await peer.handshake("node", 0, render=RENDER_ID)
        # The node is ready (engine built, our link attached) when its heartbeat says so.
        deadline = time.monotonic() + BUILD_TIMEOUT
        while time.monotonic() < deadline:
            m = await host.recv(max(0.01, deadline - time.monotonic()))
            if m is None or m.get("k") == Kind.ERROR or m.get("ready") is True:
                break
        else:
            self.outcomes["neighbour", "wedged"] += 1
            await host.close()
            await peer.close()
            self.wedged("neighbour")
            return
        if m is None or m.get("k") == Kind.ERROR:
            self.refusal(m)
            self.outcomes["neighbour", "session refused"] += 1
            await host.close()
            await peer.close()
            return
        heard: list[dict] = []

        async def drain(conn):  # keep reading, so the node's sends never block on us
            try:
                while (m := await conn.recv(BUILD_TIMEOUT)) is not None:
                    heard.append(m)
            except Hang:
                pass

        readers = [asyncio.create_task(drain(host)), asyncio.create_task(drain(peer))]
        for _ in range(self.rng.randint(10, 120)):
            if any(m.get("k") == Kind.ERROR for m in heard):
                break  # the node failed the session: what follows would go unread
            message = self._neighbour_message()
            data = _frame(message)
            if data is None:
                continue
            if not peer.send(data):
                break
            self.count("neighbour", "sent", data)
            await asyncio.sleep(0.001)
        host.send(encode(make(Kind.SHUTDOWN)))
        done, pending = await asyncio.wait(readers, timeout=CASE_TIMEOUT * 2)
        for t in pending:
            t.cancel()
        errors = [m for m in heard if m.get("k") == Kind.ERROR]
        self.refusal(errors[0] if errors else None)
        self.outcomes["neighbour", "stream refused" if errors else "stream clean"] += 1
        await host.close()
        await peer.close()
        if pending:
            raise Hang("neighbour: the node kept a link open after SHUTDOWN")

    def _neighbour_message(self) -> dict:
        rng = self.rng
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
                if self.tame:
                    bad = ~np.isfinite(mutated["o"]).all(1) | ~np.isfinite(mutated["d"]).all(1)
                    mutated[bad] = rays[bad]
                rays = mutated
            return make(Kind.RAYS, rays=rays, dest=dest)
        if r < 0.65:
            deposits = np.zeros(rng.randint(0, 16), dtypes.DEPOSIT)
            deposits["pixel"] = rng.choice([0, 63, 64, -1, 2**62])
            return make(Kind.PIXELS, deposits=deposits, dest=rng.choice([0, 1, 2, -1]))
        if r < 0.8:
            n = rng.choice([2, 2, 0, 1, 3, 1000])
            return make(
                Kind.STATE,
                state=rng.choice([0, 1, 2, 3, 4, 5, 9, -1, 2**40]),
                last_busy=rng.choice([0, 1, -1, 5]),
                round=rng.choice([0, 1, 2, -1]),
                sent=np.zeros(n, "<i8") + rng.choice([0, 1, -1]),
                received=np.zeros(n, "<i8"),
                dest=rng.choice([1, 0, 7]),
            )
        return mutate_message(rng, _valid(rng.choice(list(Kind)), rng))

    async def burst(self, n: int = 80) -> None:
        """n connections at once that each send half a HELLO and wait: refused at once past
        the node's limit, or dropped by its handshake timeout; all must close in time."""
        frame = encode(hello(CLUSTER, "host", -1, nonce()))

        async def one():
            c = await Conn.open(self.node.port)
            c.send(frame[:10])
            start = time.monotonic()
            await c.until_closed(CASE_TIMEOUT)
            await c.close()
            return time.monotonic() - start

        waits = await asyncio.gather(*(one() for _ in range(n)), return_exceptions=True)
        for w in waits:
            if isinstance(w, Hang):
                self.hangs.append(f"burst: {w}")
                self.outcomes["burst", "hang"] += 1
            elif isinstance(w, BaseException):
                self.outcomes["burst", f"connection: {type(w).__name__}"] += 1
            else:
                self.count("burst", "refused at once" if w < 1.0 else "timed out by the node")

    def wedged(self, kind: str) -> None:
        """The node lives but its one tracing thread is stuck: keep the last inputs, make it
        print every thread's stack (faulthandler, on SIGABRT) and start another."""
        import pickle

        path = self.save / f"wedge-{len(self.node.wedges)}.pickle"
        path.write_bytes(pickle.dumps(list(self.recent)))
        self.node.wedges.append({"kind": kind, "inputs": str(path), "after_cases": self.sent})
        print(
            f"node wedged ({kind}) after {self.sent} cases; last inputs in {path}", file=sys.stderr
        )
        self.node.proc.send_signal(signal.SIGABRT)
        try:
            self.node.proc.wait(10)
        except subprocess.TimeoutExpired:
            pass
        self.node.stop()
        self.node.start()
        if not self.tame:
            self.tame = True
            print(
                "from now on RAYS keep finite origins and directions and render records keep "
                "finite floats within 1e6 (known wedges: a ray with a NaN direction, a light "
                "at NaN, never finish tracing)",
                file=sys.stderr,
            )

    async def watch(self) -> None:
        """Sample RSS; a dead node is a crash: keep its last inputs and start another. A
        tracing thread that burns SPIN_SECONDS of CPU within as many seconds is wedged (the
        renders here are 8x8; a kernel compile takes less)."""
        history: collections.deque = collections.deque()
        while self.more():
            await asyncio.sleep(0.5)
            if self.node.alive():
                self.node.sample()
                now, cpu = time.monotonic(), self.node.busiest_thread()
                history.append((now, cpu, self.node.port))
                while history and now - history[0][0] > SPIN_SECONDS * 1.5:
                    history.popleft()
                t0, c0, port = history[0]
                if port == self.node.port and cpu - c0 > SPIN_SECONDS * 0.9:
                    self.wedged("a tracing thread spins")
                    history.clear()
                continue
            code = self.node.proc.returncode
            path = self.save / f"crash-{len(self.node.crashes)}.pickle"
            import pickle

            path.write_bytes(pickle.dumps(list(self.recent)))
            self.node.crashes.append(
                {"returncode": code, "inputs": str(path), "after_cases": self.sent}
            )
            print(
                f"node died (exit {code}) after {self.sent} cases; last inputs in {path}",
                file=sys.stderr,
            )
            self.node.stop()
            self.node.start()


def _frame(message: dict) -> bytes | None:
    """The message as a frame, or None when a mutation made it unframeable (too big, a
    value msgpack cannot hold): such a case is skipped, it never reaches the node."""
    try:
        return encode(message)
    except (TypeError, ValueError, OverflowError):
        return None


def _kind(message: dict):
    """The "k" of a message we made, when it is an int (mutations put anything there)."""
    k = message.get("k")
    return k if isinstance(k, int) else None


def _valid(kind: Kind, rng: random.Random) -> dict:
    """A well-formed message of `kind`: HELLO and OBJECTS as senders make them, others from
    FIELDS."""
    n = rng.randint(0, 3)
    if kind is Kind.HELLO:
        return hello(CLUSTER, "host", -1, nonce())
    if kind is Kind.OBJECTS:
        table = rng.choice(sorted(OBJECT_TABLES))
        return make(
            kind, node=0, table=table, records=np.zeros(n, OBJECT_TABLES[table]), last=False
        )
    plain = {
        int: n,
        str: "boom",
        bytes: b"\2" * 32,
        bool: False,
        dict: {"a": n},
        list: list(range(n)),
    }
    return make(
        kind,
        **{
            name: np.zeros(n, want) if isinstance(want, np.dtype) else plain[want]
            for name, want in FIELDS[kind].items()
        },
    )


CONNECTION_KINDS = {"garbage": 3, "oversized": 1, "truncated": 1, "hello": 3, "auth": 2, "frame": 4}
SESSION_KINDS = {"config": 6, "render": 1, "neighbour": 3}
SESSION_SHARE = 0.02  # of all cases, left to the session lane alone at the end (its cases
# build engines and render: a few a second, against thousands for the other lanes)


async def fuzz(args, node: Node, save: Path) -> Fuzzer:
    f = Fuzzer(node, random.Random(args.seed), args.cases, args.seconds, save)
    watcher = asyncio.create_task(f.watch())
    kinds = (
        set(args.kinds.split(","))
        if args.kinds
        else set(CONNECTION_KINDS) | set(SESSION_KINDS) | {"burst"}
    )
    if "burst" in kinds:
        await f.burst()
    mine = {k: w for k, w in CONNECTION_KINDS.items() if k in kinds}
    theirs = {k: w for k, w in SESSION_KINDS.items() if k in kinds}
    share = 1.0 - SESSION_SHARE if theirs else 1.0
    lanes = [f.lane(mine, share) for _ in range(max(1, args.lanes - 1)) if mine]
    lanes += [f.lane(theirs, session=True)] if theirs else []
    await asyncio.gather(*lanes)
    await asyncio.gather(*f.background)
    if time.monotonic() < f.deadline and "burst" in kinds:
        await f.burst()
    watcher.cancel()
    await asyncio.gather(watcher, return_exceptions=True)
    return f


async def final_render(port: int) -> str:
    """One real render through the host's client: '' when it worked, else why not."""
    from protocols.scene import SceneData, View

    scene = SceneData(view=View((0, 0, -10), (0, 0, 0), (0, 1, 0), 45.0))
    scene.materials = np.array([((1.0, 1.0, 1.0), 1.0, 0.0, 1.0, 0.0, 1.0)], dtypes.MATERIAL)
    scene.spheres = np.array([(0, 0, (0.0, 0.0, 0.0), 2.0)], dtypes.SPHERE)
    scene.lights = np.array([((0.0, 5.0, -5.0), (1.0, 1.0, 1.0))], dtypes.LIGHT)
    try:
        image, _ = await asyncio.wait_for(
            render_on_mesh(
                scene,
                ImageSpec(width=8, height=8),
                [f"127.0.0.1:{port}"],
                MeshPlan(1, 1),
                secret=SECRET,
            ),
            60,
        )
    except Exception as e:  # noqa: BLE001 - whatever failed is the figure to print
        return f"{type(e).__name__}: {e}"
    if image.shape[:2] != (8, 8) or not np.all(np.isfinite(image)) or not image.any():
        return f"bad image: shape {image.shape}, max {np.nanmax(image)}"
    return ""


def tracebacks(path: Path) -> tuple[int, collections.Counter]:
    """'Traceback' lines in the node's stderr, and the exception line ending each."""
    lines = path.read_text(errors="replace").splitlines()
    ends: collections.Counter = collections.Counter()
    count = 0
    for i, line in enumerate(lines):
        if "Traceback" in line:
            count += 1
            j = i + 1
            while j < len(lines) and (lines[j].startswith((" ", "\t")) or not lines[j].strip()):
                j += 1
            ends[lines[j][:160] if j < len(lines) else "?"] += 1
    return count, ends


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="bench.fuzz_node", description=__doc__.splitlines()[0])
    p.add_argument("--cases", type=int, default=100_000, help="cases to send (default 100000)")
    p.add_argument("--seconds", type=float, default=600.0, help="wall-time bound (default 600)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--lanes", type=int, default=6, help="concurrent connections (default 6)")
    p.add_argument("--kinds", help="only these case kinds (comma-separated; default all)")
    p.add_argument(
        "--memory-mb",
        type=int,
        default=8192,
        help="the node's address-space limit (RLIMIT_AS; 0: none; default 8192)",
    )
    args = p.parse_args(argv)

    save = Path(tempfile.mkdtemp(prefix="fuzz_node-"))
    node = Node(save / "node.stderr", args.memory_mb)
    node.start()
    start = time.monotonic()
    try:
        try:
            import uvloop

            run = uvloop.run
        except ImportError:
            run = asyncio.run
        f = run(fuzz(args, node, save))
        elapsed = time.monotonic() - start
        if not node.alive():
            node.crashes.append({"returncode": node.proc.returncode, "after_cases": f.sent})
            node.start()
        failure = run(final_render(node.port))
        node.sample()
        if failure and node.alive():  # where is it stuck? faulthandler prints every thread
            node.proc.send_signal(signal.SIGABRT)
            node.proc.wait(10)
    finally:
        node.stop()
    count, ends = tracebacks(node.stderr_path)
    crashes = len(node.crashes)

    print(
        f"cases sent: {f.sent} in {elapsed:.0f} s ({f.sent / max(elapsed, 1e-9):.0f}/s), "
        f"seed {args.seed}"
    )
    for kind, n in sorted(f.kinds.items(), key=lambda kv: -kv[1]):
        how = ", ".join(f"{o} {c}" for (k, o), c in sorted(f.outcomes.items()) if k == kind)
        print(f"  {kind:10s} {n:7d}  ({how})")
    for (k, o), c in sorted(f.outcomes.items()):
        if k not in f.kinds:
            print(f"  {k:10s}       -  ({o} {c})")
    print("node refusals (ERROR reasons, numbers and quoted values as #):")
    for reason, c in f.errors.most_common(25):
        print(f"  {c:7d}  {reason}")
    print(f"crashes (node deaths): {crashes}")
    for c in node.crashes:
        print(f"  {c}")
    print(
        f"wedges (node alive, tracing thread stuck; restarted): {len(node.wedges)}"
        + ("; after the first, RAYS and render records kept finite" if f.tame else "")
    )
    for w in node.wedges:
        print(f"  {w}")
    print(f"tracebacks in node stderr: {count}")
    for line, c in ends.most_common(10):
        print(f"  {c:7d}  {line}")
    print(
        f"connections left open by the node {EOF_SECONDS:g} s after our end of file: {f.left_open}"
    )
    for kind, waits in sorted(f.eof_close.items()):
        w = np.array(waits)
        print(
            f"  {kind}: the node hung up {np.median(w) * 1e3:.0f} ms (median), "
            f"{np.percentile(w, 99) * 1e3:.0f} ms (99th), {w.max() * 1e3:.0f} ms (max) "
            f"after our end of file; {np.mean(w > 0.1) * 100:.0f}% took over 100 ms"
        )
    print(f"hangs (cases past {CASE_TIMEOUT:g} s): {len(f.hangs)}")
    for h in f.hangs[:10]:
        print(f"  {h}")
    print(f"cases over 5 s: {len(f.slow)}  {sorted(f.slow, reverse=True)[:8]}")
    print(f"node RSS: peak {node.rss_peak / 2**20:.0f} MiB, final {node.rss_last / 2**20:.0f} MiB")
    print(f"final render: {'ok' if not failure else 'FAILED: ' + failure}")
    print(f"node stderr: {node.stderr_path}")
    return 1 if crashes or node.wedges or count or f.hangs or f.left_open or failure else 0


if __name__ == "__main__":
    sys.exit(main())
