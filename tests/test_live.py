"""The live view without a browser: the monitor's books, the WebSocket stream a page gets, what
the server refuses, where it binds, and `host render --serve` stopped by Ctrl-C."""

import asyncio
import io
import ipaddress
import json
import os
import queue
import signal
import socket
import struct
import subprocess
import sys
import threading
from pathlib import Path

import aiohttp
import numpy as np
import pytest
from PIL import Image

from host.live.figures import RAY_KINDS
from host.live.frames import preview_srgb8
from host.live.monitor import Monitor
from host.live.server import LiveServer, parse_address
from host.planning.request import Request
from host.run.connections import Nodes
from host.run.framebuffer import Framebuffer, to_srgb8
from protocols.dtypes import LINK_TRAFFIC
from protocols.messages import SETUP_STEPS
from tests.conftest import ctrl_c_default

ROOT = Path(__file__).resolve().parents[1]
EXAMPLE = ROOT / "host" / "examples" / "showcase.nff"
WAIT = 30.0  # seconds any one wait may take before the test fails


def progress(
    node: int, rays: int, state: int = 1, links=(), setup: str = "ready", traced=None
) -> dict:
    """A PROGRESS message's fields as protocols.messages.parse hands them over."""
    return {
        "node": node,
        "rays": rays,
        "work": 1,
        "ready": setup == "ready",
        "state": state,
        "busy_ms": 750,
        "elapsed_ms": 1000,
        "traced": 10 * rays if traced is None else traced,
        "objects": 7,
        "links": np.array(list(links), LINK_TRAFFIC),
        "setup": SETUP_STEPS.index(setup),
    }


class Clock:
    """Seconds that pass only when a test says so."""

    def __init__(self):
        self.now = 100.0

    def __call__(self) -> float:
        return self.now


def frame_of(fb: Framebuffer) -> np.ndarray:
    return to_srgb8(fb.image())


@pytest.mark.parametrize(
    "text,want",
    [
        ("8000", ("127.0.0.1", 8000)),
        ("0", ("127.0.0.1", 0)),
        ("0.0.0.0:80", ("0.0.0.0", 80)),
        ("[::1]:9", ("::1", 9)),
    ],
)
def test_serve_addresses_default_to_loopback(text, want):
    assert parse_address(text) == want


@pytest.mark.parametrize("text", ["", "x", ":80", "host:", "1:99999", "-1"])
def test_bad_serve_addresses_are_named(text):
    with pytest.raises(ValueError, match="HOST:]PORT"):
        parse_address(text)


def test_server_binds_loopback_by_default():
    with LiveServer(Monitor()) as live:
        assert live.host == "127.0.0.1" and live.port > 0
        assert live.url == f"http://127.0.0.1:{live.port}/"
        assert live.bound and all(ipaddress.ip_address(a).is_loopback for a, _ in live.bound)
        with socket.create_connection(("127.0.0.1", live.port), timeout=WAIT):
            pass
    assert not live.thread.is_alive()


def test_a_taken_port_is_a_clear_error():
    with LiveServer(Monitor()) as first:
        second = LiveServer(Monitor(), port=first.port)
        with pytest.raises(OSError, match=f"cannot serve the live view on 127.0.0.1:{first.port}"):
            second.start()
        second.stop()
        assert not second.thread.is_alive()


def test_frames_are_copied_at_most_once_an_interval():
    monitor = Monitor(interval=3600.0)
    fb = Framebuffer(4, 3, corners=False)
    monitor.start(fb, 1, 1, [5], total=12)
    fb.add(np.array([0, 1]), np.ones((2, 3)))
    monitor.pixels()
    fb.add(np.array([2]), np.ones((1, 3)))
    monitor.pixels()  # within the interval: not copied
    version, png = monitor.frame(png=True)
    assert version == 1
    got = np.asarray(Image.open(io.BytesIO(png)))
    assert got[0, 2].tolist() == [0, 0, 0] and got[0, 1].tolist() == [255, 255, 255]


async def receive_until(ws, done, timeout: float = WAIT):
    """Messages from the stream (status dicts, (version, RGB) frames) until `done(status,
    frames)` holds; the newest status and every frame."""
    status, frames = None, {}
    async with asyncio.timeout(timeout):
        while True:
            msg = await ws.receive()
            if msg.type == aiohttp.WSMsgType.TEXT:
                status = json.loads(msg.data)
            elif msg.type == aiohttp.WSMsgType.BINARY:
                (version,) = struct.unpack("<I", msg.data[:4])
                frames[version] = np.asarray(Image.open(io.BytesIO(msg.data[4:])))
            else:
                raise AssertionError(f"stream ended: {msg.type}")
            if status is not None and done(status, frames):
                return status, frames


