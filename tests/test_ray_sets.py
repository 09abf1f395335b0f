"""Several RAYS leaving over one link in one RAYS_SET frame (`meshnode.service.sends`): each
part checked as a RAYS is before anything is queued or passed on, and a real mesh that sends
them renders one node's image and counts."""

import asyncio

import numpy as np
import pytest

from host.planning.request import Request
from host.run.connections import Nodes
from host.run.localmesh import LocalMesh
from host.run.meshclient import render_on_mesh
from host.run.oneprocess import render
from host.scene.nff import read_nff
from meshnode.engine.counters import RAY_COUNTS
from meshnode.service.inbound import checked_parts
from protocols.dtypes import RAY
from protocols.errors import BadFrame
from protocols.render import EngineSpec, ImageSpec, MeshPlan
from tests.conftest import spd_scene


def _rays(n):
    r = np.zeros(n, RAY)
    r["d"][:, 2], r["t_max"], r["w"], r["depth"] = 1.0, np.inf, 1.0, 1
    return r


def _frame(parts, n):
    return {"parts": np.asarray(parts, np.int64).reshape(-1), "rays": _rays(n)}


def test_parts_are_read_as_destinations_cells_and_their_rays():
    got = checked_parts(_frame([(1, 2, 3), (3, 3, 1), (0, 1, 2)], 6), 4)
    assert got == [(1, 2, 0, 3), (3, 3, 3, 4), (0, 1, 4, 6)]


@pytest.mark.parametrize(
    "parts,n,message",
    [
        ([1, 2], 2, "not 2 to 16 triples"),
        ([(1, 1, 2)], 2, "not 2 to 16 triples"),
        ([(4, 1, 1), (0, 0, 1)], 2, "outside the mesh"),
        ([(1, -1, 1), (0, 0, 1)], 2, "outside the mesh"),
        ([(1, 1, 2), (0, 0, 1)], 2, "add up to 2"),
        ([(1, 1, 2), (0, 0, 0)], 2, "at least 1"),
    ],
)
def test_a_bad_set_is_refused_by_name_before_anything_is_taken(parts, n, message):
    with pytest.raises(BadFrame, match=message):
        checked_parts(_frame(parts, n), 4)


def test_a_ray_the_engine_cannot_trace_is_refused_by_its_index():
    f = _frame([(1, 1, 2), (2, 2, 3)], 5)
    f["rays"]["o"][3, 1] = np.nan
    with pytest.raises(BadFrame, match="RAYS_SET: ray 3 of 5 cannot be traced"):
        checked_parts(f, 4)


def test_a_mesh_sending_ray_sets_renders_one_nodes_image_and_counts():
    """Object space under a quarter share on 3x3 local nodes: its flushes send RAYS_SET
    frames, nodes relay rays between nodes two links apart and trace batches of few passed
    rays on their event loop's thread (each counted by the nodes themselves), and every ray
    still ends once, where one node ends it."""
    scene = read_nff(spd_scene("balls_s2.nff"))
    image = ImageSpec(width=48, height=48, spp=2)
    one = EngineSpec(threads=1)
    ref, ref_stats = render(Request(scene, image, one), progress=False)
    plan = MeshPlan(3, 3, balance="objects", max_share=0.25)
    with LocalMesh(9) as addresses:
        img, stats = asyncio.run(
            render_on_mesh(Request(scene, image, one, plan=plan), Nodes(addresses))
        )
    assert {k: stats["rays"][k] for k in RAY_COUNTS} == {
        k: ref_stats["rays"][k] for k in RAY_COUNTS
    }
    np.testing.assert_allclose(img, ref, rtol=0, atol=1e-5)
    assert sum(n["ray_sets_sent"] for n in stats["nodes"]) > 0
    assert sum(n["rays_relayed"] for n in stats["nodes"]) > 0
    assert sum(n["batches_inline"] for n in stats["nodes"]) > 0
    for n in stats["nodes"]:  # the event loop's thread: within what the batches leave
        outside = n["frame_cpu_seconds"] - n["batch_cpu_seconds"]
        assert 0.0 < n["loop_cpu_seconds"] <= outside + 1e-3
