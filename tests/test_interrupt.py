"""Ctrl-C during a render: one line on stderr, exit status 130, and no process left behind.

The render runs as a real subprocess in a session of its own, and SIGINT goes to its whole
process group, as a terminal's Ctrl-C does (local mesh nodes are in that group too)."""

import os
import re
import select
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from tests.conftest import ctrl_c_default

EXAMPLE = Path(__file__).resolve().parents[1] / "host" / "examples" / "showcase.nff"
DEADLINE = 300.0  # seconds for the nodes to build and the first progress to show


def children(pid: int) -> list[int]:
    """Processes whose parent is `pid` (a /proc scan)."""
    found = []
    for entry in os.listdir("/proc"):
        if entry.isdigit():
            try:
                stat = Path(f"/proc/{entry}/stat").read_text()
            except OSError:
                continue
            if int(stat.rsplit(")", 1)[1].split()[1]) == pid:
                found.append(int(entry))
    return found


def read_until(fd: int, pattern: str, deadline: float) -> str:
    """What the process writes on `fd` until `pattern` shows (select, bounded; no sleep)."""
    text = ""
    while not re.search(pattern, text):
        left = deadline - time.monotonic()
        ready, _, _ = select.select([fd], [], [], max(left, 0))
        assert ready, f"no {pattern!r} within the deadline: {text!r}"
        chunk = os.read(fd, 65536).decode(errors="replace")
        assert chunk, f"the render ended before {pattern!r}: {text!r}"
        text += chunk
    return text


@pytest.mark.parametrize("mesh,progress", [("2x2", r"mesh 2x2 primary:"), ("1x1", r"tracing:")])
def test_ctrl_c_prints_one_line_exits_130_and_leaves_no_process(tmp_path, mesh, progress):
    proc = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "host.cli",
            "render",
            str(EXAMPLE),
            "--mesh",
            mesh,
            "--spp",
            "64",
            "-o",
            str(tmp_path / "a.png"),
        ],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        start_new_session=True,
        preexec_fn=ctrl_c_default,
    )
    try:
        before = read_until(proc.stderr.fileno(), progress, time.monotonic() + DEADLINE)
        nodes = children(proc.pid)
        assert len(nodes) == (4 if mesh == "2x2" else 0)
        os.killpg(proc.pid, signal.SIGINT)
        code = proc.wait(timeout=60)
        after = proc.stderr.read().decode(errors="replace")
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert code == 130
    assert "Traceback" not in before + after
    lines = [x.strip() for x in re.split(r"[\r\n]", after) if x.strip()]
    said = [x for x in lines if not x.startswith(("mesh ", "tracing"))]  # progress bars
    assert said == ["host: interrupted"], after
    assert not [pid for pid in nodes if Path(f"/proc/{pid}").exists()]
    assert not list(tmp_path.iterdir())
