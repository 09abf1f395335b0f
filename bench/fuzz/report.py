"""The fuzzing run's printed report and its verdict: what was sent and how the node took it,
then everything that counts as a failure (crashes, wedges, tracebacks in the node's stderr,
hangs, connections left open, a failed final render)."""

import collections
from pathlib import Path

import numpy as np

from bench.fuzz.conn import CASE_TIMEOUT
from bench.fuzz.fuzzer import EOF_SECONDS, Fuzzer
from bench.fuzz.node import Node


def report(f: Fuzzer, node: Node, seed: int, elapsed: float, failure: str) -> int:
    """Print the report; the exit status: 1 on any crash, wedge, traceback, hang or
    connection left open, or a failed final render."""
    count, ends = tracebacks(node.stderr_path)
    crashes = len(node.crashes)
    print_cases(f, seed, elapsed)
    print_failures(f, node, count, ends)
    print_connections(f)
    print(f"cases over 5 s: {len(f.slow)}  {sorted(f.slow, reverse=True)[:8]}")
    print(f"node RSS: peak {node.rss_peak / 2**20:.0f} MiB, final {node.rss_last / 2**20:.0f} MiB")
    print(f"final render: {'ok' if not failure else 'FAILED: ' + failure}")
    print(f"node stderr: {node.stderr_path}")
    return 1 if crashes or node.wedges or count or f.hangs or f.left_open or failure else 0


def print_cases(f: Fuzzer, seed: int, elapsed: float) -> None:
    """Cases sent, per kind with their outcomes, and the node's refusal reasons."""
    print(
        f"cases sent: {f.sent} in {elapsed:.0f} s ({f.sent / max(elapsed, 1e-9):.0f}/s), "
        f"seed {seed}"
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


def print_failures(f: Fuzzer, node: Node, count: int, ends: collections.Counter) -> None:
    """Crashes, wedges and the tracebacks in the node's stderr."""
    print(f"crashes (node deaths): {len(node.crashes)}")
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


def print_connections(f: Fuzzer) -> None:
    """Connections left open after our end of file, how soon the node hung up, and hangs."""
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
