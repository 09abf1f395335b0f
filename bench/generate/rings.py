"""SPD `rings`: a pyramid of ring clusters (six pentagonal rings of touching spheres and
cylinders on a dodecahedron's faces) before a wall; three lights."""

import numpy as np

from bench.generate.records import SpdScene, rotation, surface
from protocols.scene import SceneData, View

DEFAULT = 7  # rings.nff: 140 clusters, 8,401 objects
RADIUS = 0.07412  # of the spheres and cylinders
SPREAD = 1.0 / np.sin(np.pi / 8.0)  # between layers (the SPD's SPREAD_OUT is 1)
COLOURS = ((1, 0, 0), (0, 1, 0), (0, 0, 1), (0, 1, 1), (1, 0, 1), (1, 1, 0))


def dodecahedron_rings(minor_radius: float = RADIUS) -> np.ndarray:
    """(30, 3) ring points: a pentagon in the xy plane from +x, then five copies of it tilted
    about x by the dihedral angle and turned about z by 36, 108, ... degrees; scaled so the
    cluster fits in the unit sphere."""
    k = np.arange(5) * 2.0 * np.pi / 5.0
    scale = 1.0 / (1.0 + minor_radius)
    first = np.stack([scale * np.cos(k), scale * np.sin(k), np.zeros(5)], axis=1)
    tilt = rotation("x", 2.0 * np.arccos(np.cos(np.pi / 3.0) / np.sin(np.pi / 5.0)))
    turns = rotation("z", np.pi * (2.0 * np.arange(5) + 1.0) / 5.0)  # (5, 3, 3)
    others = np.einsum("kj,pji->pki", first @ tilt, turns).reshape(25, 3)
    return np.concatenate([first, others])


def rings_count(n: int) -> int:
    """Objects of `rings(n)`: the wall and 60 per cluster."""
    return 1 + 60 * sum((d + 1) ** 2 for d in range(n))


def _offsets(n: int) -> np.ndarray:
    """(clusters, 3) cluster centres, layer by layer, z then x in each layer."""
    rows = []
    for depth in range(n):
        z, x = np.meshgrid(np.arange(depth + 1), np.arange(depth + 1), indexing="ij")
        rows.append(
            np.stack(
                [2 * x - depth, np.full(x.shape, SPREAD * (depth + 1)), 2 * z - depth], -1
            ).reshape(-1, 3)
        )
    return np.concatenate(rows).astype(float)


def rings(n: int = DEFAULT, printed: bool = False) -> SceneData:
    """SPD `rings` at size factor n (n layers): the wall (gid 0), then per cluster six rings,
    each after its colour, of five (cylinder to the previous point, sphere) pairs."""
    eye = np.array([-1.0, -SPREAD, 0.5])
    view = View(tuple(eye), tuple(eye + (0, 1, 0)), (0, 0, 1), 45.0, hither=1.0)
    scene = SpdScene(view, ((3, -SPREAD, 3), (-4, -SPREAD, 1), (2, -SPREAD, -4)))
    wall = scene.material((1, 1, 1), 1.0, 0.0, 0.0, 0.0, 0.0)
    y = SPREAD * (n + 1)
    half = 1.01 * (y - eye[1]) * np.tan(np.pi / 8.0)
    corners = np.array([[1, 1], [-1, 1], [-1, -1], [1, -1]]) * half
    scene.polygons(
        np.stack([corners[:, 0] + eye[0], np.full(4, y), corners[:, 1] + eye[2]], 1), [4], wall
    )
    ring = dodecahedron_rings()
    prev = np.arange(30) + np.where(np.arange(30) % 5 == 0, 4, -1)
    offsets = _offsets(n)
    clusters = len(offsets)
    mats = scene.materials(
        np.tile([surface(c, 0.5, 0.2, 37.0, 0, 0) for c in COLOURS], (clusters, 1))
    )
    base = (offsets[:, None, :] + ring).reshape(-1, 3)
    apex = (offsets[:, None, :] + ring[prev]).reshape(-1, 3)
    gids = scene.take(2 * len(base))
    mat = np.repeat(mats, 5)
    scene.cones(base, RADIUS, apex, RADIUS, mat, gids[0::2])
    scene.spheres(base, np.full(len(base), RADIUS), mat, gids[1::2])
    return scene.build(f"<generated rings {n}>", printed)
