"""SPD `tree`: a binary tree of cone branches with a sphere at each joint, on a square field;
seven lights."""

import numpy as np

from bench.generate.records import SpdScene, rotation
from protocols.scene import SceneData, View

DEFAULT = 11  # tree.nff: 4,095 cones and spheres
VIEW = View(eye=(4.5, 0.4, 2.0), at=(0, 0, 1.5), up=(0, 0, 1), angle=45.0, hither=1.0)
LIGHTS = (
    (-5, 5, 50),
    (30, -30, 30),
    (-40, -30, 20),
    (10, 30, 40),
    (-30, 40, 10),
    (50, 25, 20),
    (-10, -60, 30),
)
FIELD = np.array([[50, 50, 0], [-50, 50, 0], [-50, -50, 0], [50, -50, 0]], float)
WIDTH = 0.15  # branch radius at its base over its length
DIAMETER = 0.67  # a branch's radius at its tip over at its base; a child's scale over its parent's
# Per child branch: (branching angle, divergence about the parent's axis, contraction).
BRANCHES = ((40.0, 90.0, 0.65), (25.0, 140.0 + 90.0, 0.70))


def tree_count(n: int) -> int:
    """Objects of `tree(n)`: the field, then a cone and a sphere per branch."""
    return 1 + 2 * (2 ** (n + 1) - 1)


def _branch_matrices() -> np.ndarray:
    """(2, 4, 4) a child branch's frame in its parent's (row vectors, the SPD's Rst_mx): tilted
    about x, turned about z, shrunk, and moved to the parent's tip (z = 1)."""
    out = np.zeros((2, 4, 4))
    for i, (tilt, turn, contraction) in enumerate(BRANCHES):
        turned = rotation("x", np.radians(tilt)) @ rotation("z", np.radians(turn))
        out[i, :3, :3] = turned * contraction
        out[i, 3] = (0.0, 0.0, 1.0, 1.0)
    return out


def branches(n: int) -> tuple[np.ndarray, np.ndarray]:
    """(frames (2^(n+1) - 1, 4, 4), scales) of every branch in the SPD's order (a branch, then
    its first child's subtree, then its second's), built a level at a time."""
    count = 2 ** (n + 1) - 1
    frames, scales = np.zeros((count, 4, 4)), np.zeros(count)
    m, scale, pos = np.eye(4)[None], 1.0, np.zeros(1, np.int64)
    frames[0], scales[0] = m[0], scale
    child = _branch_matrices()
    for depth in range(n - 1, -1, -1):
        m = np.einsum("cij,pjk->pcik", child, m).reshape(-1, 4, 4)
        scale *= DIAMETER
        pos = np.repeat(pos, 2) + 1 + np.tile([0, 2 ** (depth + 1) - 1], len(pos))
        frames[pos], scales[pos] = m, scale
    return frames, scales


def tree(n: int = DEFAULT, printed: bool = False) -> SceneData:
    """SPD `tree` at size factor n: the field (gid 0), then per branch its cone and the sphere
    at its tip."""
    scene = SpdScene(VIEW, LIGHTS)
    scene.polygons(FIELD, [4], scene.material((0.2, 0.7, 0.2), 1.0, 0.0, 0.0, 0.0, 0.0))
    bark = scene.material((0.55, 0.4, 0.2), 1.0, 0.0, 0.0, 0.0, 0.0)
    frames, scales = branches(n)
    base, apex = frames[:, 3, :3], frames[:, 2, :3] + frames[:, 3, :3]
    base_r = scales * WIDTH
    apex_r = base_r * DIAMETER
    gids = scene.take(2 * len(scales))
    scene.cones(base, base_r, apex, apex_r, bark, gids[0::2])
    scene.spheres(apex, apex_r, bark, gids[1::2])
    return scene.build(f"<generated tree {n}>", printed)
