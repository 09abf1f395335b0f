"""Analytic first hits for every primitive kind, through the engine's public first_hits."""

import math

import numpy as np
import pytest

from meshnode.engine import Engine
from meshnode.engine.intersect import hit_polygon
from meshnode.engine.tables import POLY_IN2, POLY_OUT2, build_tables
from tests.conftest import make_scene

GLASS = ((1.0, 1.0, 1.0), 0.0, 0.1, 10.0, 0.9, 1.5)
MATTE = ((1.0, 1.0, 1.0), 1.0, 0.0, 1.0, 0.0, 1.0)


def hits(scene, o, d, **kw):
    return Engine(scene, **kw).first_hits(np.atleast_2d(o), np.atleast_2d(d))


def test_sphere_outside_inside_and_two_sided():
    c, r = np.array([1.0, 2.0, 3.0]), 0.5
    scene = make_scene(spheres=[(c, r, 0)])
    t, g = hits(scene, c - [0, 0, 5], [0, 0, 1])
    assert t[0] == pytest.approx(4.5, abs=1e-12) and g[0] == 0
    # From inside, a positive radius shows nothing (only the outside is visible).
    t, g = hits(scene, c, [0, 0, 1])
    assert g[0] == -1 and math.isinf(t[0])
    # Negative radius: only the inside is visible, from outside the far wall is seen.
    inside = make_scene(spheres=[(c, -r, 0)])
    t, g = hits(inside, c, [0, 0, 1])
    assert t[0] == pytest.approx(0.5, abs=1e-12) and g[0] == 0
    t, g = hits(inside, c - [0, 0, 5], [0, 0, 1])
    assert t[0] == pytest.approx(5.5, abs=1e-12)
    # Transmitters are two-sided.
    glass = make_scene(spheres=[(c, r, 0)], materials=[GLASS])
    t, g = hits(glass, c, [0, 0, 1])
    assert t[0] == pytest.approx(0.5, abs=1e-12)


def test_sphere_off_axis_distance_matches_geometry():
    scene = make_scene(spheres=[((0, 0, 0), 1.0, 0)])
    ys = np.linspace(-0.99, 0.99, 41)
    o = np.column_stack([np.zeros_like(ys), ys, np.full_like(ys, -5.0)])
    t, g = hits(scene, o, np.tile([0, 0, 1.0], (len(ys), 1)))
    np.testing.assert_allclose(t, 5.0 - np.sqrt(1 - ys**2), rtol=0, atol=1e-12)
    assert (g == 0).all()


def test_triangle_barycentric_inside_outside_and_both_sides():
    tri = ((0, 0, 0), (1, 0, 0), (0, 1, 0), 0)
    scene = make_scene(triangles=[tri])
    pts = np.array([[0.2, 0.2], [0.49, 0.49], [0.6, 0.6], [-0.01, 0.5], [0.5, -0.01]])
    o = np.column_stack([pts, np.full(len(pts), -2.0)])
    t, g = hits(scene, o, np.tile([0, 0, 1.0], (len(pts), 1)))
    assert g.tolist() == [0, 0, -1, -1, -1]
    assert t[0] == pytest.approx(2.0, abs=1e-14)
    # Polygons are opaque from both sides: from behind the same hit.
    t, g = hits(scene, [0.2, 0.2, 3.0], [0, 0, -1])
    assert g[0] == 0 and t[0] == pytest.approx(3.0, abs=1e-14)


def test_concave_polygon_notch_is_empty():
    # L shape: the square [1,2]x[1,2] is the notch.
    L = [(0, 0, 0), (2, 0, 0), (2, 1, 0), (1, 1, 0), (1, 2, 0), (0, 2, 0)]
    scene = make_scene(polygons=[(L, 0)])
    pts = np.array([[0.5, 0.5], [1.5, 0.5], [0.5, 1.5], [1.5, 1.5], [1.01, 1.01], [0.99, 0.99]])
    o = np.column_stack([pts, np.full(len(pts), 1.0)])
    t, g = hits(scene, o, np.tile([0, 0, -1.0], (len(pts), 1)))
    assert g.tolist() == [0, 0, 0, -1, -1, 0]


