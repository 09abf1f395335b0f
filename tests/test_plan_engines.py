"""A plan's simulated meshes share their engines and what the eye sees of the map
(`host.planning.prepass.planning`, `EngineCache.sightlines`): the plan is the one made
building everything anew for every simulation, and the shared things are made once."""

import contextlib
import json
import math

import numpy as np
import pytest

import host.planning.plan as plan_module
import meshnode.mesh.claims as claims_module
from host.planning import allowance, prepass
from host.planning.plan import plan_render
from host.planning.request import Auto, Request
from host.scene.nff import read_nff
from meshnode.mesh.engines import EngineCache
from protocols.render import EngineSpec, ImageSpec, MeshPlan
from tests.conftest import spd_scene


def _decisions(report):
    """A plan's report without what a clock measured (CPU seconds, the pre-pass's)."""
    if isinstance(report, dict):
        return {
            k: _decisions(v) for k, v in report.items() if "seconds" not in k and k != "prepass"
        }
    if isinstance(report, list):
        return [_decisions(v) for v in report]
    return report


@pytest.mark.parametrize(
    "name, shape, share", [("balls_s2.nff", (3, 3), 0.25), ("teapot_s1.nff", (2, 2), 0.5)]
)
def test_a_plan_with_shared_engines_is_the_plan_made_without(name, shape, share, monkeypatch):
    # the pre-pass's stages are afforded from measured CPU: all of them, so both plans alike
    monkeypatch.setattr(allowance, "PREPASS_SHARE", math.inf)
    scene = read_nff(spd_scene(name))
    plan = MeshPlan(*shape, 1.0, "objects", "object", "static", max_share=share)
    request = Request(
        scene, ImageSpec(96, 96, spp=2), EngineSpec(threads=1), plan=plan, auto=Auto()
    )
    made = []
    eye_map = claims_module.eye_map
    monkeypatch.setattr(claims_module, "eye_map", lambda *a: made.append(1) or eye_map(*a))
    shared = plan_render(request)
    shared_maps = len(made)
    monkeypatch.setattr(
        plan_module, "planning", lambda nodes: contextlib.nullcontext(prepass.Allowance())
    )
    meshes = []
    simulate = prepass.simulate
    monkeypatch.setattr(prepass, "simulate", lambda *a, **k: meshes.append(1) or simulate(*a, **k))
    alone = plan_render(request)
    assert shared.partition == alone.partition
    assert np.array_equal(shared.holders, alone.holders)
    assert shared.spec == alone.spec
    assert json.dumps(_decisions(shared.balance), default=str) == json.dumps(
        _decisions(alone.balance), default=str
    )
    # the eye's view of a map is made once a simulated mesh (never once a node), and once a
    # plan where its simulations share the map and the cells
    simulations = len(made) - shared_maps
    assert simulations == len(meshes)
    assert 0 < shared_maps < simulations, (shared_maps, simulations)


def test_sightlines_are_made_once_for_every_engine_on_one_map():
    from meshnode.engine import Engine

    scene = read_nff(spd_scene("balls_s1.nff"))
    box = (np.array([-1.0, -1.0, -1.0]), np.array([1.0, 1.0, 1.0]))
    bits = bytes([0b10100101]) * 8  # a 4x4x4 map
    engines = [
        Engine.from_spec(scene, EngineSpec(), box=b, scene_box=box, occupancy=((4, 4, 4), bits))
        for b in (box, (box[0], np.zeros(3)))
    ]
    cache, calls = EngineCache(), []

    def make():
        calls.append(1)
        return object()

    first = cache.sightlines(engines[0], ("eye map", "view", "cells"), make)
    # another engine on the same map and scene box: the same made thing
    assert cache.sightlines(engines[1], ("eye map", "view", "cells"), make) is first
    # other cells, or another map: made again
    assert cache.sightlines(engines[0], ("eye map", "view", "other cells"), make) is not first
    other = Engine.from_spec(
        scene, EngineSpec(), box=box, scene_box=box, occupancy=((4, 4, 4), bytes(8))
    )
    assert cache.sightlines(other, ("eye map", "view", "cells"), make) is not first
    assert len(calls) == 3


