"""The inner occupancy map: where a scene's small objects lie in a box far smaller than the
scene's (balls' sphereflake on its floor), a second map there. A walk of both misses no hit
(brute force), ends rays the scene's map alone sends on, and a mesh with it renders the one
node's image and counts; the partition checks the inner map's wire form."""

import dataclasses
import math

import numpy as np
import pytest

from host.planning.cells import scene_box
from host.planning.occupancy import inner_map, occupancy_map
from host.planning.partition import partition
from host.scene.nff import read_nff
from meshnode.engine import Engine
from meshnode.engine.counters import N_COUNTERS
from meshnode.engine.mapwalk import first_occupied
from meshnode.engine.occupancy import occupancy_arrays
from meshnode.engine.traverse import box_span
from protocols.partition import Partition
from protocols.render import ImageSpec, MeshPlan, RenderSpec
from protocols.spec import SpecError
from tests.conftest import spd_scene
from tests.meshsim import render_mesh
from tests.test_mesh_algorithm import SPD_COUNTS


def _maps(name):
    scene = read_nff(spd_scene(name))
    lo, hi = scene_box(scene)
    return scene, lo, hi, occupancy_map(scene, (lo, hi)), inner_map(scene, (lo, hi))


def test_a_floor_under_small_objects_gives_an_inner_map_and_a_fractal_none():
    _, lo, hi, _, inner = _maps("balls_s1.nff")
    i_lo, i_hi = inner[:2]
    assert np.all(lo <= i_lo) and np.all(i_hi <= hi)
    assert np.prod(i_hi - i_lo) < np.prod(hi - lo) / 8  # the flake, not the floor
    assert _maps("tetra_s3.nff")[4] is None  # its objects fill its box