def test_144_vertex_gear_face():
    # A gear outline like SPD gears: 36 teeth, 4 vertices each, tips at radius 1, roots at 0.9.
    ang = np.linspace(0, 2 * np.pi, 145)[:-1]
    radius = np.where((np.arange(144) // 2) % 2 == 0, 1.0, 0.9)
    verts = np.column_stack([radius * np.cos(ang), radius * np.sin(ang), np.zeros(144)])
    scene = make_scene(polygons=[(verts, 0)])
    step = ang[1]
    probe = {
        0.5 * step: 0.95,  # inside a tooth (between tip vertices 0 and 1)
        2.5 * step: 0.95,  # in the gap between teeth (root vertices 2 and 3)
        2.5 * step + 1e-9: 0.85,  # below the root circle: solid
    }
    o = np.array([[r * np.cos(a), r * np.sin(a), 1.0] for a, r in probe.items()])
    t, g = hits(scene, o, np.tile([0, 0, -1.0], (3, 1)))
    assert g.tolist() == [0, -1, 0]


def test_banded_crossing_test_agrees_with_every_edge_on_random_polygons():
    """Polygons of 12-300 vertices (stars, and self-crossing random walks) answer exactly as
    the every-edge crossing test, on random points and on points level with a vertex, the
    lowest and the highest vertex (where half-open edges decide)."""
    rng = np.random.default_rng(7)
    shapes = []
    for k in range(24):
        n = int(rng.integers(12, 301))
        ang = np.sort(rng.uniform(0, 2 * np.pi, n))
        if k % 2:  # a star
            r = rng.uniform(0.3, 1.0, n)
            xy = np.column_stack([r * np.cos(ang), r * np.sin(ang)])
        else:  # a closed random walk: crosses itself, short edges
            xy = np.cumsum(rng.normal(0.0, 1.0, (n, 2)), axis=0)
            xy = 2.0 * (xy - xy.min(axis=0)) / np.ptp(xy, axis=0) - 1.0
        shapes.append((np.column_stack([xy, np.zeros(n)]), 0))
    tb = build_tables(make_scene(polygons=shapes))
    info = tb.poly_info
    assert (info[:, 5] > 0).sum() >= 18  # most have bands (some walks are combs: none)
    plain = info.copy()
    plain[:, 5] = 0
    for i, (verts, _) in enumerate(shapes):
        y = verts[:, 1]
        level = np.concatenate([y, [y.min(), y.max()], rng.uniform(-1.1, 1.1, 300)])
        px = rng.uniform(-1.1, 1.1, len(level))
        for qx, qy in zip(px, level, strict=True):
            args = (i, qx, qy, 1.0, 0.0, 0.0, -1.0, 0.0, np.inf)
            banded = hit_polygon(tb.polygons, info, tb.poly_uv, tb.poly_bands, *args)
            every = hit_polygon(tb.polygons, plain, tb.poly_uv, tb.poly_bands, *args)
            assert banded == every or (np.isinf(banded) and np.isinf(every)), (i, qx, qy)


def test_polygon_discs_answer_as_the_crossing_test():
    """A polygon's inner disc (a hit) and outer disc (a miss beyond it) decide exactly what the
    crossing test decides, on random points and on points just inside and outside either
    circle: gear faces, stars, C shapes (centre outside: no inner disc), quads, a tiny and a
    far-off polygon, and self-crossing random walks."""
    rng = np.random.default_rng(11)
    ang = np.linspace(0, 2 * np.pi, 145)[:-1]
    gear = np.where((np.arange(144) // 2) % 2 == 0, 1.0, 0.9)
    shapes = [np.column_stack([gear * np.cos(ang), gear * np.sin(ang)])]
    c_ang = np.linspace(0.3, 2 * np.pi - 0.3, 40)
    shapes.append(
        np.vstack(
            [
                np.column_stack([np.cos(c_ang), np.sin(c_ang)]),
                0.5 * np.column_stack([np.cos(c_ang[::-1]), np.sin(c_ang[::-1])]),
            ]
        )
    )
    shapes.append(np.array([[0.0, 0.0], [2.0, 0.0], [2.0, 0.1], [0.0, 0.1]]))  # a strip
    shapes.append(np.array([[0.0, 0.0], [1.0, 0.0], [0.2, 0.2], [0.0, 1.0]]))  # a dart
    shapes.append(np.array([[0.0, 0.0], [3.0, 1.0], [3.0, 0.0], [0.0, 2.0]]))  # a bowtie
    shapes.append(1e-6 * np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]]))
    shapes.append(1e6 + np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]]))
    for k in range(12):
        n = int(rng.integers(5, 200))
        a = np.sort(rng.uniform(0, 2 * np.pi, n))
        if k % 2:
            r = rng.uniform(0.3, 1.0, n)
            shapes.append(np.column_stack([r * np.cos(a), r * np.sin(a)]))
        else:
            shapes.append(np.cumsum(rng.normal(0.0, 1.0, (n, 2)), axis=0))
    polys = [(np.column_stack([xy, np.zeros(len(xy))]), 0) for xy in shapes]
    tb = build_tables(make_scene(polygons=polys))
    assert (tb.polygons[:, POLY_IN2] > 0).sum() >= 8  # most have an inner disc
    assert tb.polygons[1, POLY_IN2] < 0  # the C's centre lies in its gap
    plain = tb.polygons.copy()
    plain[:, POLY_IN2], plain[:, POLY_OUT2] = -1.0, np.inf
    for i, xy in enumerate(shapes):
        lo, hi = xy.min(axis=0), xy.max(axis=0)
        size = np.max(hi - lo)
        pts = [rng.uniform(lo - 0.1 * size, hi + 0.1 * size, (400, 2))]
        centre = xy.mean(axis=0)
        for r2 in tb.polygons[i, POLY_IN2 : POLY_OUT2 + 1]:
            if r2 > 0:  # on either side of each circle
                a = rng.uniform(0, 2 * np.pi, 100)
                r = np.sqrt(r2) * (1.0 + rng.choice([-1e-6, -1e-12, 1e-12, 1e-6], 100))
                pts.append(centre + np.column_stack([r * np.cos(a), r * np.sin(a)]))
        for qx, qy in np.vstack(pts):
            args = (i, qx, qy, 1.0, 0.0, 0.0, -1.0, 0.0, np.inf)
            fast = hit_polygon(tb.polygons, tb.poly_info, tb.poly_uv, tb.poly_bands, *args)
            slow = hit_polygon(plain, tb.poly_info, tb.poly_uv, tb.poly_bands, *args)
            assert fast == slow or (np.isinf(fast) and np.isinf(slow)), (i, qx, qy)


