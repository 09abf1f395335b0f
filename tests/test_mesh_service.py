"""The mesh over TCP: meshnode processes on loopback render the single-node image with the
single-node counts; a dead node or a bad peer fails clearly; the CLI and cluster files."""

import asyncio
import os
import socket
from functools import partial
from pathlib import Path

import numpy as np
import pytest

from host.cli import main
from host.planning.request import Request
from host.run.cluster import parse_mesh, read_cluster
from host.run.connections import Nodes
from host.run.errors import MeshError
from host.run.framebuffer import read_pfm
from host.run.localmesh import LocalMesh
from host.run.meshclient import render_on_mesh
from host.run.oneprocess import render
from host.run.summary import COMMON, summary_line
from host.scene.nff import read_nff
from meshnode.engine.counters import RAY_COUNTS, WALK_COUNTS
from protocols.render import MeshPlan
from tests.conftest import records, spd_scene

COUNTS = RAY_COUNTS


def on_mesh(scene, rs, addresses, plan: MeshPlan, **kw):
    """render_on_mesh of a test's records (`rs`) on running nodes."""
    return render_on_mesh(Request(scene, *rs, plan), Nodes(addresses), **kw)


def mesh_render(scene, plan: MeshPlan, rs):
    with LocalMesh(plan.nodes) as addresses:
        return asyncio.run(asyncio.wait_for(on_mesh(scene, rs, addresses, plan), 180))


def slow_mesh(
    n: int, src: int, dst: int, seconds: float, count: int, progress: float | None = None
) -> LocalMesh:
    """Nodes whose link src -> dst holds back its first `count` ray messages (tests.faultnode),
    telling the host their progress at most every `progress` seconds (None: as in production)."""
    root = str(Path(__file__).resolve().parents[1])
    every = [] if progress is None else ["--progress-every", str(progress)]
    return LocalMesh(
        n,
        module="tests.faultnode",
        options=["--slow-link", f"{src},{dst},{seconds},{count}", *every],
        env={"PYTHONPATH": root + os.pathsep + os.environ.get("PYTHONPATH", "")},
    )


@pytest.mark.parametrize(
    "name,rows,cols,overlap",
    [
        ("balls_s1.nff", 1, 2, 1),
        ("gears_s1.nff", 2, 2, 24),
        ("rings_s1.nff", 2, 3, 100),
        ("mount_s1.nff", 3, 3, 1),
    ],
)
def test_mesh_over_tcp_equals_single_node(name, rows, cols, overlap):
    # One request, rendered both ways: one process reads its scene and records, the mesh
    # its plan too.
    request = Request(read_nff(spd_scene(name)), *records(width=40, height=40, threads=1))
    request = request.on(MeshPlan(rows, cols, overlap))
    ref, ref_stats = render(request)
    with LocalMesh(request.plan.nodes) as addresses:
        coro = render_on_mesh(request, Nodes(addresses))
        img, stats = asyncio.run(asyncio.wait_for(coro, 180))
    assert {k: stats["rays"][k] for k in COUNTS} == {k: ref_stats["rays"][k] for k in COUNTS}
    np.testing.assert_allclose(img, ref, rtol=0, atol=1e-5)
    # Conservation over the wire: rays sent on links are received, every ray ends once.
    nodes = stats["nodes"]
    assert sum(n["rays_sent"] for n in nodes) == sum(n["rays_received"] for n in nodes)
    r = stats["rays"]
    created = r["eye_rays"] + r["reflected_rays"] + r["refracted_rays"] + r["shadow_rays"]
    assert created == r["hits"] + r["escaped"] + r["shadow_rays_blocked"] + r["shadow_rays_lit"]
    # termination waves: DOWNLOAD, TRACE (again while rays were passed), DONE
    assert all(n["waves"] >= 3 for n in nodes)
    assert all(50e6 < n["peak_rss_bytes"] < 4e9 for n in nodes)  # reported, and plausible
    assert len(nodes) == rows * cols
    # One statistics record: the figures every render carries mean the same both ways (the
    # SPD table's counts too, total internal reflections among them), and one summary prints
    # either.
    assert stats["rays"]["internal_reflections"] == ref_stats["rays"]["internal_reflections"]
    for key in ("scene", "image", "engine_spec", "total_rays", "spd_counts"):
        assert stats[key] == ref_stats[key], key
    for s in (stats, ref_stats):
        assert set(COMMON) <= set(s) and not set(WALK_COUNTS) & set(s["rays"])
        assert s["wall_seconds"] == pytest.approx(s["setup_seconds"] + s["trace_seconds"])
        assert s["rays_per_second"] == pytest.approx(s["total_rays"] / s["trace_seconds"])
        line = summary_line("out.png", s)
        assert f"40x40  eye {s['rays']['eye_rays']} (hit {s['rays']['eye_hits']})" in line
        assert f"wall {s['wall_seconds']:.3f} s  {s['rays_per_second']:.0f} rays/s" in line


