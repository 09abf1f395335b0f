"""SPD `jacks`: a jack (three cylinders crossing at right angles, a sphere at each end) with
a half-size copy in each of its eight octants, recursively; one light, a purple background."""

import numpy as np

from bench.generate.records import SpdScene, rotation
from protocols.scene import SceneData, View

DEFAULT = 1  # jacks.nff: one jack
VIEW = View(
    eye=(0, 0, -8), at=(0, 0, 0), up=(0, 1, 0), angle=25.0, hither=0.001, width=256, height=256
)
BACKGROUND = (0.2, 0.05, 0.2)
AXES = np.eye(3)
ENDS = np.concatenate([AXES, -AXES])  # sphere centres: +x, +y, +z, -x, -y, -z
OCTANTS = np.array([(i, j, k) for i in (-0.5, 0.5) for j in (-0.5, 0.5) for k in (-0.5, 0.5)])


def jacks_count(n: int) -> int:
    """Objects of `jacks(n)`: 9 per jack, (8^n - 1) / 7 jacks."""
    return 9 * (8**n - 1) // 7


def frames(n: int) -> np.ndarray:
    """(jacks, 4, 4) each jack's frame (row vectors), in the SPD's order (a jack, then the
    subtrees of its octants): the scene turned -30 degrees about x after -20 about y; a child
    halved and moved to an octant of its parent's frame."""
    count = (8**n - 1) // 7
    out = np.zeros((count, 4, 4))
    root = np.eye(4)
    root[:3, :3] = rotation("y", np.radians(-20.0)) @ rotation("x", np.radians(-30.0))
    m, pos = root[None], np.zeros(1, np.int64)
    out[0] = root
    child = np.tile(np.diag([0.5, 0.5, 0.5, 1.0]), (8, 1, 1))
    child[:, 3, :3] = OCTANTS
    for depth in range(n - 1, 0, -1):
        m = np.einsum("cij,pjk->pcik", child, m).reshape(-1, 4, 4)
        pos = np.repeat(pos, 8) + 1 + np.tile(np.arange(8) * ((8**depth - 1) // 7), len(pos))
        out[pos] = m
    return out


def jacks(n: int = DEFAULT, printed: bool = False) -> SceneData:
    """SPD `jacks` at size factor n: per jack (scaled by 0.75) its cylinders along x, y, z of
    radius 0.1, then its six end spheres of radius 0.2, radii scaled with the jack."""
    scene = SpdScene(VIEW, ((-10.0, 3.0, -20.0),), BACKGROUND)
    pink = scene.material((0.737, 0.561, 0.561), 0.7, 0.7, 20.0, 0.0, 1.0)
    m = frames(n)
    m[:, :3, :3] *= 0.75
    turn, move = m[:, :3, :3], m[:, 3, :3]
    scale = np.linalg.norm(turn[:, 0], axis=1)  # the SPD's radius scale: its first row's length

    def place(p):
        return np.einsum("kj,pji->pki", p, turn) + move[:, None, :]

    gids = scene.take(9 * len(m)).reshape(-1, 9)
    base, apex = place(-AXES).reshape(-1, 3), place(AXES).reshape(-1, 3)
    r = np.repeat(0.1 * scale, 3)
    scene.cones(base, r, apex, r, pink, gids[:, :3])
    scene.spheres(place(ENDS).reshape(-1, 3), np.repeat(0.2 * scale, 6), pink, gids[:, 3:])
    return scene.build(f"<generated jacks {n}>", printed)