def test_a_zigzag_of_tall_edges_keeps_the_every_edge_test_and_a_small_table():
    """Every band would list every edge of a comb (teeth reaching from bottom to top): such a
    polygon gets no bands, so its table does not grow as vertices x bands, and it still hits
    as the every-edge test says (inside a tooth, in a gap)."""
    n = 400  # 200 teeth
    x = np.repeat(np.arange(n // 2, dtype=float), 2)
    y = np.tile([0.0, 1.0, 1.0, 0.0], n // 4)
    comb = np.column_stack([x, y, np.zeros(n)])
    base = [(n / 2, 0.0, 0.0), (n / 2, -1.0, 0.0), (0.0, -1.0, 0.0)]
    scene = make_scene(polygons=[(np.vstack([comb, base]), 0)])
    tb = build_tables(scene)
    assert tb.poly_info[0, 5] == 0 and len(tb.poly_bands) == 0  # every edge, no table
    pts = np.array([[0.5, 0.5], [1.5, 0.5], [10.5, -0.5], [2.5, 0.5]])
    o = np.column_stack([pts, np.ones(len(pts))])
    t, g = hits(scene, o, np.tile([0, 0, -1.0], (len(pts), 1)))
    assert g.tolist() == [0, -1, 0, 0]


def test_cylinder_and_cone_analytic():
    cyl = make_scene(cones=[((0, 0, 0), 1.0, (0, 0, 4), 1.0, 0)])
    t, g = hits(cyl, [-5, 0, 2], [1, 0, 0])
    assert g[0] == 0 and t[0] == pytest.approx(4.0, abs=1e-12)
    # Open: along the axis from outside the caps nothing is hit; from inside nothing visible.
    t, g = hits(cyl, [0, 0, -3], [0, 0, 1])
    assert g[0] == -1
    t, g = hits(cyl, [0, 0, 2], [1, 0, 0])
    assert g[0] == -1
    # Negative radii: inside visible.
    inner = make_scene(cones=[((0, 0, 0), -1.0, (0, 0, 4), -1.0, 0)])
    t, g = hits(inner, [0, 0, 2], [1, 0, 0])
    assert g[0] == 0 and t[0] == pytest.approx(1.0, abs=1e-12)
    # Cone radius 1 at z=0 to 0.5 at z=2: at height z the radius is 1 - z/4.
    cone = make_scene(cones=[((0, 0, 0), 1.0, (0, 0, 2), 0.5, 0)])
    for z in (0.1, 1.0, 1.9):
        t, g = hits(cone, [-5, 0, z], [1, 0, 0])
        assert g[0] == 0 and t[0] == pytest.approx(5 - (1 - z / 4), abs=1e-12)
    # Beyond the ends nothing.
    t, g = hits(cone, [-5, 0, 2.1], [1, 0, 0])
    assert g[0] == -1


def test_first_hits_rejects_bad_rays():
    scene = make_scene(spheres=[((0, 0, 0), 1.0, 0)])
    e = Engine(scene)
    with pytest.raises(ValueError):
        e.first_hits([[0, 0, 0]], [[0, 0, 0]])
    with pytest.raises(ValueError):
        e.first_hits([[0, 0, 0], [1, 1, 1]], [[0, 0, 1]])


def test_an_empty_node_misses_everything():
    # A mesh node whose box holds no object still traces (and passes) rays.
    scene = make_scene(spheres=[((0, 0, 0), 1.0, 0)])
    scene.spheres = scene.spheres[:0]
    t, g = hits(scene, [0, 0, -5], [0, 0, 1])
    assert g[0] == -1 and math.isinf(t[0])