def test_boxes_clipped_before_are_not_clipped_again_and_hold_the_same_objects(monkeypatch):
    from host.planning import clip
    from host.scene.derived import scene_tables

    scene = read_nff(spd_scene("gears_s1.nff"))  # triangles and polygons: the edge tests too
    tb = scene_tables(scene)
    lo, hi = tb.lo.min(axis=0), tb.hi.max(axis=0)
    rng = np.random.default_rng(3)
    corners = np.sort(rng.uniform(lo, hi, (2, 6, 3)), axis=0)
    los, his = corners[0], corners[1]
    fresh = clip._clipped(scene, los, his)
    clipped = []
    own = clip._clipped
    monkeypatch.setattr(clip, "_clipped", lambda s, a, b: clipped.append(len(a)) or own(s, a, b))
    first = clip.holders(scene, los[:4], his[:4])
    again = clip.holders(scene, los, his)  # four of six clipped before
    assert clipped == [4, 2]
    assert np.array_equal(first, fresh[:4]) and np.array_equal(again, fresh)
    again[:] = False  # the caller's array: what is kept does not change
    assert np.array_equal(clip.holders(scene, los, his), fresh) and clipped == [4, 2]
    # another scene object (the same file read again) is clipped anew
    clip.holders(read_nff(spd_scene("gears_s1.nff")), los[:1], his[:1])
    assert clipped == [4, 2, 1]


def test_a_plan_makes_each_node_s_scene_once_and_digests_it_once(monkeypatch):
    """Within a plan the same rows of held objects give the same scene objects
    (`prepass.held_scenes`), and the plan's engine cache digests each once
    (`EngineCache(same_scenes=True)`); outside a plan every call makes its own, and a cache
    without `same_scenes` digests every time. The engines are the same either way."""
    import meshnode.mesh.engines as engines_module
    from host.scene.subset import subset
    from protocols.scene import OBJECT_KINDS

    scene = read_nff(spd_scene("balls_s1.nff"))
    objects = sum(len(getattr(scene, kind)) for kind in OBJECT_KINDS)
    keep = np.random.default_rng(5).random((3, objects)) < 0.6  # each node's objects
    outside = prepass.held_scenes(scene, keep)
    assert all(a is not b for a, b in zip(outside, prepass.held_scenes(scene, keep), strict=True))
    digested = []
    digest = engines_module.scene_digest
    monkeypatch.setattr(engines_module, "scene_digest", lambda s: digested.append(1) or digest(s))
    with prepass.planning(3):
        first = prepass.held_scenes(scene, keep)
        again = prepass.held_scenes(scene, keep[::-1])
        assert [id(s) for s in again] == [id(s) for s in first[::-1]]
        cache = prepass._PLANNING.get().engines
        for s in first + again:
            cache.get(s, keep=6)
        assert len(digested) == 3 and cache.built == 3
    for made, row in zip(first, keep, strict=True):
        expected = subset(scene, row)
        assert engines_module.scene_digest(made) == engines_module.scene_digest(expected)
    plain = EngineCache(least=6)
    digested.clear()
    for s in first + again:
        plain.get(s, keep=6)
    assert len(digested) == 6 and plain.built == 3


def test_an_engine_s_key_digests_a_map_by_its_bytes_whichever_object_holds_them():
    from meshnode.mesh.engines import BLOB, BLOBS_KEPT, _engine_key

    bits = bytes(range(256)) * (2 * BLOB // 256)
    blobs: dict = {}
    key = _engine_key(b"scene", {"occupancy": ((4, 4, 4), bits)}, blobs)
    again = bytes(bytearray(bits))  # the same bytes in another object
    assert again is not bits
    assert _engine_key(b"scene", {"occupancy": ((4, 4, 4), again)}, blobs) == key
    assert _engine_key(b"scene", {"occupancy": ((4, 4, 4), bits)}) == key  # no memo: alike
    changed = bytearray(bits)
    changed[-1] ^= 1  # one bit of the map's last voxels
    assert _engine_key(b"scene", {"occupancy": ((4, 4, 4), bytes(changed))}, blobs) != key
    for i in range(2 * BLOBS_KEPT):
        _engine_key(b"scene", {"occupancy": bytes([i]) * BLOB}, blobs)
    assert len(blobs) == BLOBS_KEPT  # the newest kept, each with the bytes it digested
    assert all(id(held) == at for at, (held, _) in blobs.items())