def test_dead_node_stops_the_render_naming_it_when_told_to_fail():
    scene = read_nff(spd_scene("balls_s3.nff"))
    rs = records(width=800, height=800, spp=4)  # ~10 s of tracing

    async def run(mesh, addresses, tracing: bool):
        started = asyncio.Event()
        # The nodes are listening already (LocalMesh waited for them): the host need not
        # retry a dead one for the default 5 s before naming it.
        nodes = Nodes(addresses, wait=2.0)
        request = Request(scene, *rs, MeshPlan(2, 2, 1))
        task = asyncio.create_task(
            render_on_mesh(request, nodes, progress=lambda n: started.set(), on_node_loss="fail")
        )
        if tracing:  # the first primary rays traced somewhere
            await asyncio.wait_for(started.wait(), 60)
        mesh.procs[1].kill()
        return await asyncio.wait_for(task, 30)

    for tracing in (False, True):  # before the host connects, and in the middle of tracing
        mesh = LocalMesh(4)
        with mesh as addresses:
            with pytest.raises(MeshError, match="node 1"):
                asyncio.run(run(mesh, addresses, tracing))


def test_delayed_link_over_tcp_gives_the_whole_image():
    # Ray messages from node 0 to node 1 held back 0.4 s each, far longer than a termination
    # wave on a 2x2 (milliseconds): the render must wait for them, not end early.
    scene = read_nff(spd_scene("balls_s2.nff"))
    rs = records(width=40, height=40, threads=1)
    ref, ref_stats = render(Request(scene, *rs))
    mesh = slow_mesh(4, 0, 1, 0.4, 3)
    with mesh as addresses:
        coro = on_mesh(scene, rs, addresses, MeshPlan(2, 2, 1))
        img, stats = asyncio.run(asyncio.wait_for(coro, 120))
    assert {k: stats["rays"][k] for k in COUNTS} == {k: ref_stats["rays"][k] for k in COUNTS}
    np.testing.assert_allclose(img, ref, rtol=0, atol=1e-5)
    assert stats["nodes"][0]["links"]["1"]["rays_sent"] > 0  # the slow link carried rays
    assert stats["wall_seconds"] > 0.4
    assert all(p.poll() is not None for p in mesh.procs)  # no process outlives the mesh


def test_a_mesh_that_lives_but_never_finishes_fails_instead_of_hanging():
    # A ray message held on one link for 1000 s: every node is alive (heartbeats flow) and
    # soon idle, but no termination wave can end the frame. The host gives up after `stall`.
    scene = read_nff(spd_scene("balls_s2.nff"))
    rs = records(width=40, height=40, threads=1)
    with slow_mesh(4, 0, 1, 1000.0, 1) as addresses:
        coro = on_mesh(scene, rs, addresses, MeshPlan(2, 2, 1), stall=3.0)
        with pytest.raises(MeshError, match="alive but stuck"):  # a TimeoutError fails it
            asyncio.run(asyncio.wait_for(coro, 30))


