"""Neighbours' copies (MeshPlan.copies): each node also holds the engines of the nodes it links
to, built from their objects in their boxes, and traces there the rays they would take on.
Every mesh shape gives the single node's image and counts with pinhole, supersampled, camera
and adaptive renders, stolen chunks included; no ray is ever passed to a linked neighbour;
the node refuses objects of a node it does not link to, and names a neighbour whose objects
never came. Shared cells (MeshPlan.shared): every node holds them too, so their tiles go to
any node, and no ray is passed to a node whose engine the sender holds."""

import asyncio

import numpy as np
import pytest

from host.camera.setup import CameraSetup
from host.planning.partition import partition
from host.planning.request import Request
from host.run.connections import Nodes
from host.run.localmesh import LocalMesh
from host.run.meshclient import render_on_mesh, shrink
from host.run.oneprocess import render
from host.scene.nff import read_nff
from meshnode.mesh.engines import EngineCache
from meshnode.service.config import Config, Objects
from protocols.camera import CameraSampling
from protocols.errors import BadFrame
from protocols.messages import OBJECT_TABLES
from protocols.render import EngineSpec, ImageSpec, MeshPlan, RenderSpec
from protocols.spec import SpecError
from protocols.topology import Torus
from tests.conftest import records, spd_scene
from tests.meshsim import render_mesh
from tests.test_mesh_algorithm import SPD_COUNTS
from tests.test_node_service import config
from tests.test_sampling import dof_scene, thin_camera

SHAPES = [(1, 2), (2, 2), (3, 3), (2, 3)]


def _check_sends(rows: int, cols: int, nodes, shared=()) -> int:
    """Rays passed in all; asserts none went to a node the sender holds a copy of."""
    plan = MeshPlan(rows, cols, copies=True, shared=shared)
    for n, rec in enumerate(nodes):
        to_held = {m: rec.sent_to.get(m, 0) for m in plan.held(n)}
        assert not any(to_held.values()), (rows, cols, n, to_held)
    return sum(rec.rays_sent for rec in nodes)


@pytest.mark.parametrize("name,spp", [("balls_s2.nff", 1), ("gears_s1.nff", 4)])
def test_copies_on_every_mesh_give_the_single_node_image(name, spp):
    scene = read_nff(spd_scene(name))
    image = ImageSpec(width=36, height=36, spp=spp)
    ref, st = render(Request(scene, image, EngineSpec(threads=1)))
    want = {k: st["rays"][k] for k in SPD_COUNTS}
    for rows, cols in SHAPES:
        for steal in (False, True):
            img, totals, nodes, _ = render_mesh(
                scene,
                rows,
                cols,
                1,
                36,
                36,
                spp=spp,
                steal=steal,
                tile=4,
                passed_min=1,
                copies=True,
            )
            assert {k: totals[k] for k in SPD_COUNTS} == want, (rows, cols, steal)
            np.testing.assert_allclose(img, ref, rtol=0, atol=1e-12)
            passed = _check_sends(rows, cols, nodes)
            if (rows, cols) == (1, 2):
                assert passed == 0  # each node holds the other's objects: nothing crosses


