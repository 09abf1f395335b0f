"""The SPD scenes at their default size give the ray counts of the databases' author's published
table (scenes README: 513x513 corner rays, depth 5) within 0.1%, teapot within 0.5%: the
independent reference for the whole tracer (camera, intersections, shading rules, counting).
The table counts a hit on a transmitter that reflects totally as a refracted ray (gears: -3.7%
without, -0.01% with): a glass prism whose ray trees a hand can count pins that rule."""

import numpy as np
import pytest

from bench.spd_published import PUBLISHED_TOLERANCE, TOLERANCE, parse_published
from host.planning.request import Request
from host.run.oneprocess import render
from host.run.summary import summary_line
from host.scene.nff import read_nff
from meshnode.engine.counters import spd_counts
from protocols.render import EngineSpec, ImageSpec
from protocols.scene import View
from tests.conftest import make_scene, records, spd_readme, spd_scene


@pytest.mark.parametrize("name", ["balls", "gears", "rings", "teapot", "tetra", "tree"])
def test_default_scene_counts_match_the_published_table(name):
    scene = read_nff(spd_scene(f"{name}.nff"))
    published = parse_published(spd_readme().read_text())[name]
    _, stats = render(Request(scene, ImageSpec(spd=True), EngineSpec()))
    ours = spd_counts(stats["rays"])
    tolerance = PUBLISHED_TOLERANCE.get(name, TOLERANCE)
    for key, n in published.items():
        assert abs(ours[key] - n) <= tolerance * max(n, 1), (key, ours[key], n)


def porro_prism(length=2.0):
    """A right-angled glass prism along z, open at its ends: the hypotenuse face in y = 0 for x
    in [-1, 1], the right angle at (0, -1), each face's normal (its first three vertices,
    counter-clockwise) outward; glass as gears' (T 0.8, Ks 0), index 1.5 (critical angle
    41.8 degrees). The eye looks straight down onto x in [0.24, 0.76] of the hypotenuse."""
    z = length
    faces = [
        [(-1, 0, -z), (-1, 0, z), (1, 0, z), (1, 0, -z)],  # hypotenuse, normal +y
        [(0, -1, -z), (1, 0, -z), (1, 0, z), (0, -1, z)],  # leg at x > 0, normal (1, -1, 0)
        [(-1, 0, -z), (0, -1, -z), (0, -1, z), (-1, 0, z)],  # leg at x < 0, normal (-1, -1, 0)
    ]
    for f in faces:  # outward: away from the cross-section's centre (0, -1/3)
        v = np.asarray(f, float)
        assert np.cross(v[1] - v[0], v[2] - v[0]) @ (v.mean(axis=0) - (0, -1 / 3, 0)) > 0
    glass = ((1.0, 1.0, 1.0), 0.2, 0.0, 1.0, 0.8, 1.5)
    view = View(eye=(0.5, 10.0, 0.0), at=(0.5, 0.0, 0.0), up=(0.0, 0.0, 1.0), angle=3.0)
    return make_scene(polygons=[(f, 0) for f in faces], materials=[glass], view=view)


def test_a_total_internal_reflection_counts_as_a_refracted_ray_as_the_spd_author_counted():
    # Every eye ray (9x9 corner rays, within 1.5 degrees of straight down) has one tree,
    # counted by hand: depth 1 enters the hypotenuse (a reflected ray, which escapes, and a
    # refracted one); 2 meets a leg at 45 degrees (past the critical angle: totally
    # reflected, no refracted ray); 3 the other leg at 45 degrees, likewise; 4 the hypotenuse
    # from inside head-on (a refracted ray, which escapes upward, and a reflected one); 5 a
    # leg, at the depth limit: nothing spawned. No lights, so no shadow rays.
    n = 9 * 9
    _, stats = render(Request(porro_prism(), *records(spd=True, width=8, height=8, threads=1)))
    r = stats["rays"]
    assert (r["eye_rays"], r["eye_hits"], r["shadow_rays"]) == (n, n, 0)
    assert (r["reflected_rays"], r["refracted_rays"]) == (4 * n, 2 * n)  # traced
    assert (r["hits"], r["escaped"]) == (5 * n, 2 * n)  # a total reflection traces no more
    assert r["internal_reflections"] == 2 * n
    # The SPD author's count: a refracted ray at every transmitter hit below the depth limit,
    # totally reflected or not (4n). The rules it is told from: rays actually traced (2n),
    # rays entering only (n), rays also counted at the depth limit (5n).
    assert stats["spd_counts"] == {
        "eye_hits": n,
        "reflected_rays": 4 * n,
        "refracted_rays": 4 * n,
        "shadow_rays": 0,
    }
    assert stats["spd_counts"] == spd_counts(r)
    line = summary_line("prism.png", stats)
    assert f"refracted {2 * n} (SPD {4 * n}: +{2 * n} total internal reflections)" in line
