"""Convex planar quads traced as triangle pairs (`meshnode.engine.quads`): first hits against
the quad's plane and edges (numpy) on rays all over and around them, their gid kept; warped,
concave or larger polygons stay polygons."""

import numpy as np

from meshnode.engine import Engine
from meshnode.engine.quads import quads_as_triangles
from protocols import dtypes
from protocols.scene import SceneData, View


def _scene(polygons) -> SceneData:
    """A scene of polygons (each a list of vertices), gid = index, material 0."""
    scene = SceneData(view=View((0, 0, -5), (0, 0, 0), (0, 1, 0), 45.0))
    scene.materials = np.array([((0.8, 0.8, 0.8), 0.8, 0.0, 1.0, 0.0, 1.0)], dtypes.MATERIAL)
    poly = np.zeros(len(polygons), dtypes.POLYGON)
    poly["gid"] = np.arange(len(polygons))
    poly["count"] = [len(q) for q in polygons]
    poly["start"] = np.cumsum(poly["count"]) - poly["count"]
    scene.polygons = poly
    scene.vertices = np.concatenate([np.asarray(q, float) for q in polygons])
    return scene


def test_convex_quads_become_triangle_pairs_and_others_stay():
    square = [(0, 0, 0), (1, 0, 0), (1, 1, 0), (0, 1, 0)]
    tilted = [(2, 0, 0), (3.5, 0.2, 0.5), (3.2, 1.4, 1.0)]
    tilted.append(tuple(np.asarray(tilted[0]) + np.asarray(tilted[2]) - np.asarray(tilted[1])))
    dart = [(0, 2, 0), (1, 2.2, 0), (0.3, 2.4, 0), (0.5, 3.2, 0)]  # concave
    pent = [(2, 2, 0), (3, 2, 0), (3.3, 2.8, 0), (2.5, 3.3, 0), (1.8, 2.8, 0)]
    warped = [(0, 4, 0), (2, 4, 0), (2, 6, 1.5), (0, 6, 0)]
    out = quads_as_triangles(_scene([square, tilted, dart, pent, warped]))
    assert list(out.polygons["gid"]) == [2, 3, 4]
    assert list(out.triangles["gid"]) == [0, 0, 1, 1] and (out.triangles["smooth"] == 0).all()


def test_a_quad_as_triangles_hits_where_its_plane_and_edges_say():
    """Rays within 1e-9 of an edge or the diagonal are left out (either answer is right)."""
    rng = np.random.default_rng(2)
    square = [(0, 0, 0), (1, 0, 0), (1, 1, 0), (0, 1, 0)]
    tilted = [(2, 0, 0), (3.5, 0.2, 0.5), (3.2, 1.4, 1.0)]
    tilted.append(tuple(np.asarray(tilted[0]) + np.asarray(tilted[2]) - np.asarray(tilted[1])))
    for quad in (square, tilted):
        q = np.asarray(quad, float)
        lo, hi = q.min(axis=0) - 0.3, q.max(axis=0) + 0.3
        targets = lo + rng.random((4000, 3)) * (hi - lo)
        normal = np.cross(q[1] - q[0], q[3] - q[0])
        normal /= np.linalg.norm(normal)
        targets -= np.outer((targets - q[0]) @ normal, normal)  # onto the quad's plane
        origins = targets + normal * 4 + rng.normal(size=(4000, 3)) * 0.5
        d = targets - origins
        engine = Engine(_scene([quad]), structure="bvh")
        assert engine.tables.polygons is None  # traced as triangles
        t, ids = engine.first_hits(origins, d)
        d /= np.linalg.norm(d, axis=1)[:, None]
        t_ref = ((q[0] - origins) @ normal) / (d @ normal)
        p = origins + t_ref[:, None] * d
        sides = [np.cross(q[(k + 1) % 4] - q[k], p - q[k]) @ normal for k in range(4)]
        diagonal = np.cross(q[2] - q[0], p - q[0]) @ normal
        inside = np.all(np.stack(sides) > 0, axis=0)
        clear = np.min(np.abs(np.stack([*sides, diagonal])), axis=0) > 1e-9
        assert np.array_equal(ids[clear] == 0, inside[clear])
        assert 500 < inside.sum() < 3500  # hits and misses both tried
        np.testing.assert_allclose(t[clear & inside], t_ref[clear & inside], rtol=1e-9)
