"""The fuzzing run: lanes of cases sent at once, each bounded by a timeout, while a watcher
samples the node and restarts it after a crash or a wedge, keeping the inputs that led there."""

import asyncio
import collections
import pickle
import random
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

from bench.fuzz.conn import Conn, Hang
from bench.fuzz.connection_cases import CONNECTION_CASES, CONNECTION_KINDS, case_burst
from bench.fuzz.node import Node
from bench.fuzz.session_cases import SESSION_CASES, SESSION_KINDS, session_messages
from meshnode.service.warmup import ALL_KINDS, variant_scene
from protocols.errors import ProtocolError
from protocols.messages import Kind
from protocols.render import ImageSpec, MeshPlan

EOF_SECONDS = 2.0  # s: after our end of file, the node closes its side within this
EOF_WAITERS = 48  # connections waiting for the node's close at once
SPIN_SECONDS = 40.0  # s of CPU in one tracing thread within ~60 s: stuck, not rendering 8x8
SESSION_SHARE = 0.02  # of all cases, left to the session lane alone at the end (its cases
# build engines and render: a few a second, against thousands for the other lanes)
CASES = {**CONNECTION_CASES, **SESSION_CASES}


class Fuzzer:
    """One fuzzing run: the node under test, the seeded random source, the counts of cases
    and outcomes, and what went wrong; the cases get it as `f`."""

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
        self.scene = variant_scene(ALL_KINDS)
        self.one = session_messages(self.scene, MeshPlan(1, 1), 0, ImageSpec(width=8, height=8))
        self.two = session_messages(self.scene, MeshPlan(1, 2), 1, ImageSpec(width=8, height=8))
        self.slow: list = []  # (seconds, kind, when) of cases that took over 5 s
        self.tame = False  # set after the first wedge: fuzz past the known ones
        self.left_open = 0  # connections the node kept open after our end of file
        self.in_session = False  # the session lane is in a case (the node refuses hosts)
        self.eof_waiters = asyncio.Semaphore(EOF_WAITERS)
        self.background: set[asyncio.Task] = set()
        self.eof_close: dict = collections.defaultdict(list)  # kind -> s until the node hung up

    def more(self) -> bool:
        """Whether to go on: cases and wall time are both bounded."""
        return self.sent < self.limit and time.monotonic() < self.deadline

    def count(self, kind: str, outcome: str, data=None, n: int = 1) -> None:
        """Count `n` cases of `kind` with their outcome, keeping the input for a crash."""
        self.sent += n
        self.kinds[kind] += n
        self.outcomes[kind, outcome] += n
        if data is not None:
            self.recent.append((kind, data))

    def refusal(self, message: dict | None) -> None:
        """Note an ERROR's reason, numbers and quoted values as #, so alike ones group."""
        if message is not None and message.get("k") == Kind.ERROR:
            reason = str(message.get("reason", ""))
            self.errors[re.sub(r"\d+|'[^']*'|\"[^\"]*\"", "#", reason)[:90]] += 1

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
                await CASES[kind](self)
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

    def wedged(self, kind: str) -> None:
        """The node lives but its one tracing thread is stuck: keep the last inputs, make it
        print every thread's stack (faulthandler, on SIGABRT) and start another."""
        path = self.keep_inputs(f"wedge-{len(self.node.wedges)}")
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
            path = self.keep_inputs(f"crash-{len(self.node.crashes)}")
            self.node.crashes.append(
                {"returncode": code, "inputs": str(path), "after_cases": self.sent}
            )
            print(
                f"node died (exit {code}) after {self.sent} cases; last inputs in {path}",
                file=sys.stderr,
            )
            self.node.stop()
            self.node.start()

    def keep_inputs(self, name: str) -> Path:
        """The last inputs sent, pickled as NAME.pickle in the run's folder: what a crash or
        a wedge can be replayed from."""
        path = self.save / f"{name}.pickle"
        path.write_bytes(pickle.dumps(list(self.recent)))
        return path


async def fuzz(args, node: Node, save: Path) -> Fuzzer:
    """Every lane of `args.kinds` against the node, with a burst first and last and the node
    watched throughout; returns the run with its counts."""
    f = Fuzzer(node, random.Random(args.seed), args.cases, args.seconds, save)
    watcher = asyncio.create_task(f.watch())
    kinds = (
        set(args.kinds.split(","))
        if args.kinds
        else set(CONNECTION_KINDS) | set(SESSION_KINDS) | {"burst"}
    )
    if "burst" in kinds:
        await case_burst(f)
    mine = {k: w for k, w in CONNECTION_KINDS.items() if k in kinds}
    theirs = {k: w for k, w in SESSION_KINDS.items() if k in kinds}
    share = 1.0 - SESSION_SHARE if theirs else 1.0
    lanes = [f.lane(mine, share) for _ in range(max(1, args.lanes - 1)) if mine]
    lanes += [f.lane(theirs, session=True)] if theirs else []
    await asyncio.gather(*lanes)
    await asyncio.gather(*f.background)
    if time.monotonic() < f.deadline and "burst" in kinds:
        await case_burst(f)
    watcher.cancel()
    await asyncio.gather(watcher, return_exceptions=True)
    return f
