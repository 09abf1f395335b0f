"""Whole ray trees: the grid gives the same ray counts and the same image as brute force; ray
counts a hand can check; refraction and total internal reflection; scenes moved far from the
origin or scaled tiny and huge give the same image and the same counts."""

import dataclasses
import math

import numpy as np
import pytest

from host.planning.request import Request
from host.run.oneprocess import render
from host.scene.nff import read_nff
from meshnode.engine import Engine
from meshnode.engine.counters import RAY_COUNTS
from meshnode.engine.trace import HINT_SLOTS, hint_slots
from protocols import dtypes
from protocols.scene import View
from tests.conftest import make_scene, records, spd_scene
from tests.test_grid import lit_glass_scene

COUNTS = RAY_COUNTS


def small(scene, **kw):
    settings = records(width=40, height=40, depth=5, threads=1, **kw)
    image, stats = render(Request(scene, *settings))
    return image, {k: stats["rays"][k] for k in COUNTS}


@pytest.mark.parametrize(
    "name",
    [
        "balls_s1.nff",
        "tetra_s2.nff",
        "mount_s1.nff",
        "gears_s1.nff",
        "teapot_s1.nff",
        "rings_s1.nff",
    ],
)
def test_grid_and_bvh_image_and_counts_equal_brute_force(name):
    scene = read_nff(spd_scene(name))
    ref_img, ref_counts = small(scene, brute=True)
    assert ref_counts["eye_hits"] > 0
    configs = [
        {"storage": s, "density": d, "structure": "grid"}
        for s in ("csr", "hash")
        for d in (0.5, 4.0)
    ] + [{"structure": "bvh"}]
    for config in configs:
        img, counts = small(scene, **config)
        assert counts == ref_counts
        np.testing.assert_allclose(img, ref_img, rtol=0, atol=1e-12)


def test_the_shadow_cache_has_a_slot_per_object_and_light_up_to_its_bound():
    """A power of two of slots, so a pair's slot is a mask (pairs share slots past the bound:
    a hint is only tried first, the walk still decides)."""
    assert [hint_slots(n) for n in (0, 1, 5, 8, 9)] == [1, 1, 8, 8, 16]
    assert hint_slots(9345 * 5) == HINT_SLOTS == 1 << 14


def test_random_scene_with_glass_and_lights_equals_brute_force():
    scene = lit_glass_scene(np.random.default_rng(7), n=30)
    ref_img, ref_counts = small(scene, brute=True)
    assert ref_counts["refracted_rays"] > 0 and ref_counts["shadow_rays_blocked"] > 0
    for structure in ("grid", "bvh"):
        img, counts = small(scene, structure=structure)
        assert counts == ref_counts
        np.testing.assert_allclose(img, ref_img, rtol=0, atol=1e-12)


def one_ray(o, d, depth=1):
    ray = np.zeros(1, dtypes.RAY)
    ray["o"], ray["d"] = o, np.asarray(d, float) / np.linalg.norm(d)
    ray["t_max"], ray["origin"], ray["depth"], ray["kind"] = math.inf, -1, depth, dtypes.EYE
    ray["w"] = 1.0
    return ray


def test_counts_of_a_mirror_sphere_by_hand():
    # A reflective sphere, one light behind the eye: every hit faces the light, nothing blocks
    # it, every reflection leaves the scene.
    mirror = ((1.0, 1.0, 1.0), 0.5, 0.5, 10.0, 0.0, 1.0)
    scene = make_scene(spheres=[((0, 0, 0), 1.0, 0)], lights=[(0, 0, -20)], materials=[mirror])
    scene.view = View(eye=(0, 0, -5), at=(0, 0, 0), up=(0, 1, 0), angle=40.0)
    img, counts = small(scene)
    hits = counts["eye_hits"]
    assert 0 < hits < 1600
    expect = {
        "eye_rays": 1600,
        "eye_hits": hits,
        "reflected_rays": hits,
        "refracted_rays": 0,
        "shadow_rays": hits,
        "shadow_rays_blocked": 0,
    }
    assert counts == expect
    # The eye ray through the centre hits head-on: ambient + diffuse + specular, exactly.
    engine = Engine(scene)
    rgb, c = engine.trace(one_ray((0, 0, -5), (0, 0, 1)))
    amb = 0.5  # sqrt(1) / (2 * 1)
    assert rgb[0, 0] == pytest.approx(amb * 0.5 + amb * (0.5 * 1.0 + 0.5 * 1.0), abs=1e-12)
    assert c["shadow_rays"] == 1 and c["reflected_rays"] == 1


GLASS = ((1.0, 1.0, 1.0), 0.0, 0.0, 1.0, 1.0, 1.5)


