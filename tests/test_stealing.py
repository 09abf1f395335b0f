"""Object-space stealing (MeshPlan.steal): each node traces its rectangle in chunks spiralling
out from the centre; a node that has run out takes unstarted chunks from the outer end of a
busy neighbour's spiral and makes their primary rays itself. Every mesh shape gives the
single node's image and counts (every pixel traced exactly once), chunks really move, and
termination waves cannot end TRACE while a STEAL or GIVE is on its way."""

import asyncio
from pathlib import Path

import numpy as np
import pytest

from host.camera.lensfile import read_camera
from host.camera.setup import CameraSetup
from host.planning.plan import plan_render
from host.planning.request import Request
from host.run.connections import Nodes
from host.run.localmesh import LocalMesh
from host.run.meshclient import render_on_mesh
from host.run.oneprocess import render
from host.scene.nff import read_nff
from meshnode.mesh.adaptive import AdaptiveFilm
from meshnode.mesh.feeds import ChunkFeed
from meshnode.mesh.scheduler import Scheduler
from meshnode.mesh.spiral import spiral_chunks
from meshnode.mesh.steps import Give, Steal, Trace
from meshnode.mesh.termination import Probe
from protocols.camera import CameraSampling
from protocols.dtypes import RAY
from protocols.render import EngineSpec, ImageSpec, MeshPlan
from protocols.spec import SpecError
from protocols.state import State
from tests.conftest import records, spd_scene
from tests.meshsim import render_mesh
from tests.test_mesh_algorithm import SPD_COUNTS
from tests.test_sampling import dof_scene, thin_camera