@pytest.mark.parametrize("high", [64, 2])
def test_tiny_receive_buffers_do_not_deadlock(high):
    # Readers that stop after 64 (or 2) queued rays: links back up constantly, yet the mesh
    # finishes (a reader resumes once the queue is down to a quarter, or empty).
    scene = read_nff(spd_scene("gears_s1.nff"))
    rs = records(width=40, height=40, threads=1)
    ref, ref_stats = render(Request(scene, *rs))
    with LocalMesh(4, options=["--incoming-high", str(high)]) as addresses:
        coro = on_mesh(scene, rs, addresses, MeshPlan(2, 2, 24), stall=20.0)
        img, stats = asyncio.run(asyncio.wait_for(coro, 120))
    assert {k: stats["rays"][k] for k in COUNTS} == {k: ref_stats["rays"][k] for k in COUNTS}
    np.testing.assert_allclose(img, ref, rtol=0, atol=1e-5)


def test_a_silent_node_fails_the_render_when_told_to_fail():
    # Node 1 stopped (SIGSTOP: alive, its sockets open, but silent): the watchdog names it.
    import os
    import signal

    scene = read_nff(spd_scene("balls_s2.nff"))
    rs = records(width=400, height=400, spp=4)
    mesh = LocalMesh(2)
    with mesh as addresses:

        async def run():
            started = asyncio.Event()
            task = asyncio.create_task(
                on_mesh(
                    scene,
                    rs,
                    addresses,
                    MeshPlan(1, 2),
                    silence=2.0,
                    progress=lambda n: started.set(),
                    on_node_loss="fail",
                )
            )
            await asyncio.wait_for(started.wait(), 60)  # tracing has begun
            os.kill(mesh.procs[1].pid, signal.SIGSTOP)
            try:
                return await asyncio.wait_for(task, 30)
            finally:
                os.kill(mesh.procs[1].pid, signal.SIGCONT)

        with pytest.raises(MeshError, match=r"node 1 \(.*\): no message for 2 s"):
            asyncio.run(run())


def test_garbage_from_a_peer_closes_only_that_link():
    scene = read_nff(spd_scene("tetra_s2.nff"))
    rs = records(width=24, height=24, threads=1)
    ref, _ = render(Request(scene, *rs))
    with LocalMesh(2) as addresses:
        host, port = addresses[1].rsplit(":", 1)
        with socket.create_connection((host, int(port))) as s:
            s.sendall(b"\x00\x00\x00\x05hello-not-msgpack")
            s.settimeout(5)
            assert s.recv(100) == b""  # the node hung up on us
        img, _ = asyncio.run(asyncio.wait_for(on_mesh(scene, rs, addresses, MeshPlan(1, 2)), 120))
    np.testing.assert_allclose(img, ref, rtol=0, atol=1e-5)


def test_cli_mesh_image_equals_single_node(tmp_path):
    scene = spd_scene("balls_s1.nff")
    one, two = tmp_path / "one.png", tmp_path / "two.png"
    common = ["--width", "32", "--height", "32", "--quiet"]
    assert main(["render", str(scene), "-o", str(one), "--mesh", "1x1", *common]) == 0
    assert main(["render", str(scene), "-o", str(two), "--mesh", "2x2", *common]) == 0
    np.testing.assert_allclose(
        read_pfm(two.with_suffix(".pfm")), read_pfm(one.with_suffix(".pfm")), atol=1e-5
    )


def test_mesh_and_cluster_arguments(tmp_path):
    assert parse_mesh("2x3") == (2, 3)
    assert parse_mesh("auto")[0] == 1
    with pytest.raises(ValueError):
        parse_mesh("2by3")
    with pytest.raises(ValueError, match="at most 64 node processes"):
        parse_mesh("9x8")  # 72 processes on one machine: refused before any starts
    f = tmp_path / "cluster.txt"
    f.write_text("# row col address\n0 0 10.0.0.1:7700\n0 1 10.0.0.2:7700\n")
    assert read_cluster(f) == (1, 2, ["10.0.0.1:7700", "10.0.0.2:7700"])
    f.write_text("0 0 a:1\n1 1 b:2\n")
    with pytest.raises(ValueError, match="no address"):
        read_cluster(f)
    f.write_text("0 0 a:1\n0 zero b:2\n")
    with pytest.raises(ValueError, match=":2:"):
        read_cluster(f)