def test_refraction_follows_snell_and_total_internal_reflection_reflects():
    scene = make_scene(spheres=[((0, 0, 0), 1.0, 0)], materials=[GLASS])
    engine = Engine(scene, max_depth=2)
    # From outside: one refracted and one reflected ray.
    _, c = engine.trace(one_ray((0.3, 0, -5), (0, 0, 1)))
    assert (c["refracted_rays"], c["reflected_rays"]) == (1, 1)
    # From inside at 60 degrees incidence (> asin(1/1.5) = 41.8): total internal reflection,
    # so no refracted ray and the transmitted share goes to the one reflection ray.
    p = np.array([math.sin(math.radians(60)), 0.0, math.cos(math.radians(60))])
    # Start inside, on the chord along +z through p: it meets the normal p at 60 degrees.
    d = np.array([0.0, 0.0, 1.0])
    start = p - 0.5 * d
    assert np.linalg.norm(start) < 1.0
    _, c = engine.trace(one_ray(start, d))
    assert (c["refracted_rays"], c["reflected_rays"]) == (0, 1)
    # Just below the critical angle: refraction again.
    q = np.array([math.sin(math.radians(41)), 0.0, math.cos(math.radians(41))])
    _, c = engine.trace(one_ray(q - 0.5 * d, d))
    assert (c["refracted_rays"], c["reflected_rays"]) == (1, 1)


def test_snell_direction_through_a_glass_slab():
    # A horizontal glass plane: a ray at 45 degrees bends to asin(sin45 / 1.5) below it, and
    # the ray through the slab's underside (a second plane) comes out parallel to itself.
    top = [(-9, 1, -9), (-9, 1, 9), (9, 1, 9), (9, 1, -9)]
    bottom = [(-9, 0, -9), (9, 0, -9), (9, 0, 9), (-9, 0, 9)]
    screen = [(-99, -5, -99), (-99, -5, 99), (99, -5, 99), (99, -5, -99)]
    matte = ((1.0, 1.0, 1.0), 1.0, 0.0, 1.0, 0.0, 1.0)
    scene = make_scene(polygons=[(top, 0), (bottom, 0), (screen, 1)], materials=[GLASS, matte])
    # Geometry by hand: entry at x=0 (y=1), inside angle b = asin(sin45/1.5), exit at
    # x = tan(b), then 5 more units down at 45 degrees.
    b = math.asin(math.sin(math.radians(45)) / 1.5)
    expect_x = math.tan(b) + 5.0
    o = np.array([-2.0, 3.0, 0.0])
    d = np.array([1.0, -1.0, 0.0]) / math.sqrt(2)
    # Trace and locate the screen hit through first_hits along the refracted path.
    e = Engine(scene)
    t1, g1 = e.first_hits([o], [d])
    p1 = o + t1[0] * d
    assert g1[0] == 0 and p1[0] == pytest.approx(0.0, abs=1e-12)
    inside = np.array([math.sin(b), -math.cos(b), 0.0])
    t2, g2 = e.first_hits([p1], [inside], t_min=1e-9)
    p2 = p1 + t2[0] * inside
    assert g2[0] == 1 and p2[0] == pytest.approx(math.tan(b), abs=1e-12)
    t3, g3 = e.first_hits([p2], [d], t_min=1e-9)
    assert g3[0] == 2 and (p2 + t3[0] * d)[0] == pytest.approx(expect_x, abs=1e-12)
    # The tree by hand, depth 5: eye->top (refl, refr), refr->bottom (refl, refr: screen),
    # refl->top from inside at b < 41.8 deg (refl, refr: escapes), refl->bottom (refl, refr),
    # then depth 5 spawns nothing.
    _, c = Engine(scene, max_depth=5).trace(one_ray(o, d))
    assert (c["refracted_rays"], c["reflected_rays"], c["eye_hits"]) == (4, 4, 1)


@pytest.mark.parametrize("incidence", [0.0, 10.0, 30.0, 41.0, 41.9, 60.0, 89.0])
@pytest.mark.parametrize("eta", [1 / 1.5, 1.5])
def test_refract_kernel_obeys_snell(incidence, eta):
    from meshnode.engine.shade import refract

    a = math.radians(incidence)
    d = (math.sin(a), -math.cos(a), 0.0)  # hitting the plane y = 0 from above
    ok, tx, ty, tz = refract(*d, 0.0, 1.0, 0.0, eta)
    s = eta * math.sin(a)  # Snell: sin(out) = (n1 / n2) sin(in)
    assert ok == (s <= 1.0)
    if ok:
        assert tx == pytest.approx(s, abs=1e-12)
        assert ty == pytest.approx(-math.sqrt(1 - s * s), abs=1e-12)
        assert tz == 0.0