def test_spiral_chunks_tile_the_rectangle_once_from_the_centre_out():
    rect = (3, 40, 5, 30)
    chunks = spiral_chunks(rect, 6)
    cover = np.zeros((30, 40), int)
    for x0, x1, y0, y1 in chunks:
        cover[y0:y1, x0:x1] += 1
    assert (cover[5:30, 3:40] == 1).all() and cover.sum() == 37 * 25  # once, nothing outside
    ring = [
        max(abs(i - 3), abs(j - 2))
        for i, j in (  # chunk grid 7 x 5, centre (3, 2)
            ((x0 - 3) // 6, (y0 - 5) // 6) for x0, _, y0, _ in chunks
        )
    ]
    assert ring == sorted(ring) and ring[0] == 0  # the centre first, then ring by ring


def test_a_chunk_feed_gives_half_its_unstarted_chunks_from_the_outer_end():
    made = []

    def batches(chunks):
        made.extend(chunks)
        yield np.zeros(1, RAY)

    feed = ChunkFeed([(i, i + 1, 0, 1) for i in range(6)], batches)
    assert made == [(0, 1, 0, 1)]  # the first chunk is started by the look-ahead
    assert feed.take() == [(5, 6, 0, 1), (4, 5, 0, 1)]  # 2 of the 5 unstarted, outer first
    feed.pop()
    feed.add([(9, 10, 0, 1)])
    while feed:
        feed.pop()
    assert made == [(i, i + 1, 0, 1) for i in range(4)] + [(9, 10, 0, 1)]  # none twice
    assert feed.take() == []


def test_a_chunk_feed_starts_as_many_chunks_as_fit_its_ray_budget():
    made = []

    def batches(chunks):
        made.append(list(chunks))
        yield np.zeros(1, RAY)

    chunks = [(i, i + 1, 0, 1) for i in range(7)]
    feed = ChunkFeed(chunks, batches, rays=lambda c: 3, budget=7)
    assert made == [chunks[:2]]  # 3 + 3 rays fit 7, a third would not
    assert feed.take() == [chunks[6], chunks[5]]  # unstarted ones only, outer first
    while feed:
        feed.pop()
    assert made == [chunks[:2], chunks[2:4], chunks[4:5]]
    made.clear()
    feed = ChunkFeed(chunks[:2], batches, rays=lambda c: 10, budget=7)  # over: one each
    while feed:
        feed.pop()
    assert made == [chunks[:1], chunks[1:2]]


def test_a_node_out_of_work_steals_and_holds_the_wave_until_answered():
    s = Scheduler(1, 0, (), neighbours=[0], steal=True)
    s.probe_in(Probe(1, int(State.TRACE)))
    assert s.next().state == State.TRACE
    s.primaries = ChunkFeed([], lambda c: iter([np.zeros(16, RAY)]))
    assert s.next() == Steal(0)
    s.message_out()  # the driver counts the STEAL as sent
    assert s.next() is None  # no second ask, and the wave waits for the answer
    s.given(0, [(0, 4, 0, 4)])
    step = s.next()
    assert isinstance(step, Trace) and step.primary  # the given chunk's rays, made here
    s.batch_done()
    assert s.next() == Steal(0)  # out again: ask again (it had work last time)
    s.message_out()
    s.given(0, [])
    assert s.term.sent == s.term.received == 2  # STEAL and GIVE are counted messages
    assert not isinstance(s.next(), Steal)  # it had none: not asked again in this state


def test_a_busy_node_answers_a_steal_before_tracing_on():
    s = Scheduler(0, 1, (), neighbours=[1], steal=True)
    s.state = State.TRACE
    s.primaries = ChunkFeed(
        [(i, i + 1, 0, 1) for i in range(5)], lambda c: iter([np.zeros(1, RAY)])
    )
    s.steal_request(1)
    assert s.next() == Give(1, [(4, 5, 0, 1), (3, 4, 0, 1)]) and s.chunks_given == 2


def test_a_node_that_had_nothing_gives_unasked_once_it_has_chunks_to_spare():
    """Node 1 links to 0 and 2 only; 0 asks 1 while 1 has nothing, then 1 steals from 2: 1
    hands 0 half of what it got without being asked again (0 could not ask 2 itself)."""
    s = Scheduler(1, 0, (2,), neighbours=[0, 2], steal=True)
    s.state = State.TRACE
    s.primaries = ChunkFeed([], lambda c: iter([np.zeros(1, RAY)]))
    s.steal_request(0)
    assert s.next() == Give(0, [])
    s.message_out()
    assert s.next() == Steal(0) and s.steal_from == 0  # out of work too: asks in turn
    s.message_out()
    s.given(0, [])  # 0 had none either
    assert s.next() == Steal(2)
    s.message_out()
    s.given(2, [(i, i + 1, 0, 1) for i in range(5)])  # the first is started at once
    assert s.next() == Give(0, [(4, 5, 0, 1), (3, 4, 0, 1)])  # unasked: 0 had asked before
    s.message_out()
    assert isinstance(s.next(), Trace) and s.chunks_given == 2 and not s.hungry
    assert s.term.sent == s.term.received + 1  # the gift is a counted message


@pytest.mark.parametrize(
    "name,spp,corners",
    [("balls_s2.nff", 1, False), ("gears_s1.nff", 4, False), ("rings_s1.nff", 1, True)],
)
def test_stealing_on_every_mesh_gives_the_single_node_image(name, spp, corners):
    scene = read_nff(spd_scene(name))
    size = 24 if corners else 36
    image = ImageSpec(width=size, height=size, spp=spp, spd=corners)
    ref, st = render(Request(scene, image, EngineSpec(threads=1)))
    moved = 0
    for rows, cols in [(1, 2), (2, 2), (3, 3), (2, 3)]:
        # Passed rays go first as they come (passed_min 1): at this size they never reach
        # PASSED_MIN, so every node would trace its primaries at one pace and none run out
        # early; this way nodes busy with passed rays fall behind and the others steal.
        img, totals, nodes, _ = render_mesh(
            scene,
            rows,
            cols,
            1,
            size,
            size,
            corners=corners,
            spp=spp,
            steal=True,
            tile=4,
            passed_min=1,
        )
        assert {k: totals[k] for k in SPD_COUNTS} == {k: st["rays"][k] for k in SPD_COUNTS}
        np.testing.assert_allclose(img, ref, rtol=0, atol=1e-5)
        assert sum(n.chunks_given for n in nodes) == sum(n.chunks_taken for n in nodes)
        moved += sum(n.chunks_given for n in nodes)
    assert moved > 0  # chunks did change hands, and every pixel was still traced once


def test_stealing_through_a_camera_and_where_it_is_refused():
    scene = read_nff(spd_scene("balls_s2.nff"))
    rs = records(width=24, height=24, spp=16, threads=1)
    lens = Path(__file__).resolve().parents[1] / "host" / "cameras" / "thin_f2.8.toml"
    camera = CameraSetup(read_camera(lens))
    ref, st = render(Request(scene, rs.image, rs.engine, camera))
    spec = plan_render(
        Request(scene, rs.image, rs.engine, camera, MeshPlan(2, 2, steal=True, tile=4))
    ).spec
    img, totals, nodes, _ = render_mesh(
        scene, 2, 2, 1, 24, 24, spp=16, camera=spec.camera, steal=True, tile=4
    )
    assert totals["eye_rays"] == st["rays"]["eye_rays"]
    np.testing.assert_allclose(img, ref, rtol=0, atol=1e-5)
    with pytest.raises(SpecError, match="MeshPlan.steal"):
        MeshPlan(2, 2, mode="image", steal=True)


def adaptive_setup(width, height):
    """The depth-of-field scene, an adaptive thin-lens camera, and its `CameraSpec`."""
    scene = dof_scene()
    image = ImageSpec(width=width, height=height, spp=9, seed=3)
    setup = CameraSetup(thin_camera(), CameraSampling(sampling="adaptive"))
    spec, _ = setup.spec(scene, image.sized(scene.view), lambda: None)
    return scene, image, setup, spec


def test_adaptive_sampling_steals_both_passes_and_gives_the_single_node_image(monkeypatch):
    """Pass 1's chunks and pass 2's runs of refined pixels change hands; the owners keep
    the books, so every pixel is divided by the rays it got, exactly as on one node (passed
    rays first as they come, so nodes fall behind and steal at this size: see above; chunks
    start CHUNK_RAYS rays' worth at a time, and a small budget leaves some to steal). On the
    work clock, where a node's dear batches hold it back: with one batch a node a turn and
    every node starting TRACE within a wave's few hops, nobody ran out early in pass 1."""
    monkeypatch.setattr("meshnode.mesh.books.CHUNK_RAYS", 64)
    scene, image, setup, spec = adaptive_setup(30, 24)
    ref, st = render(Request(scene, image, EngineSpec(threads=1), setup))
    given = {"TRACE": 0, "REFINE": 0}
    for rows, cols in [(1, 2), (2, 2), (3, 3), (2, 3)]:
        img, totals, nodes, _ = render_mesh(
            scene,
            rows,
            cols,
            1,
            30,
            24,
            spp=image.spp,
            seed=3,
            camera=spec,
            steal=True,
            tile=3,
            passed_min=1,
            clock="work",
            latency=1000,
        )
        assert {k: totals[k] for k in SPD_COUNTS} == {k: st["rays"][k] for k in SPD_COUNTS}
        np.testing.assert_allclose(img, ref, rtol=0, atol=1e-12)
        assert sum(n.chunks_given for n in nodes) == sum(n.chunks_taken for n in nodes)
        for n in nodes:
            for state, count in n.given_in.items():
                given[state] += count
    assert given["TRACE"] > 0 and given["REFINE"] > 0  # both passes were stolen from


def test_refined_runs_cover_exactly_the_refined_pixels_of_a_chunk():
    film = AdaptiveFilm(adaptive_setup(16, 12)[3], 9, (2, 12, 1, 9), 16, 12)
    rng = np.random.default_rng(5)
    film.refined = rng.random(len(film.pixels)) < 0.4
    chunk = (4, 11, 2, 7)
    cover = np.zeros((12, 16), int)
    for x0, x1, y0, y1 in film.refined_runs(chunk):
        assert y1 == y0 + 1 and x1 > x0
        cover[y0:y1, x0:x1] += 1
    want = np.zeros((12, 16), int)
    want.reshape(-1)[film.pixels[film.refined]] = 1
    mask = np.zeros((12, 16), bool)
    mask[2:7, 4:11] = True
    assert (cover == want * mask).all()  # each refined pixel of the chunk once, nothing else


def test_stealing_over_tcp_gives_the_single_node_image():
    scene = read_nff(spd_scene("balls_s2.nff"))
    rs = records(width=48, height=48, spp=4, threads=1)
    ref, st = render(Request(scene, *rs))
    with LocalMesh(4) as addresses:
        coro = render_on_mesh(
            Request(scene, rs.image, rs.engine, plan=MeshPlan(2, 2, 1, steal=True, tile=8)),
            Nodes(addresses),
        )
        img, stats = asyncio.run(asyncio.wait_for(coro, 120))
    assert {k: stats["rays"][k] for k in SPD_COUNTS} == {k: st["rays"][k] for k in SPD_COUNTS}
    np.testing.assert_allclose(img, ref, rtol=0, atol=1e-5)
    assert sum(n["chunks_given"] for n in stats["nodes"]) == sum(
        n["chunks_taken"] for n in stats["nodes"]
    )


def test_adaptive_stealing_over_tcp_gives_the_single_node_image():
    scene, image, setup, _ = adaptive_setup(30, 24)
    ref, st = render(Request(scene, image, EngineSpec(threads=1), setup))
    with LocalMesh(4) as addresses:
        coro = render_on_mesh(
            Request(
                scene, image, EngineSpec(threads=1), setup, MeshPlan(2, 2, 1, steal=True, tile=3)
            ),
            Nodes(addresses),
        )
        img, stats = asyncio.run(asyncio.wait_for(coro, 120))
    assert {k: stats["rays"][k] for k in SPD_COUNTS} == {k: st["rays"][k] for k in SPD_COUNTS}
    np.testing.assert_allclose(img, ref, rtol=0, atol=1e-12)
    given = [n["chunks_given_by_state"] for n in stats["nodes"]]
    assert sum(n["chunks_given"] for n in stats["nodes"]) == sum(
        n["chunks_taken"] for n in stats["nodes"]
    )
    # Whether chunks change hands over TCP, and in which pass, depends on timing (a clean
    # CI run once gave none in one pass): the by-state record must add up; the simulated
    # mesh above shows both passes stolen from, deterministically.
    assert sum(sum(g.values()) for g in given) == sum(n["chunks_given"] for n in stats["nodes"])


def test_holders_steal_claimed_chunks_and_give_the_single_node_image(monkeypatch):
    # Under copies the eye's claims stay on (each block's eye rays made where they are
    # traced): a node out of work takes unstarted chunks of a neighbour's claimed samples
    # whose every block starts in a cell it holds, and makes them as their claimant would.
    import meshnode.mesh.node
    from meshnode.mesh.claimfeed import ClaimFeed

    feeds = []

    class Kept(ClaimFeed):
        def __init__(self, *args):
            super().__init__(*args)
            feeds.append(self)

    monkeypatch.setattr(meshnode.mesh.node, "ClaimFeed", Kept)
    # chunks are made together up to a batch: at this size a copies' batch would take a
    # node's every chunk at once, and none would be left to take
    monkeypatch.setattr(meshnode.mesh.node, "COPIES_EYE_BATCH", 16)
    scene = read_nff(spd_scene("balls_s2.nff"))
    ref, st = render(Request(scene, ImageSpec(width=32, height=32, spp=4), EngineSpec(threads=1)))
    moved = 0
    for shape in [(1, 2), (2, 2), (3, 3), (2, 3)]:
        nodes = shape[0] * shape[1]
        holds = tuple(tuple(c for c in (0, 1) if c != n) for n in range(nodes))  # 0, 1: all
        feeds.clear()
        img, totals, records, _ = render_mesh(
            scene, *shape, 1.0, 32, 32, spp=4, balance="objects", copies=True, holds=holds,
            steal=True, tile=4, passed_min=1, batch=16,
        )  # fmt: skip
        assert {k: totals[k] for k in SPD_COUNTS} == {k: st["rays"][k] for k in SPD_COUNTS}
        np.testing.assert_allclose(img, ref, rtol=0, atol=1e-5)
        assert len(feeds) == nodes  # the claims kept under stealing: every node's feed
        given = sum(r.chunks_given for r in records)
        assert given == sum(r.chunks_taken for r in records)
        moved += given
        # a given chunk is made as its giver claimed it, and never given on
        for feed in feeds:
            thief = (feed.node + 1) % nodes
            assert not feed.usable(thief, [(0, 4, 0, 4, thief)]).any()
    assert moved > 0  # chunks did change hands, and every sample was still made once


def test_a_budget_s_copies_set_their_holders_stealing():
    import math
    from dataclasses import replace
    from unittest import mock

    from host.planning import allowance
    from host.planning.plan import plan_render, stealing
    from host.planning.request import Auto

    scene = read_nff(spd_scene("teapot.nff"))
    plan = MeshPlan(3, 3, max_share=0.25, balance="objects")
    image = ImageSpec(width=48, height=48, spp=2)
    one = EngineSpec(threads=1)
    with mock.patch.object(allowance, "PREPASS_SHARE", math.inf):
        on = plan_render(Request(scene, image, one, plan=plan))
        off = plan_render(Request(scene, image, one, plan=plan, auto=Auto(steal_claims=False)))
    assert on.spec.plan.holds and on.spec.plan.steal  # the hot spout's cell is copied
    assert on.balance["budget"]["copies"]["steal"]["chosen"] is True
    assert off.spec.plan.holds and not off.spec.plan.steal
    bare = dict(copies=False, holds=(), claim_shares=(), steal=False)
    none = replace(on.spec, plan=replace(on.spec.plan, **bare))
    assert stealing(none) == (none, {"chosen": False, "why": stealing(none)[1]["why"]})
    assert "no copies" in stealing(none)[1]["why"]