async def test_the_stream_pushes_progress_nodes_frames_and_the_end():
    monitor = Monitor(interval=0.0)
    fb = Framebuffer(6, 4, corners=False)
    with LiveServer(monitor, interval=0.0) as live:
        async with aiohttp.ClientSession() as http:
            async with http.ws_connect(f"ws://127.0.0.1:{live.port}/ws") as ws:
                status, _ = await receive_until(ws, lambda s, f: True)
                assert status["phase"] == "preparing" and status["nodes"] == []

                monitor.start(fb, 1, 2, [3, 4], total=24)
                fb.add(np.arange(12), np.full((12, 3), 0.5))
                monitor.pixels()
                monitor.node(1, progress(1, 12, links=[(0, 40, 4000)]))
                half = frame_of(fb)
                status, frames = await receive_until(
                    ws, lambda s, f: s["progress"]["done"] == 12 and s["frame"] in f
                )
                preview = frames[status["frame"]].astype(int)  # a JPEG: near, not equal
                assert np.abs(preview - half).mean() < 4
                assert status["progress"]["total"] == 24
                assert status["progress"]["fraction"] == 0.5
                assert status["frame_done"] == 0  # copied before the node's progress came
                n1 = status["nodes"][1]
                assert (n1["row"], n1["col"], n1["state"]) == (0, 1, "trace")
                assert n1["busy"] == 0.75 and n1["traced"] == 120 and n1["objects"] == 7
                assert n1["links"] == [{"peer": 0, "rays": 40, "bytes": 4000}]
                monitor.tiles(1, 2)
                monitor.tiles(7, 1)  # no such node: ignored
                status, _ = await receive_until(ws, lambda s, f: s["nodes"][1]["tiles"] == 2)
                assert status["nodes"][0]["tiles"] == 0

                fb.add(np.arange(12, 24), np.full((12, 3), 2.0))
                stats = {
                    "nodes": [node_stats(0, 5, 0.25), node_stats(1, 9, 0.5)],
                    "rays": {"eye_rays": 12, "shadow_rays": 14, "eye_hits": 99},
                    "total_rays": 26,
                    "wall_seconds": 3.0,
                    "setup_seconds": 1.0,
                    "trace_seconds": 2.0,
                    "rays_per_second": 13.0,
                    "odd": float("inf"),
                }
                monitor.finish(fb.image(), stats)
                status, frames = await receive_until(
                    ws, lambda s, f: s["final"] and s["frame"] in f
                )
                np.testing.assert_array_equal(frames[status["frame"]], frame_of(fb))
                assert status["phase"] == "done" and status["progress"]["fraction"] == 1.0
                done = status["progress"]  # the command line's figures: wall, rays after setup
                assert (done["elapsed_seconds"], done["traced"]) == (3.0, 26)
                assert done["rays_per_second"] == 26 / (3.0 - 1.0)
                assert status["stats"]["odd"] is None  # strict JSON: no Infinity
                assert [n["traced"] for n in status["nodes"]] == [5 + 6, 9 + 6]
                assert [n["busy"] for n in status["nodes"]] == [0.25, 0.5]
                assert [n["rays_per_second"] for n in status["nodes"]] == [11.0, 15.0]
                assert status["nodes"][0]["links"] == [{"peer": 1, "rays": 2, "bytes": 99}]

            async with http.get(f"http://127.0.0.1:{live.port}/stats.json") as r:
                assert r.status == 200 and (await r.json())["nodes"][1]["objects"] == 4
            async with http.get(f"http://127.0.0.1:{live.port}/") as r:
                assert r.status == 200 and "<canvas" in await r.text()


def node_stats(n: int, shadow: int, busy: float) -> dict:
    """A node's STATS body as far as the live view reads it."""
    return {
        "objects": 3 + n,
        "rays": {"eye_rays": 6, "shadow_rays": shadow, "eye_hits": 99},
        "busy_seconds": busy,
        "idle_seconds": 1.0 - busy,
        "links": {str(1 - n): {"rays_sent": 2, "bytes_out": 99}},
    }


def test_building_nodes_say_their_step_and_progress_counts_from_the_first_ray():
    clock = Clock()
    monitor = Monitor(clock=clock)
    monitor.start(Framebuffer(4, 4, corners=False), 1, 2, [1, 1], total=100)
    status = monitor.status()
    assert status["phase"] == "building" and status["progress"]["started"]
    assert [n["setup"] for n in status["nodes"]] == ["objects", "objects"]
    monitor.node(0, progress(0, 0, state=0, setup="compile"))
    clock.now += 12.0
    monitor.node(1, progress(1, 0, state=0, setup="load"))
    status = monitor.status()
    assert status["phase"] == "building"
    assert [(n["setup"], n["setup_seconds"]) for n in status["nodes"]] == [
        ("compile", 12.0),
        ("load", 0.0),
    ]
    assert status["progress"]["done"] == 0 and status["progress"]["eta_seconds"] is None
    monitor.node(0, progress(0, 10))  # node 0 built and tracing, node 1 still loading
    status = monitor.status()
    assert status["phase"] == "tracing" and status["progress"]["done"] == 10
    assert status["progress"]["elapsed_seconds"] == 12.0  # since the render began


