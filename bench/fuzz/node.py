"""The node under test: a `meshnode serve` process of its own cluster, capped in memory and
restarted when it dies, and the real render that shows it still serves at the end."""

import asyncio
import os
import re
import resource
import select
import subprocess
import sys
from pathlib import Path

import numpy as np

from host.planning.request import Request
from host.run.connections import Nodes
from host.run.meshclient import render_on_mesh
from protocols import dtypes
from protocols.render import ImageSpec, MeshPlan

SECRET = b"fuzz-node secret, as long as a cluster needs"
CLUSTER = "meshtrace"


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
        """Start the node and read its port from its `listening HOST:PORT` line."""
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
        """Whether the process still runs (a dead one is a crash)."""
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
        """Note the node's RSS (VmRSS) and its peak: an unbounded allocation shows here."""
        try:
            text = Path(f"/proc/{self.proc.pid}/status").read_text()
        except OSError:
            return
        m = re.search(r"VmRSS:\s+(\d+) kB", text)
        if m:
            self.rss_last = int(m.group(1)) * 1024
            self.rss_peak = max(self.rss_peak, self.rss_last)

    def stop(self) -> None:
        """End the node, killing it if it does not stop within 10 s."""
        if self.alive():
            self.proc.terminate()
            try:
                self.proc.wait(10)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()
        if self.proc is not None and self.proc.stdout:
            self.proc.stdout.close()


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
                Request(scene, ImageSpec(width=8, height=8), plan=MeshPlan(1, 1)),
                Nodes([f"127.0.0.1:{port}"], secret=SECRET),
            ),
            60,
        )
    except Exception as e:  # noqa: BLE001 - whatever failed is the figure to print
        return f"{type(e).__name__}: {e}"
    if image.shape[:2] != (8, 8) or not np.all(np.isfinite(image)) or not image.any():
        return f"bad image: shape {image.shape}, max {np.nanmax(image)}"
    return ""
