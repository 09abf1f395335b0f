"""SPD `sombrero`: a height field of the damped ripple cos(2 pi r) exp(-r), two triangles per
cell; one light."""

import numpy as np

from bench.generate.records import SpdScene
from protocols.scene import SceneData, View

DEFAULT = 1  # the SPD's default: a 32 x 32 field
VIEW = View(eye=(0, 5, -8), at=(0, 0, 0), up=(0, 0, 1), angle=40.0, hither=0.01)
TWO_PI = 2.0 * 3.14159265358  # the SPD's own pi


def sombrero_count(n: int) -> int:
    """Triangles of `sombrero(n)`."""
    return 2 * (32 * 2 ** (n - 1) - 1) ** 2


def heights(w: int) -> np.ndarray:
    """(w, w) samples of cos(2 pi r) exp(-r) on [-4, 4)^2 in single precision, as the SPD
    stores them (row i at y = -4 + 8 i / w, column j at x = -4 + 8 j / w)."""
    y, x = np.meshgrid(
        -4.0 + np.arange(w) * (8.0 / w), -4.0 + np.arange(w) * (8.0 / w), indexing="ij"
    )
    r = np.sqrt(x * x + y * y)
    return (3.0 * np.cos(TWO_PI * r) * np.exp(-r) / 3.0).astype(np.float32).astype(float)


def sombrero(n: int = DEFAULT, printed: bool = False) -> SceneData:
    """SPD `sombrero` at size factor n: the field of w = 32 x 2^(n-1) samples drawn over x and
    z in [-4, 4] (w - 1 steps) at height -3 + sample, cell by cell, row by row."""
    scene = SpdScene(VIEW, ((10.0, 10.0, -10.0),))
    red = scene.material((1.0, 0.1, 0.1), 0.8, 0.0, 40.0, 0.0, 1.0)
    w = 32 * (1 << (n - 1))
    d = heights(w)
    step = 8.0 / (w - 1)
    i, j = (a.reshape(-1) for a in np.indices((w - 1, w - 1)))

    def corner(di, dj):
        return np.stack(
            [-4.0 + (j + dj) * step, -3.0 + d[i + di, j + dj], -4.0 + (i + di) * step], axis=1
        )

    v00, v11, v01, v10 = corner(0, 0), corner(1, 1), corner(0, 1), corner(1, 0)
    tris = np.stack([np.stack([v00, v11, v01], 1), np.stack([v00, v10, v11], 1)], 1)
    scene.polygons(tris.reshape(-1, 3), np.full(2 * len(i), 3), red)
    return scene.build(f"<generated sombrero {n}>", printed)
