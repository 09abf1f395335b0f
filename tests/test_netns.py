"""The mesh over real network devices: each node in its own network namespace, on a bridge,
with its own address; one cable rate-limited, one with a small MTU; a node cut off mid-render.
Needs root and iproute2 (CI machines like this one have them)."""

import asyncio

import numpy as np
import pytest

from host.planning.request import Request
from host.run.connections import Nodes
from host.run.errors import MeshError
from host.run.meshclient import render_on_mesh
from host.run.oneprocess import render
from host.scene.nff import read_nff
from protocols.render import MeshPlan
from tests import netns
from tests.conftest import records, spd_scene

pytestmark = pytest.mark.skipif(not netns.available(), reason="needs root and ip netns")

COUNTS = ("eye_rays", "reflected_rays", "refracted_rays", "shadow_rays", "shadow_rays_blocked")


def _shape(net):
    net.shape(1, rate="100mbit")  # ~12 MB/s: rays queue behind it
    net.shape(2, mtu=1280)  # frames split across many small packets


def test_mesh_across_namespaces_equals_single_node():
    scene = read_nff(spd_scene("rings_s1.nff"))
    rs = records(width=64, height=64, threads=1)
    ref, ref_stats = render(Request(scene, *rs))
    with netns.namespaced_mesh(4, _shape) as (_, mesh, addresses):
        assert all(a.startswith("10.213.") for a in addresses)
        coro = render_on_mesh(
            Request(scene, rs.image, rs.engine, plan=MeshPlan(2, 2, 24.0)),
            Nodes(addresses, secret=mesh.secret),
        )
        img, stats = asyncio.run(asyncio.wait_for(coro, 120))
    np.testing.assert_allclose(img, ref, rtol=0, atol=1e-5)
    assert {k: stats["rays"][k] for k in COUNTS} == {k: ref_stats["rays"][k] for k in COUNTS}
    nodes = stats["nodes"]
    assert sum(n["rays_sent"] for n in nodes) == sum(n["rays_received"] for n in nodes) > 0


def test_a_node_cut_off_the_network_is_named_within_seconds():
    scene = read_nff(spd_scene("balls_s2.nff"))
    rs = records(width=400, height=400, spp=4)  # several seconds' work
    with netns.namespaced_mesh(2) as (net, mesh, addresses):

        async def run():
            started = asyncio.Event()
            coro = render_on_mesh(
                Request(scene, rs.image, plan=MeshPlan(1, 2)),
                Nodes(addresses, secret=mesh.secret),
                silence=3.0,
                on_node_loss="fail",
                progress=lambda n: started.set(),
            )
            task = asyncio.create_task(coro)
            await asyncio.wait_for(started.wait(), 60)  # tracing has begun
            net.cut(1)  # no RST, no FIN: only silence tells
            return await asyncio.wait_for(task, 15)  # named within seconds, or TimeoutError

        with pytest.raises(MeshError, match=r"node 1 \(10\.213\.[0-9.]+:7700\): no message"):
            asyncio.run(run())
