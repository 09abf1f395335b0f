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
import signal
import sys
import tempfile
import time
from pathlib import Path

if __package__ in (None, ""):
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench.fuzz.fuzzer import Fuzzer, fuzz  # noqa: E402 (after the path is set)
from bench.fuzz.node import Node, final_render  # noqa: E402
from bench.fuzz.report import report  # noqa: E402


def parse_args(argv=None) -> argparse.Namespace:
    """Command line options."""
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
    return p.parse_args(argv)


def main(argv=None) -> int:
    """Fuzz a fresh node, check it still renders, and print the report (exit 1 on a failure)."""
    args = parse_args(argv)
    save = Path(tempfile.mkdtemp(prefix="fuzz_node-"))
    node = Node(save / "node.stderr", args.memory_mb)
    node.start()
    try:
        f, elapsed, failure = run(args, node, save)
    finally:
        node.stop()
    return report(f, node, args.seed, elapsed, failure)


def run(args: argparse.Namespace, node: Node, save: Path) -> tuple[Fuzzer, float, str]:
    """(the run, its seconds, why the final render failed or '') of fuzzing the node, then
    one real render on it (restarted first if it died at the very end)."""
    start = time.monotonic()
    try:
        import uvloop

        loop_run = uvloop.run
    except ImportError:
        loop_run = asyncio.run
    f = loop_run(fuzz(args, node, save))
    elapsed = time.monotonic() - start
    if not node.alive():
        node.crashes.append({"returncode": node.proc.returncode, "after_cases": f.sent})
        node.start()
    failure = loop_run(final_render(node.port))
    node.sample()
    if failure and node.alive():  # where is it stuck? faulthandler prints every thread
        node.proc.send_signal(signal.SIGABRT)
        node.proc.wait(10)
    return f, elapsed, failure


if __name__ == "__main__":
    sys.exit(main())
