"""SPD `lattice`: a cubic grid of spheres joined along x, y and z by thin cylinders, every
object after a colour of its own; six lights."""

import numpy as np

from bench.generate.records import SpdScene, surface
from protocols.scene import SceneData, View

DEFAULT = 12  # the SPD's default size factor
LIGHTS = (
    (2, 0.5, 0.5),
    (-1, 0.5, 0.5),
    (0.5, 2, 0.5),
    (0.5, -1, 0.5),
    (0.5, 0.5, 2),
    (0.5, 0.5, -1),
)
# Colour of the spheres, then of the cylinders along x, y and z.
SURFACES = (
    surface((0.9, 0.9, 0.9), 0.5, 0.5, 37.0, 0.0, 0.0),
    surface((0.9, 0.1, 0.1), 0.99, 0.0, 0.0, 0.0, 0.0),
    surface((0.1, 0.9, 0.1), 0.99, 0.0, 0.0, 0.0, 0.0),
    surface((0.1, 0.1, 0.9), 0.99, 0.0, 0.0, 0.0, 0.0),
)


def lattice_count(n: int) -> int:
    """Objects of `lattice(n)`: (n + 1)^3 spheres and 3 n (n + 1)^2 cylinders."""
    return (n + 1) ** 3 + 3 * n * (n + 1) ** 2


def lattice(n: int = DEFAULT, printed: bool = False) -> SceneData:
    """SPD `lattice` at size factor n: for each grid point (x, then y, then z) its sphere and
    the cylinders to its +x, +y, +z neighbours (none past the last), each after its colour."""
    x = ((n >> 1) + 0.5) / n
    half_cell = 1.0 / (n << 1)
    view = View((x, 1.0, 1.0 - half_cell), (x, -1.0, -1.0 - half_cell), (0.2, 1.0, 0.0), 60.0)
    scene = SpdScene(view, LIGHTS)
    r1, r2 = 0.25 / n, (1.0 / 16.0) / n
    delta = r1 * (1.0 - np.sqrt((1.0 / 16.0) / (1.0 / 4.0))) * 0.99
    grid = np.indices((n + 1,) * 3).reshape(3, -1).T  # (points, 3): x, y, z, z fastest
    # Slot 0: the sphere; slot 1 + a: the cylinder along axis a, where there is a neighbour.
    present = np.concatenate([np.ones((len(grid), 1), bool), grid != n], axis=1)
    point, slot = np.nonzero(present)  # file order: point by point, slot by slot
    mats = scene.materials(np.array(SURFACES)[slot])
    gids = scene.take(len(slot))
    centre = grid[point] / n
    ball = slot == 0
    scene.spheres(centre[ball], np.full(int(ball.sum()), r1), mats[ball], gids[ball])
    axis = np.eye(3, dtype=bool)[slot[~ball] - 1]
    start = centre[~ball]
    # Along its axis a cylinder runs from x0 + delta to x0 + 1/n - delta (summed in that order).
    base = np.where(axis, start + delta, start)
    apex = np.where(axis, start + 1.0 / n - delta, start)
    scene.cones(base, r2, apex, r2, mats[~ball], gids[~ball])
    return scene.build(f"<generated lattice {n}>", printed)
