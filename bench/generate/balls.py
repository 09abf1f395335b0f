"""SPD `balls`: the sphereflake, 1 + 9 + ... + 9^n mirrored spheres on a floor square."""

import numpy as np

from bench.generate.records import SpdScene
from protocols.scene import SceneData, View

DEFAULT = 4  # balls.nff: 7,381 spheres
VIEW = View(eye=(2.1, 1.3, 1.7), at=(0, 0, 0), up=(0, 0, 1), angle=45.0, hither=0.01)
LIGHTS = ((4.0, 3.0, 2.0), (1.0, -4.0, 4.0), (-3.0, 1.0, 5.0))
FLOOR = np.array([[12, 12, -0.5], [-12, 12, -0.5], [-12, -12, -0.5], [12, -12, -0.5]], float)


def balls_count(n: int) -> int:
    """Spheres of `balls(n)` (the floor polygon not counted)."""
    return (9 ** (n + 1) - 1) // 8


def _child_directions() -> np.ndarray:
    """The sphereflake's nine child directions about +z: three groups 120 degrees apart of
    one direction 45 degrees round at elevation asin(sqrt(2/3)) and two on the equator at 15
    and 75 degrees (SPD balls' `objset`)."""
    azimuth = np.radians([45.0, 15.0, 75.0])[None, :] + np.radians([0.0, 120.0, 240.0])[:, None]
    cos_elev = np.array([1 / np.sqrt(3), 1.0, 1.0])[None, :]
    z = np.broadcast_to(np.array([np.sqrt(2 / 3), 0.0, 0.0]), azimuth.shape)
    dirs = np.stack([cos_elev * np.cos(azimuth), cos_elev * np.sin(azimuth), z], axis=-1)
    return dirs.reshape(9, 3)


def _z_to(d: np.ndarray) -> np.ndarray:
    """(N, 3, 3) rotations taking +z to the unit directions `d` about the axis z x d: the
    frame SPD turns the child directions into at each sphere."""
    axis = np.stack([-d[:, 1], d[:, 0], np.zeros(len(d))], axis=1)
    sin = np.linalg.norm(axis, axis=1)
    cos = d[:, 2]
    # Along -z SPD turns half a turn about y (balls_s3.nff shows it); along +z any axis does.
    k = np.where(sin[:, None] > 1e-12, axis / np.maximum(sin, 1e-300)[:, None], (0.0, 1.0, 0.0))
    cross = np.zeros((len(d), 3, 3))
    cross[:, 0, 1], cross[:, 0, 2], cross[:, 1, 2] = -k[:, 2], k[:, 1], -k[:, 0]
    cross -= cross.transpose(0, 2, 1)
    outer = k[:, :, None] * k[:, None, :]
    return (
        cos[:, None, None] * np.eye(3)
        + sin[:, None, None] * cross
        + (1 - cos)[:, None, None] * outer
    )


def sphereflake(n: int) -> tuple[np.ndarray, np.ndarray]:
    """(centres (N, 3), radii (N,)) of the SPD sphereflake of size factor n >= 0, in the SPD
    file's order (each sphere, then its nine children's subtrees). Built a level at a time:
    a child of radius r/3 touches its parent of radius r along the parent's frame's direction;
    its place in the file is its parent's + 1 + child index x the size of a child's subtree."""
    if n < 0:
        raise ValueError(f"balls: size factor must be >= 0, got {n}")
    objset = _child_directions()
    centres, radii = np.zeros((balls_count(n), 3)), np.zeros(balls_count(n))
    c, d, r, pos = np.zeros((1, 3)), np.array([[0.0, 0.0, 1.0]]), 0.5, np.zeros(1, np.int64)
    centres[0], radii[0] = c[0], r
    for level in range(1, n + 1):
        d = np.einsum("pij,kj->pki", _z_to(d), objset).reshape(-1, 3)  # (P * 9, 3)
        c = np.repeat(c, 9, axis=0) + d * (r + r / 3)
        r /= 3
        pos = np.repeat(pos, 9) + 1 + np.tile(np.arange(9), len(pos)) * balls_count(n - level)
        centres[pos], radii[pos] = c, r
    return centres, radii


def balls(n: int = DEFAULT, printed: bool = False) -> SceneData:
    """SPD `balls` at size factor n: the floor square (gid 0), then the sphereflake."""
    scene = SpdScene(VIEW, LIGHTS)
    floor = scene.material((1.0, 0.75, 0.33), 0.8, 0.0, 0.0, 0.0, 1.0)
    scene.polygons(FLOOR, [4], floor)
    mirror = scene.material((1.0, 0.9, 0.7), 0.5, 0.5, 37.0, 0.0, 1.0)
    scene.spheres(*sphereflake(n), mirror)
    return scene.build(f"<generated balls {n}>", printed)