def test_an_outbox_wakes_the_work_loop_when_it_sends():
    # A node paused on full outboxes waits for this: without it, a node whose rays bring
    # nothing back would sleep forever once its outboxes drained.
    from meshnode.transport.link import Outbox

    class Sink:
        sent: list = []

        async def send(self, message):
            self.sent.append(message)

    async def run():
        woken = asyncio.Event()
        box = Outbox(Sink(), on_error=print, sent=woken)
        box.post({"k": 4}, size=1000)
        await asyncio.wait_for(woken.wait(), 5)
        box.task.cancel()
        return box.bytes

    assert asyncio.run(run()) == 0


def test_nodes_tracing_on_several_threads_give_the_single_node_image():
    # Two batches in flight per node: deposits and passed rays come back in any order, the
    # termination waves must wait for both; image and counts stay the single node's.
    scene = read_nff(spd_scene("rings_s1.nff"))
    rs = records(width=48, height=48, spp=2, threads=1)
    ref, ref_stats = render(Request(scene, *rs))
    with LocalMesh(2, threads=2) as addresses:
        coro = on_mesh(scene, rs, addresses, MeshPlan(1, 2, 24.0))
        img, stats = asyncio.run(asyncio.wait_for(coro, 120))
    np.testing.assert_allclose(img, ref, rtol=0, atol=1e-5)
    assert {k: stats["rays"][k] for k in COUNTS} == {k: ref_stats["rays"][k] for k in COUNTS}


@pytest.mark.parametrize(
    "name,rows,cols,family",
    [("gears_s1.nff", 3, 3, "rows per column"), ("teapot_s1.nff", 2, 2, "work map")],
)
def test_cost_balanced_cuts_give_the_single_node_image(name, rows, cols, family, monkeypatch):
    # Cuts from the simulated pre-pass, of one family each: rectangles and boxes of unequal
    # sizes, or cells cut on the work map (sent to the nodes in the partition, eye rays sent
    # on to the cell they enter), same image and counts (correctness never depends on the
    # cuts; which family wins on a scene is the pre-pass's choice, tested in simulation).
    import host.planning.plan
    from host.planning import allowance
    from host.planning.balance import balanced_cuts

    families = partial(balanced_cuts, families=(family,))
    monkeypatch.setattr(host.planning.plan, "balanced_cuts", families)
    # a render this small affords no family's rounds (`host.planning.allowance`)
    monkeypatch.setattr(allowance, "PREPASS_SHARE", float("inf"))
    scene = read_nff(spd_scene(name))
    rs = records(width=60, height=60, threads=1)
    ref, ref_stats = render(Request(scene, *rs))
    img, stats = mesh_render(scene, MeshPlan(rows, cols, 2, balance="cost"), rs)
    assert stats["balance"]["cuts"] == "cost" and stats["balance"]["family"] == family
    if family != "work map":
        assert stats["balance"]["columns"] != [0, 20, 40, 60]  # the pre-pass moved them
    assert {k: stats["rays"][k] for k in COUNTS} == {k: ref_stats["rays"][k] for k in COUNTS}
    np.testing.assert_allclose(img, ref, rtol=0, atol=1e-5)


def test_brute_force_is_honoured_on_a_mesh():
    # EngineSpec(brute=True), the reference the structures are checked against, reaches every
    # node (a node's copy of the spec once dropped it and built a grid): each node's engine
    # says so, and the mesh gives one brute-force node's image and counts.
    scene = read_nff(spd_scene("balls_s1.nff"))
    rs = records(width=24, height=24, threads=1, brute=True)
    ref, ref_stats = render(Request(scene, *rs))
    assert ref_stats["engine"]["structure_reason"].startswith("brute force")
    img, stats = mesh_render(scene, MeshPlan(1, 2, 1), rs)
    assert {k: stats["rays"][k] for k in COUNTS} == {k: ref_stats["rays"][k] for k in COUNTS}
    np.testing.assert_allclose(img, ref, rtol=0, atol=1e-5)
    reasons = [node["engine"]["structure_reason"] for node in stats["nodes"]]
    assert len(reasons) == 2 and all(r.startswith("brute force") for r in reasons), reasons
