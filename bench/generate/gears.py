"""SPD `gears`: an n x n x n block of meshing 36-tooth gears (concave 144-vertex faces and 144
tooth sides each), some transmitting, on a reflective floor square; five lights."""

import numpy as np

from bench.generate.records import SpdScene
from protocols.scene import SceneData, View

DEFAULT = 4  # gears.nff: 64 gears, 9,345 polygons
VIEW = View(eye=(-1.1, -2.1, 2.6), at=(0, 0, 0), up=(0, 0, 1), angle=45.0, hither=1.0)
LIGHTS = ((2, 4, 4), (-2, 4, 3), (2, -2.5, 2.5), (-1, -4, 2), (-1.111, -2.121, 2.626))
GROUND = np.array([[2, 2, 0], [-2, 2, 0], [-2, -2, 0], [2, -2, 0]], float)
TEETH = 36
EDGE_DIFF = 1.0 - 0.9  # the tooth depth as a part of the radius (as the SPD computes it)
# Each tooth's four rim points: (angle in tooth widths, on the outer (1) or inner (0) circle).
TOOTH = ((-0.19, 1), (0.19, 1), (0.3, 0), (0.7, 0))


def gears_count(n: int) -> int:
    """Polygons of `gears(n)`: the floor, then per gear two faces and 4 x 36 tooth sides."""
    return 1 + n**3 * (2 + 4 * TEETH)


def _rim(centre, offset, outer, inner, z, turn: float) -> np.ndarray:
    """(G, 144, 3) face outlines of gears about `centre` (G, 3) at height centre + z: tooth k at
    offset + turn * 2 pi k / 36, its points `TOOTH` tooth widths (signed by `turn`) round."""
    width = turn * 2 * np.pi / TEETH
    at = turn * 2 * np.pi * np.arange(TEETH) / TEETH
    frac, on_outer = np.array(TOOTH).T
    angle = offset[:, None, None] + at[None, :, None] + frac[None, None, :] * width  # (G, 36, 4)
    radius = np.where(on_outer == 1, outer, inner)
    pts = np.stack([radius * np.cos(angle), radius * np.sin(angle), np.zeros_like(angle)], -1)
    pts = pts.reshape(len(centre), 4 * TEETH, 3) + centre[:, None, :]
    pts[..., 2] += z
    return pts


def _gear_polygons(centre, offset, outer, inner, thickness):
    """(points, counts) of each gear's top face, its 144 side quads, its bottom face."""
    top = _rim(centre, offset, outer, inner, 0.0, 1.0)
    nxt = np.roll(top, -1, axis=1)
    low = np.array([0.0, 0.0, thickness])
    sides = np.stack([top, top - low, nxt - low, nxt], axis=2).reshape(len(centre), -1, 3)
    bottom = _rim(centre, offset, outer, inner, -thickness, -1.0)
    pts = np.concatenate([top, sides, bottom], axis=1).reshape(-1, 3)
    counts = np.tile(np.r_[4 * TEETH, np.full(4 * TEETH, 4), 4 * TEETH], len(centre))
    return pts, counts


def _colours(ix, iy, iz) -> np.ndarray:
    """The SPD's pseudo-random gear colours, brightest component scaled to 1."""
    rgb = np.stack(
        [
            (ix * 3 + iy * 2 + iz + 1) * 5.0 / 7.0,
            (iy * 3 + iz * 2 + ix + 1) * 3.0 / 7.0,
            (iz * 3 + ix * 2 + iy + 1) * 2.0 / 7.0,
        ],
        axis=1,
    )
    rgb = 0.01 + (rgb - np.trunc(rgb))
    return rgb / rgb.max(axis=1, keepdims=True)


def gears(n: int = DEFAULT, printed: bool = False) -> SceneData:
    """SPD `gears` at size factor n: the floor (gid 0), then n^3 gears, each after its colour
    (every fifth by index transmitting, index 1.1)."""
    scene = SpdScene(VIEW, LIGHTS)
    floor = scene.material((1.0, 0.85, 0.7), 0.3, 0.6, 37.0, 0.0, 0.0)
    scene.polygons(GROUND, [4], floor)
    radius = 1.0 / (n - (n - 1) * EDGE_DIFF / 2.0)
    iz, iy, ix = (a.reshape(-1) for a in np.indices((n, n, n)))
    step = radius * (2.0 - EDGE_DIFF)
    centre = np.stack(
        [-1.0 + radius + ix * step, -1.0 + radius + iy * step, 1.0 + iz * (-1.0 / n)], axis=1
    )
    clear = (ix * 4 + iy * 2 + iz) % 5 == 0
    rows = np.zeros((len(ix), 8))
    rows[:, :3] = _colours(ix, iy, iz)
    rows[:, 3:] = np.where(clear[:, None], [0.2, 0.0, 100000.0, 0.8, 1.1], [1, 0, 100000.0, 0, 0])
    mats = scene.materials(rows)
    offset = np.pi * ((ix + iy + iz) % 2) / TEETH
    thickness = min(0.1, 1.0 / (2.0 * n))
    pts, counts = _gear_polygons(
        centre, offset, 0.995 * radius, (1.0 - EDGE_DIFF) * radius, thickness
    )
    scene.polygons(pts, counts, np.repeat(mats, 2 + 4 * TEETH))
    return scene.build(f"<generated gears {n}>", printed)