def transformed(scene, scale, offset):
    """The same scene with every coordinate mapped x -> x * scale + offset."""
    s = dataclasses.replace(scene)

    def f(x):
        return np.asarray(x) * scale + offset

    v = scene.view
    s.view = dataclasses.replace(v, eye=tuple(f(v.eye)), at=tuple(f(v.at)), hither=v.hither * scale)
    s.lights = scene.lights.copy()
    s.lights["pos"] = f(scene.lights["pos"])
    s.spheres = scene.spheres.copy()
    s.spheres["center"] = f(scene.spheres["center"])
    s.spheres["radius"] *= scale
    s.polygons = scene.polygons.copy()
    s.vertices = f(scene.vertices)
    s.triangles = scene.triangles.copy()
    s.triangles["v"] = f(scene.triangles["v"])
    s.cones = scene.cones.copy()
    for k in ("base", "apex"):
        s.cones[k] = f(scene.cones[k])
    for k in ("base_r", "apex_r"):
        s.cones[k] *= scale
    return s


@pytest.mark.parametrize(
    "scale,offset",
    [(1.0, 1e6), (1e-4, 0.0), (1e4, 0.0), (1e-4, 3.0)],
)
def test_far_tiny_and_huge_scenes_render_the_same(scale, offset):
    scene = read_nff(spd_scene("balls_s2.nff"))
    base_img, base_counts = small(scene)
    img, counts = small(transformed(scene, scale, offset))
    assert counts == base_counts
    np.testing.assert_allclose(img, base_img, rtol=0, atol=1e-6)


def test_rays_of_extreme_finite_numbers_end_on_every_kernel_path():
    # What a peer can send (finite, so it passes the RAYS checks) and what a scene near the
    # float64 limits makes: origins and directions from 1e-300 to 1e300, unnormalised, spans
    # from 0 to 1e308. Overflowing arithmetic (inf - inf = NaN) must not keep a ray walking:
    # every kernel loop is bounded, so each batch comes back, on one node and as a mesh node.
    rng = np.random.default_rng(5)
    scene = lit_glass_scene(rng, n=30)
    values = np.array([0.0, 1e-300, -1e-300, 1e-150, 0.5, -2.0, 1e150, -1e150, 1e300, -1e300])
    n = 2000
    rays = np.zeros(n, dtypes.RAY)
    rays["o"] = rng.choice(values, (n, 3))
    rays["d"] = rng.choice(values, (n, 3))
    rays["d"][np.all(rays["d"] == 0, axis=1)] = (0.0, 0.0, 1.0)
    rays["t_min"] = rng.choice([0.0, 1e-300, 1.0, 1e300], n)
    rays["t_max"] = rng.choice([math.inf, 1e308, 1.0], n)
    rays["w"], rays["origin"], rays["kind"] = 1.0, -1, rng.integers(0, 4, n)
    rays["depth"] = rng.integers(1, 6, n)
    for brute in (False, True):
        engine = Engine(scene, brute=brute)
        rgb, counts = engine.trace(rays)
        assert counts["eye_rays"] + counts["reflected_rays"] + counts["refracted_rays"] >= 0
        # a node holding half the scene runs the mesh kernel (spans, passing); a node whose
        # box is the scene's the one-node kernel, and passes nothing
        lo, hi = engine.scene_lo, engine.scene_hi
        half = Engine(scene, brute=brute, box=(lo, (lo + hi) / 2), scene_box=(lo, hi))
        assert half.holds_scene is False and engine.holds_scene is True
        _, _, passed = half.trace_node(rays)
        assert len(rgb) == n and passed is not None
        assert len(engine.trace_node(rays)[2]) == 0


def test_teapot_patches_render_without_isolated_dark_pixels():
    # teapot_s1's spout is two sheets of smooth triangles in one plane with shading normals
    # in that plane: eye rays were won by round-off, sheet by sheet, and their mirror
    # directions pointed into the surface. Coincident hits now go to the lower gid and a
    # mirror direction below the face is mirrored back above it. A pixel much darker than
    # all eight neighbours (below 70% of the darkest, in linear light) is such a speckle:
    # there were 12 at 256x256, now none.
    scene = read_nff(spd_scene("teapot_s1.nff"))
    img, _ = render(Request(scene, *records(width=256, height=256)))
    lum = img @ np.array([0.2126, 0.7152, 0.0722])
    h, w = lum.shape
    around = np.stack(
        [
            lum[1 + dy : h - 1 + dy, 1 + dx : w - 1 + dx]
            for dy in (-1, 0, 1)
            for dx in (-1, 0, 1)
            if dy or dx
        ]
    )
    speckles = lum[1:-1, 1:-1] < 0.7 * around.min(axis=0)
    assert int(speckles.sum()) == 0
