"""Shared test helpers: where the SPD scenes are, and small scene builders."""

from pathlib import Path

import numpy as np
import pytest

from protocols import dtypes
from protocols.scene import SceneData, View

SCENES = Path(__file__).resolve().parents[2] / "shared" / "scenes"


def spd_scene(name: str) -> Path:
    """Path of an SPD scene, skipping the test when ../shared/scenes is not beside the repo."""
    path = SCENES / name
    if not path.exists():
        pytest.skip(f"{path} not available")
    return path


def make_scene(
    spheres=(), triangles=(), polygons=(), cones=(), lights=(), materials=None,
    view=None, background=(0.0, 0.0, 0.0),
) -> SceneData:  # fmt: skip
    """A scene from plain tuples: spheres (c, r, mat), triangles (v0, v1, v2, mat),
    polygons (vertices, mat), cones (base, br, apex, ar, mat), lights (pos). gids follow the
    order spheres, triangles, polygons, cones."""
    view = view or View(eye=(0, 0, -10), at=(0, 0, 0), up=(0, 1, 0), angle=45.0)
    mats = materials or [((1.0, 1.0, 1.0), 1.0, 0.0, 1.0, 0.0, 1.0)]
    m = np.zeros(len(mats), dtypes.MATERIAL)
    for i, (rgb, kd, ks, shine, t, ior) in enumerate(mats):
        m[i] = (rgb, kd, ks, shine, t, ior)
    gid = 0
    s = np.zeros(len(spheres), dtypes.SPHERE)
    for i, (c, r, mat) in enumerate(spheres):
        s[i] = (gid, mat, c, r)
        gid += 1
    t = np.zeros(len(triangles), dtypes.TRIANGLE)
    for i, (a, b, c, mat) in enumerate(triangles):
        v = np.array([a, b, c], float)
        n = np.cross(v[1] - v[0], v[2] - v[0])
        n /= np.linalg.norm(n)
        t[i] = (gid, mat, v, np.tile(n, (3, 1)), 0)
        gid += 1
    p = np.zeros(len(polygons), dtypes.POLYGON)
    verts = []
    for i, (vs, mat) in enumerate(polygons):
        p[i] = (gid, mat, sum(len(x) for x in verts), len(vs))
        verts.append(np.asarray(vs, float))
        gid += 1
    c = np.zeros(len(cones), dtypes.CONE)
    for i, (b, br, a, ar, mat) in enumerate(cones):
        c[i] = (gid, mat, b, br, a, ar)
        gid += 1
    li = np.zeros(len(lights), dtypes.LIGHT)
    for i, pos in enumerate(lights):
        li[i] = (pos, (1.0, 1.0, 1.0))
    return SceneData(
        view=view, background=background, lights=li, materials=m, spheres=s, triangles=t,
        polygons=p, vertices=np.concatenate(verts) if verts else np.zeros((0, 3)), cones=c,
    )  # fmt: skip