def test_shared_cells_on_every_mesh_give_the_single_node_image():
    """Every node holding one or two cells' engines besides its links': the same image and
    counts as one node, with and without stealing, and fewer rays passed than without."""
    scene = read_nff(spd_scene("balls_s2.nff"))
    image = ImageSpec(width=36, height=36, spp=1)
    ref, st = render(Request(scene, image, EngineSpec(threads=1)))
    want = {k: st["rays"][k] for k in SPD_COUNTS}
    for rows, cols in SHAPES[1:]:
        n = rows * cols
        for shared, steal in (((n - 1,), True), ((0, n // 2), False)):
            img, totals, nodes, _ = render_mesh(
                scene,
                rows,
                cols,
                1,
                36,
                36,
                steal=steal,
                tile=4,
                passed_min=1,
                copies=True,
                shared=shared,
            )
            assert {k: totals[k] for k in SPD_COUNTS} == want, (rows, cols, shared)
            np.testing.assert_allclose(img, ref, rtol=0, atol=1e-12)
            _check_sends(rows, cols, nodes, shared)


@pytest.mark.parametrize("sampling", ["jittered", "adaptive"])
def test_copies_through_a_camera_give_the_single_node_image(sampling):
    scene = dof_scene()
    image = ImageSpec(width=30, height=24, spp=9, seed=3)
    setup = CameraSetup(thin_camera(), CameraSampling(sampling=sampling))
    ref, st = render(Request(scene, image, EngineSpec(threads=1), setup))
    spec, _ = setup.spec(scene, image.sized(scene.view), lambda: None)
    for rows, cols in SHAPES:
        shared = (rows * cols - 1,) if rows * cols > 2 else ()
        img, totals, nodes, _ = render_mesh(
            scene,
            rows,
            cols,
            1,
            30,
            24,
            spp=9,
            seed=3,
            camera=spec,
            steal=True,
            tile=3,
            passed_min=1,
            copies=True,
            shared=shared,
        )
        assert {k: totals[k] for k in SPD_COUNTS} == {k: st["rays"][k] for k in SPD_COUNTS}
        np.testing.assert_allclose(img, ref, rtol=0, atol=1e-12)
        _check_sends(rows, cols, nodes, shared)


@pytest.mark.parametrize("shared", [(), (3,)])
def test_copies_over_tcp_give_the_single_node_image_and_say_what_each_node_holds(shared):
    scene = read_nff(spd_scene("balls_s2.nff"))
    rs = records(width=48, height=48, spp=4, threads=1)
    ref, st = render(Request(scene, *rs))
    with LocalMesh(4) as addresses:
        plan = MeshPlan(2, 2, 1, steal=True, tile=8, copies=True, shared=shared)
        coro = render_on_mesh(Request(scene, rs.image, rs.engine, plan=plan), Nodes(addresses))
        img, stats = asyncio.run(asyncio.wait_for(coro, 120))
    assert {k: stats["rays"][k] for k in SPD_COUNTS} == {k: st["rays"][k] for k in SPD_COUNTS}
    np.testing.assert_allclose(img, ref, rtol=0, atol=1e-12)
    torus, own = Torus(2, 2), stats["objects_per_node"]
    for n, node in enumerate(stats["nodes"]):
        held = sorted(set(torus.links(n)) | set(shared) - {n})
        assert sorted(map(int, node["copies"])) == held
        assert stats["objects_held_per_node"][n] == own[n] + sum(own[m] for m in held)
    assert stats["mesh"]["copies"] is True and stats["mesh"]["shared"] == list(shared)
    objects = len(scene.spheres) + len(scene.triangles) + len(scene.polygons) + len(scene.cones)
    share = stats["objects_held_max_share"]
    assert share == 1.0 if shared else max(own) / objects <= share <= 1.0  # 2x2: all held


def test_a_node_takes_objects_only_of_itself_and_its_linked_neighbours():
    c = Config(config(node=0, plan=MeshPlan(3, 3, copies=True)))
    assert c.copies == [1, 2, 3, 6]
    objects = Objects([c.node, *c.copies])
    materials = np.zeros(1, OBJECT_TABLES["materials"])
    objects.add(3, "materials", materials)
    with pytest.raises(BadFrame, match="node = 4: this render downloads objects of 0, 1, 2, 3, 6"):
        objects.add(4, "materials", materials)
    with pytest.raises(BadFrame, match="OBJECTS: none came for node 1"):
        objects.scene(1, c.scene)
    assert Config(config(node=0, plan=MeshPlan(3, 3))).copies == []
    with pytest.raises(SpecError, match="MeshPlan.copies"):
        MeshPlan(2, 2, mode="image", copies=True)


def test_the_engine_cache_keeps_the_last_renders_engines_and_no_more():
    scenes = [read_nff(spd_scene(n)) for n in ("balls_s2.nff", "gears_s1.nff", "rings_s1.nff")]
    cache = EngineCache()
    first = [cache.get(s, keep=2)[0] for s in scenes[:2]]
    again = [cache.get(s, keep=2) for s in scenes[:2]]
    assert [e for e, _ in again] == first and all(reused for _, reused in again)
    cache.get(scenes[2], keep=2)  # a third: the least recently used goes first
    assert len(cache.engines) == 2
    assert cache.get(scenes[1], keep=2) == (first[1], True)
    assert cache.get(scenes[0], keep=2)[1] is False


def test_tiles_go_to_the_taker_or_a_neighbour_holding_its_engine_evenly():
    """Under copies a tile may be made by any node holding its taker's engine: the partition
    keeps the takers (without copies, the owners) and deals the tiles evenly among them."""
    scene = read_nff(spd_scene("balls_s2.nff"))
    image = ImageSpec(width=64, height=64).sized(scene.view)
    plain = partition(scene, RenderSpec(image, plan=MeshPlan(3, 3, tile=4)))[0]
    part = partition(scene, RenderSpec(image, plan=MeshPlan(3, 3, tile=4, copies=True)))[0]
    assert part.takers == plain.owner and plain.takers == ()
    torus = Torus(3, 3)
    for taker, owner in zip(part.takers, part.owner, strict=True):
        assert owner == taker or owner in torus.links(taker)
    counts = np.bincount(part.owner, minlength=9)
    assert counts.max() < np.bincount(plain.owner, minlength=9).max()  # spread out


def test_shared_cells_are_checked_and_held_by_every_node():
    plan = MeshPlan(3, 3, copies=True, shared=(8,))
    assert plan.held(0) == [0, 1, 2, 3, 6, 8] and plan.held(8) == [8, 2, 5, 6, 7]
    assert plan.holders(8) == [8, *range(8)] and plan.holders(4) == [4, 1, 3, 5, 7]
    assert MeshPlan.from_wire({**plan.to_wire(), "shared": [8]}) == plan  # msgpack: a list
    for bad, why in (
        ((9,), "distinct nodes from 0 to 8"),
        ((1, 1), "distinct nodes"),
        ((True,), "list of node numbers"),
        ([1], "list of node numbers"),
    ):
        with pytest.raises(SpecError, match=why):
            MeshPlan(3, 3, copies=True, shared=bad)
    with pytest.raises(SpecError, match="need 'copies'"):
        MeshPlan(3, 3, shared=(1,))
    # a node lost: the re-plan on 8 nodes (2x4) chooses its own shared cells
    assert shrink(plan, 8) == MeshPlan(2, 4, copies=True)


def test_tiles_of_a_shared_cell_are_dealt_over_the_whole_mesh():
    """Where most eye rays enter one cell, only it and its four neighbours can make them; with
    that cell shared, every node makes an even share of the tiles."""
    scene = read_nff(spd_scene("balls_s2.nff"))
    image = ImageSpec(width=64, height=64).sized(scene.view)
    part = partition(scene, RenderSpec(image, plan=MeshPlan(3, 3, tile=4, copies=True)))[0]
    hot = int(np.bincount(part.takers).argmax())
    plan = MeshPlan(3, 3, tile=4, copies=True, shared=(hot,))
    shared = partition(scene, RenderSpec(image, plan=plan))[0]
    assert shared.takers == part.takers
    mine = np.asarray(shared.takers) == hot
    before = set(np.asarray(part.owner)[mine].tolist())
    assert before <= set(plan.held(hot))  # the hot cell and its four links only
    assert len(set(np.asarray(shared.owner)[mine].tolist())) > len(before)
    counts = np.bincount(shared.owner, minlength=9)
    assert counts.max() - counts.min() <= 1 < np.ptp(np.bincount(part.owner, minlength=9))


def test_the_pre_pass_shares_the_cell_the_work_gathers_in_within_memory():
    """mount_s1 under even cuts on 3x3: all its objects lie in one cell, so only that cell
    and its four links work. The pre-pass shares a cell, which spreads the simulated work
    over more nodes and lowers the busiest; a memory too small for it shares none."""
    from host.planning.prepass import node_costs
    from host.planning.shared_cells import SHARE_GAIN, choose_shared

    scene = read_nff(spd_scene("mount_s1.nff"))
    image = ImageSpec(width=48, height=48).sized(scene.view)
    spec = RenderSpec(image, plan=MeshPlan(3, 3, 100, tile=4, steal=True, copies=True))
    before = node_costs(scene, spec, None, None)
    assert (before > 0.01 * before.max()).sum() <= 5
    shared, report = choose_shared(scene, spec, None, None, None, True, before.max())
    assert shared and report["chosen"] == list(shared)
    at = RenderSpec(image, plan=MeshPlan(3, 3, 100, tile=4, steal=True, copies=True, shared=shared))
    after = node_costs(scene, at, None, None)
    assert after.max() <= SHARE_GAIN * before.max()
    assert (after > 0.01 * after.max()).sum() > 5
    none, refused = choose_shared(scene, spec, None, None, None, True, before.max(), memory=1)
    assert none == () and refused["too_big_for_memory"]
