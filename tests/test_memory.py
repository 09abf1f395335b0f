"""A node gives a render's memory back (issue 41 item 2): its resident set after a render of
262,144 triangles (40 MB of records, an engine of about 100 MB) returns to within 100 MB of
what it was before, measured from the node process's own /proc status."""

import asyncio
import sys
from pathlib import Path

import pytest

from bench.generate import tetra
from host.planning.request import Request
from host.run.connections import Nodes
from host.run.localmesh import LocalMesh
from host.run.meshclient import render_on_mesh
from host.scene.nff import read_nff
from protocols.render import EngineSpec, ImageSpec, MeshPlan
from tests.conftest import spd_scene

MB = 1024 * 1024


def resident(pid: int) -> dict[str, int]:
    """The process's resident set now (VmRSS) and at its peak (VmHWM), bytes."""
    out = {}
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        key, _, value = line.partition(":")
        if key in ("VmRSS", "VmHWM"):
            out[key] = int(value.split()[0]) * 1024
    return out


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc")
def test_a_node_gives_a_large_renders_memory_back():
    small, large = read_nff(spd_scene("balls_s2.nff")), tetra(9)
    mesh = LocalMesh(1, once=False)
    with mesh as addresses:
        pid = mesh.procs[0].pid

        def run(scene) -> None:
            image = ImageSpec(width=48, height=48)
            plan, engine = MeshPlan(1, 1), EngineSpec(threads=1)
            asyncio.run(
                asyncio.wait_for(
                    render_on_mesh(Request(scene, image, engine, plan=plan), Nodes(addresses)), 120
                )
            )

        run(small)  # kernels loaded, one small engine cached
        before = resident(pid)
        run(large)
        # two small renders: the first replaces the cached engine, and the large one goes
        # when that render's session ends
        run(small)
        run(small)
        after = resident(pid)
    assert after["VmHWM"] - before["VmRSS"] > 100 * MB  # the large render held memory
    assert after["VmRSS"] - before["VmRSS"] < 100 * MB, (before, after)


def test_engines_kept_between_renders_stay_within_their_bound():
    # `meshnode serve --keep-engines SIZE`: after a render the oldest engines go until the
    # rest fit; 0 keeps none, so a render's whole memory can come back.
    from meshnode.mesh.engines import EngineCache

    scenes = [read_nff(spd_scene("balls_s1.nff")), read_nff(spd_scene("tetra_s1.nff"))]
    cache = EngineCache(keep_bytes=None)
    first, _ = cache.get(scenes[0], keep=2)
    second, _ = cache.get(scenes[1], keep=2)
    cache.trim()  # no bound: both stay
    assert len(cache.engines) == 2
    cache.keep_bytes = second.nbytes()  # room for the newer one only
    cache.trim()
    assert list(cache.engines.values()) == [second] and first.nbytes() > 0
    cache.keep_bytes = 0
    cache.trim()
    assert not cache.engines
    assert cache.get(scenes[1])[1] is False  # built again, not reused
