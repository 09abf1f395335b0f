"""--mode auto: image space when the whole scene's engine fits comfortably in the smallest
node's memory (reported by each node at the handshake, or --node-memory), object space when
it does not; the choice and the reason are in the first line of output and in the stats."""

import asyncio

import numpy as np
import pytest

from host.cli import main
from host.planning.holding import FITS, engine_bytes
from host.planning.plan import choose_mode
from host.planning.request import Auto, Request
from host.run.connections import Nodes
from host.run.localmesh import LocalMesh
from host.run.meshclient import render_on_mesh
from host.run.oneprocess import render
from host.scene.nff import read_nff
from protocols.render import MeshPlan
from tests.conftest import records, spd_scene


def test_choose_mode_weighs_the_engine_against_the_smallest_node():
    scene = read_nff(spd_scene("balls_s1.nff"))
    need = engine_bytes(scene)
    assert need > 0
    plan = MeshPlan(2, 2)
    roomy = int(need / FITS) + 1
    assert choose_mode(plan, scene, [roomy * 4, roomy])[0].mode == "image"
    tight, why = choose_mode(plan, scene, [roomy * 4, roomy - 2])
    assert tight.mode == "object" and "would take over 25%" in why
    assert choose_mode(plan, scene, [0, 0])[0].mode == "object"  # nothing reported
    assert choose_mode(plan, scene, [1], override=roomy)[0].mode == "image"
    assert choose_mode(plan, scene, [roomy * 9], override=roomy - 2)[0].mode == "object"
    cost = choose_mode(MeshPlan(2, 2, balance="cost"), scene, [roomy * 9])
    assert cost[0].mode == "object" and "--balance cost" in cost[1]
    asked = choose_mode(plan, scene, [roomy * 9], "object")
    assert asked == (MeshPlan(2, 2, mode="object"), "asked for with --mode object")


@pytest.mark.parametrize(
    "name,node_memory,mode",
    # balls_s1: a few KB of engine, fits in any node; tetra: about 1.8 MB, over a quarter of
    # 4 MiB, while half of it (and the occupancy map) stays within 4 MiB on each of two nodes
    [("balls_s1.nff", None, "image"), ("tetra.nff", 4 << 20, "object")],
)
def test_auto_on_real_nodes_reports_memory_and_gives_the_single_node_image(name, node_memory, mode):
    scene = read_nff(spd_scene(name))
    rs = records(width=32, height=32, threads=1)
    ref, ref_stats = render(Request(scene, *rs))
    notices: list[str] = []
    with LocalMesh(2) as addresses:
        coro = render_on_mesh(
            Request(
                scene,
                rs.image,
                rs.engine,
                plan=MeshPlan(1, 2),
                auto=Auto(mode="auto", node_memory=node_memory),
            ),
            Nodes(addresses),
            notice=notices.append,
        )
        img, stats = asyncio.run(asyncio.wait_for(coro, 120))
    assert stats["mode"]["choice"] == mode == stats["mesh"]["mode"]
    assert all(m > 64 << 20 for m in stats["mode"]["node_memory_bytes"])  # real reports
    assert notices[0].startswith(f"plan: {mode} space on 1x2 (")
    if mode == "image":  # (object space may pass none: each eye ray made where it ends)
        assert stats["rays_passed"] == 0
    if node_memory:  # in object space --node-memory bounds each node's engines
        assert stats["mesh"]["node_bytes"] == node_memory
        assert all(0 < n["engine_bytes_held"] <= node_memory for n in stats["nodes"])
    assert stats["rays"]["eye_rays"] == ref_stats["rays"]["eye_rays"]
    np.testing.assert_allclose(img, ref, rtol=0, atol=1e-5)


def test_the_cli_says_which_plan_it_chose_first(tmp_path, capsys):
    scene = str(spd_scene("tetra.nff"))  # about 1.8 MB of engine: over a quarter of 4M
    out = str(tmp_path / "t.png")
    assert (
        main(
            [
                "render",
                scene,
                "-o",
                out,
                "--mesh",
                "1x2",
                "--width",
                "16",
                "--height",
                "16",
                "--node-memory",
                "4M",
            ]
        )
        == 0
    )
    # The first line the host writes, among the progress bar's redraws:
    lines = capsys.readouterr().err.replace("\r", "\n").splitlines()
    first = next(line for line in lines if line.startswith("host:"))
    assert first.startswith("host: plan: object space on 1x2 (the whole scene's engine")
    assert "--node-memory" in first
    with pytest.raises(SystemExit) as e:
        main(["render", scene, "-o", out, "--node-memory", "lots"])
    assert e.value.code == 2
    assert "'lots' is not a memory size" in capsys.readouterr().err


def test_a_running_cluster_reuses_the_engine_of_an_unchanged_scene():
    # Same objects, boxes and engine settings: the second render builds nothing (each node
    # says so); another scene builds again. Images are the single node's every time.
    balls, tetra = read_nff(spd_scene("balls_s1.nff")), read_nff(spd_scene("tetra_s2.nff"))
    with LocalMesh(2, once=False) as addresses:

        def run(scene, spp):
            rs = records(width=24, height=24, spp=spp, threads=1)
            coro = render_on_mesh(
                Request(scene, rs.image, rs.engine, plan=MeshPlan(1, 2)), Nodes(addresses)
            )
            img, stats = asyncio.run(asyncio.wait_for(coro, 120))
            np.testing.assert_allclose(img, render(Request(scene, *rs))[0], rtol=0, atol=1e-5)
            return [n["engine_reused"] for n in stats["nodes"]], stats

        assert run(balls, 1)[0] == [False, False]
        reused, stats = run(balls, 4)  # other sampling, same engine
        assert reused == [True, True]
        assert all(n["setup_seconds"] > 0 for n in stats["nodes"])
        assert 0 < stats["connect_seconds"] and 0 < stats["setup_seconds"] < stats["wall_seconds"]
        assert 0 < stats["parallel_efficiency"] <= 1
        # a node's batches cost their kernels and the routing around them
        assert all(0 < n["busy_cpu_seconds"] <= n["batch_cpu_seconds"] for n in stats["nodes"])
        assert stats["busiest_node_batch_cpu_seconds"] >= stats["busiest_node_cpu_seconds"]
        assert run(tetra, 1)[0] == [False, False]


def test_the_auto_choices_are_checked_when_asked_for():
    # A mode the host cannot choose, or a memory of no bytes, fails where the request is
    # made, not after the nodes have been dialled.
    with pytest.raises(ValueError, match="mode 'sideways'"):
        Auto(mode="sideways")
    with pytest.raises(ValueError, match="node memory 0"):
        Auto(node_memory=0)
    assert Auto(overlaps=[1, 2]).overlaps == (1.0, 2.0)