def test_the_eta_follows_the_recent_rate():
    """Half the rays in the first moment (the showcase's sky), then 10 a second: the ETA is
    the recent rate's (400 left at 10/s), not the mean's since the start (60/s)."""
    clock = Clock()
    monitor = Monitor(clock=clock)
    monitor.start(Framebuffer(4, 4, corners=False), 1, 1, [1], total=1000)
    monitor.node(0, progress(0, 500, traced=500))
    for second in range(1, 11):
        clock.now += 1.0
        monitor.node(0, progress(0, 10, traced=500 + 30 * second))
    p = monitor.status()["progress"]
    assert p["done"] == 600 and p["rate"] == pytest.approx(10.0)
    assert p["eta_seconds"] == pytest.approx(40.0)
    assert p["rays_per_second"] == pytest.approx(30.0)
    assert monitor.status()["nodes"][0]["rays_per_second"] == pytest.approx(30.0)
    clock.now += 2.5  # a stall: the rate falls as it lasts (30 rays since 7 s, 5.5 s ago) ...
    assert monitor.status()["progress"]["rate"] == pytest.approx(30 / 5.5)
    clock.now += 2.5  # ... to nothing, and there is no ETA
    p = monitor.status()["progress"]
    assert p["rate"] == 0.0 and p["eta_seconds"] is None


def test_the_final_figures_are_the_statistics():
    """Rays of every kind, rays/s and wall seconds as the summary prints them."""
    monitor = Monitor()
    fb = Framebuffer(2, 2, corners=False)
    monitor.start(fb, 1, 1, [3], total=4, unit="batches")
    rays = {"eye_rays": 4, "reflected_rays": 2, "refracted_rays": 1, "shadow_rays": 5}
    stats = {
        "rays": rays | {"eye_hits": 3},
        "total_rays": 12,
        "trace_seconds": 0.5,
        "wall_seconds": 0.75,
        "rays_per_second": 24.0,
        "engine": {"objects": 3},
    }
    monitor.finish(fb.image(), stats)
    p = monitor.status()["progress"]
    assert (p["traced"], p["rays_per_second"], p["elapsed_seconds"]) == (12, 24.0, 0.75)
    assert monitor.status()["nodes"][0]["rays_per_second"] == 24.0


def test_previews_are_within_a_level_of_the_exact_image():
    fb = Framebuffer(64, 48, corners=False, spp=4)
    fb.sums[:] = np.random.default_rng(1).random(fb.sums.shape) * 5.0  # some above white
    exact = frame_of(fb).astype(int)
    assert np.abs(preview_srgb8(fb).astype(int) - exact).max() <= 1


def test_progress_outside_the_mesh_is_not_trusted():
    monitor = Monitor()
    monitor.start(Framebuffer(2, 2, corners=False), 1, 2, [1, 1], total=4)
    monitor.node(5, progress(5, 3))  # no such node: ignored
    monitor.node(0, progress(0, 1, state=99, links=[(1, 2, 3), (9, 9, 9)]))
    status = monitor.status()
    assert status["progress"]["done"] == 1
    assert status["nodes"][0]["state"] == "unknown"
    assert [link["peer"] for link in status["nodes"][0]["links"]] == [1]


@pytest.mark.parametrize(
    "headers", [{"Origin": "http://evil.example"}, {"Host": "rebound.example"}]
)
async def test_other_sites_are_refused(headers):
    with LiveServer(Monitor()) as live:
        async with aiohttp.ClientSession() as http:
            for path in ("/", "/ws", "/status.json"):
                async with http.get(f"http://127.0.0.1:{live.port}{path}", headers=headers) as r:
                    assert r.status == 403
                    assert (await r.text()).startswith("refused: ")


def test_serve_stays_until_ctrl_c(tmp_path):
    """`host render --serve` keeps the page after the render; Ctrl-C ends it, exit 0, with
    the final image and the statistics it wrote served."""
    out, stats = tmp_path / "a.png", tmp_path / "s.json"
    proc = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "host.cli",
            "render",
            str(EXAMPLE),
            "-o",
            str(out),
            "--stats",
            str(stats),
            "--width",
            "24",
            "--height",
            "16",
            "--mesh",
            "1x1",
            "--quiet",
            "--serve",
            "0",
        ],
        stderr=subprocess.PIPE,
        text=True,
        cwd=tmp_path,
        env=os.environ | {"PYTHONPATH": str(ROOT)},
        preexec_fn=ctrl_c_default,
    )
    try:
        lines = stderr_lines(proc)
        url = wait_for_line(lines, "live view at ").split("live view at ")[1].strip()
        assert url.startswith("http://127.0.0.1:")
        wait_for_line(lines, "stays at")
        status = asyncio.run(final_status(url))
        assert status["stats"] == json.loads(stats.read_text())
        proc.send_signal(signal.SIGINT)
        assert proc.wait(WAIT) == 0
        assert "live view stopped" in "".join(drain(lines))
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()