@pytest.mark.parametrize("name", ["balls_s1.nff"])
def test_the_walk_of_both_maps_misses_no_hit_and_ends_more_rays(name):
    """Rays from random points in random directions: with the inner map the first occupied
    voxel still comes no later than the first hit (brute force), a ray told nothing lies
    ahead hits nothing, and more rays are told so than by the scene's map alone."""
    scene, lo, hi, outer, inner = _maps(name)
    assert inner is not None
    both = occupancy_arrays(lo, hi, *outer, inner=inner)
    alone = occupancy_arrays(lo, hi, *outer)
    i_lo, i_hi = inner[:2]
    rng = np.random.default_rng(3)
    n = 3000
    # half from inside the inner box, half from anywhere in the scene's
    origins = np.where(
        (np.arange(n) < n // 2)[:, None],
        i_lo + rng.random((n, 3)) * (i_hi - i_lo),
        lo + rng.random((n, 3)) * (hi - lo),
    )
    dirs = rng.normal(size=(n, 3))
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    t_hit, _ = Engine(scene, brute=True).first_hits(origins, dirs)
    counters = np.zeros(N_COUNTERS, np.int64)
    clear = {"both": 0, "alone": 0}
    for o, d, th in zip(origins, dirs, t_hit, strict=True):
        r = [1.0 / v if v != 0.0 else math.inf for v in d]
        t0, t1 = box_span(*o, *r, 0.0, math.inf, *lo, *hi)
        for label, occ in (("both", both), ("alone", alone)):
            t = first_occupied(*o, *d, *r, t0, t1, *occ, counters)
            assert t <= th, (name, label, o, d, t, th)
            clear[label] += t == math.inf
    assert clear["both"] > clear["alone"], clear


def test_a_mesh_with_an_inner_map_renders_the_one_nodes_image_and_counts():
    scene = read_nff(spd_scene("balls_s1.nff"))
    spec = RenderSpec(
        ImageSpec(width=32, height=32, spp=2).sized(scene.view), plan=MeshPlan(2, 2, 1)
    )
    assert partition(scene, spec)[0].inner_res  # the mesh below walks an inner map
    img, totals, _, _ = render_mesh(scene, 2, 2, 1, 32, 32, spp=2)
    ref, ref_totals, _, _ = render_mesh(scene, 1, 1, 0, 32, 32, spp=2)
    np.testing.assert_allclose(img, ref, rtol=0, atol=1e-12)
    for k in (*SPD_COUNTS, "hits", "escaped", "shadow_rays_lit"):
        assert totals[k] == ref_totals[k], k


def test_a_partition_checks_its_inner_map():
    base = dict(
        rects=[(0, 4, 0, 4)],
        los=[(0, 0, 0)],
        his=[(1, 1, 1)],
        scene_box=((0, 0, 0), (1, 1, 1)),
        occupancy=((4, 4, 2), bytes(4)),
    )
    inner = ((0.25, 0.25, 0.0), (0.75, 0.75, 0.5), (2, 2, 2), bytes([0b10000000]), b"")
    part = Partition.make(**base, inner=inner)
    again = Partition.from_wire(part.to_wire())
    assert again.inner == part.inner and again.inner_res == (2, 2, 2)
    with pytest.raises(SpecError, match="inner_bits is 2 bytes: must be 1 bytes"):
        Partition.make(**base, inner=(*inner[:3], bytes(2), b""))
    with pytest.raises(SpecError, match="inner_hi"):  # past the scene's box
        Partition.make(**base, inner=(inner[0], (0.75, 0.75, 1.5), *inner[2:]))
    with pytest.raises(SpecError, match="inner_fine"):  # masks the outer map has not
        Partition.make(**base, inner=(*inner[:4], bytes(8)))
    with pytest.raises(SpecError, match="inner_res"):  # a box with no map
        dataclasses.replace(part, inner_res=(), inner_bits=b"").check()


def test_the_eyes_and_the_lights_bounds_on_both_maps_miss_no_hit():
    """Balls with its inner map: no eye ray hits an object nearer than its block's bound, no
    segment a light's map calls clear meets an object (brute force), and both bounds reach
    farther than on the scene's map alone."""
    from meshnode.engine.camera import eye_rays
    from meshnode.engine.lightmaps import light_clear, light_maps
    from meshnode.engine.sightlines import eye_map
    from tests.test_sightlines import _bound, _views

    scene, lo, hi, outer, inner = _maps("balls_s1.nff")
    both = occupancy_arrays(lo, hi, *outer, inner=inner)
    alone = occupancy_arrays(lo, hi, *outer)
    engine = Engine(scene, brute=True)
    rng = np.random.default_rng(11)
    farther = nearer = 0
    for view in _views(scene, lo, hi):
        image = ImageSpec(width=40, height=30, spp=2)
        rays = eye_rays(view, image)
        rays = rays[rng.choice(len(rays), 400, replace=False)]
        bound, before = (_bound(eye_map(m, view, image)[0], rays) for m in (both, alone))
        t_hit, _ = engine.first_hits(rays["o"], rays["d"])
        assert (t_hit >= bound * np.linalg.norm(rays["d"], axis=1)).all(), view
        farther += int((bound > before).sum())
        nearer += int((bound < before).sum())
    assert farther > 100 and farther > 10 * nearer, (farther, nearer)
    points = np.vstack([scene.lights["pos"], lo + rng.random((2, 3)) * (hi - lo)])
    maps = {label: light_maps(m, points) for label, m in (("both", both), ("alone", alone))}
    assert (maps["both"] > maps["alone"]).sum() > 10 * (maps["both"] < maps["alone"]).sum()
    told = {"both": 0, "alone": 0}
    i_lo, i_hi = inner[:2]
    for li, light in enumerate(points):
        ends = np.vstack(  # half of them among the small objects
            [lo + rng.random((100, 3)) * (hi - lo), i_lo + rng.random((100, 3)) * (i_hi - i_lo)]
        )
        for label, m in maps.items():
            clear = np.array([light_clear(m, li, *light, *x) for x in ends])
            told[label] += int(clear.sum())
            if clear.any():
                d = light - ends[clear]
                hit = engine.occluded(ends[clear], d, np.linalg.norm(d, axis=1))
                assert not hit.any(), (label, light)
    assert told["both"] > told["alone"], told
