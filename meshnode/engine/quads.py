"""Convex planar quadrilaterals traced as two triangles.

A polygon is tested by its plane and an even-odd crossing test in 2-D (`intersect.hit_polygon`),
one at a time; triangles four at a time in a leaf (`leaves`). A convex planar quad is the same
surface as the triangles (v0, v1, v2) and (v0, v2, v3) with its gid and material, its normal
the same way round, so an engine traces such quads as triangles (teapot's 36 floor quads:
its first hits 0.94-0.96 of Embree's rate as polygons, 1.08-1.28 as triangle pairs, in
turns). Warped or concave quads, and polygons of more vertices (gears' outlines), stay
polygons. The host's tables keep the scene's rows: this is the engine's own choice.
"""

from dataclasses import replace

import numpy as np

from protocols import dtypes
from protocols.scene import SceneData

FLAT = 1e-12  # of the quad's size: the fourth vertex's distance from the first three's plane


def quads_as_triangles(scene: SceneData) -> SceneData:
    """`scene` with its convex planar four-vertex polygons moved to the triangle table (flat,
    two rows a quad sharing its gid), the triangles kept in gid order; the scene itself when
    it has none."""
    polys = scene.polygons
    if not len(polys):
        return scene
    quad = polys["count"] == 4
    starts = polys["start"][quad].astype(np.int64)
    v = scene.vertices[starts[:, None] + np.arange(4)]  # (quads, 4, 3)
    convex = _convex(v)
    if not convex.any():
        return scene
    which = np.flatnonzero(quad)[convex]
    v = v[convex]
    tri = np.zeros(2 * len(which), dtypes.TRIANGLE)
    tri["gid"] = np.repeat(polys["gid"][which], 2)
    tri["mat"] = np.repeat(polys["mat"][which], 2)
    tri["v"][0::2] = v[:, [0, 1, 2]]
    tri["v"][1::2] = v[:, [0, 2, 3]]
    triangles = np.concatenate([scene.triangles, tri])
    triangles = triangles[np.argsort(triangles["gid"], kind="stable")]
    keep = np.ones(len(polys), bool)
    keep[which] = False
    return replace(scene, triangles=triangles, polygons=polys[keep])


def _convex(v: np.ndarray) -> np.ndarray:
    """Per quad (v: quads x 4 x 3) whether it is planar and strictly convex: every corner
    turns the same way about its normal, none straight or folded back."""
    edges = np.roll(v, -1, axis=1) - v
    turns = np.cross(edges, np.roll(edges, -1, axis=1))  # at corners 1, 2, 3, 0
    normal = turns.sum(axis=1)
    along = np.einsum("qkc,qc->qk", turns, normal)
    unit = normal / np.maximum(np.linalg.norm(normal, axis=1), 1e-300)[:, None]
    size = np.abs(v - v[:, :1]).max(axis=(1, 2))
    off = np.abs(np.einsum("qc,qc->q", v[:, 3] - v[:, 0], unit))
    return (along > 0).all(axis=1) & (off <= FLAT * size)