async def final_status(url: str) -> dict:
    async with aiohttp.ClientSession() as http:
        async with http.ws_connect(url.replace("http:", "ws:") + "ws") as ws:
            status, _ = await receive_until(ws, lambda s, f: s["final"])
        async with http.get(url + "frame.png") as r:
            assert r.status == 200
    return status


def stderr_lines(proc) -> queue.Queue:
    """The process's stderr lines, read on a thread (a wait on them can then time out)."""
    lines: queue.Queue = queue.Queue()

    def pump():
        for line in proc.stderr:
            lines.put(line)
        lines.put(None)

    threading.Thread(target=pump, daemon=True).start()
    return lines


def wait_for_line(lines: queue.Queue, text: str) -> str:
    seen = []
    while True:
        line = lines.get(timeout=WAIT * 4)  # the first render may load kernels from disk
        if line is None:
            raise AssertionError(f"no line with {text!r}; stderr was:\n{''.join(seen)}")
        seen.append(line)
        if text in line:
            return line


def drain(lines: queue.Queue):
    while (line := lines.get(timeout=WAIT)) is not None:
        yield line


class Recording(Monitor):
    """A monitor that keeps every node's PROGRESS fields."""

    def __init__(self):
        super().__init__()
        self.seen: dict[int, list[dict]] = {}

    def node(self, n: int, f: dict) -> None:
        self.seen.setdefault(n, []).append(f)
        super().node(n, f)


def test_nodes_report_state_busy_objects_and_link_traffic():
    """Real nodes' PROGRESS, as the page gets it: counters only grow, and end no higher than
    the STATS the node sends last."""
    from host.run.localmesh import LocalMesh
    from host.run.meshclient import render_on_mesh
    from host.scene.nff import read_nff
    from protocols.render import ImageSpec, MeshPlan

    watch = Recording()
    with LocalMesh(2) as addresses:
        img, stats = asyncio.run(
            render_on_mesh(
                Request(read_nff(EXAMPLE), ImageSpec(width=24, height=16), plan=MeshPlan(1, 2)),
                Nodes(addresses),
                watch=watch,
            )
        )
    watch.finish(img, stats)
    for n, s in enumerate(stats["nodes"]):
        seen = watch.seen[n]
        assert {f["node"] for f in seen} == {n}
        assert seen[-1]["objects"] == s["objects"] > 0
        for key in ("traced", "busy_ms", "elapsed_ms", "work", "setup"):
            values = [f[key] for f in seen]
            assert values == sorted(values), key
        assert all(0 <= f["busy_ms"] <= f["elapsed_ms"] + 1 for f in seen)
        assert SETUP_STEPS[seen[-1]["setup"]] == "ready" and seen[-1]["ready"]
        assert seen[-1]["traced"] <= sum(s["rays"].get(k, 0) for k in RAY_KINDS)
        sent = [f["links"] for f in seen if len(f["links"])][-1]
        assert sent["peer"].tolist() == [1 - n]
        assert 0 <= sent["rays"][0] <= s["links"][str(1 - n)]["rays_sent"]
    assert watch.status()["progress"]["done"] == 24 * 16


def test_serve_exit_returns_when_the_render_is_done(tmp_path, capsys):
    from host.cli import main

    code = main(
        [
            "render",
            str(EXAMPLE),
            "-o",
            str(tmp_path / "a.png"),
            "--width",
            "8",
            "--height",
            "8",
            "--mesh",
            "1x1",
            "--quiet",
            "--serve",
            "0",
            "--serve-exit",
        ]
    )
    assert code == 0 and (tmp_path / "a.png").exists()
    assert "live view at http://127.0.0.1:" in capsys.readouterr().err
    assert not [t for t in threading.enumerate() if t.name == "live-view"]


@pytest.mark.parametrize(
    "options,message",
    [
        (["--serve-exit"], "--serve-exit needs --serve"),
        (["--serve", "nowhere:port"], "expected [HOST:]PORT"),
    ],
)
def test_serve_options_are_checked_before_any_work(tmp_path, capsys, options, message):
    from host.cli import main

    out = tmp_path / "a.png"
    assert main(["render", str(EXAMPLE), "-o", str(out), "--quiet", *options]) == 2
    assert message in capsys.readouterr().err and not out.exists()
