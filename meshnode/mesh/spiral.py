"""The centre-out order of a grid of cells (DESIGN.md 6): a node starts its chunks from the
middle of its rectangle so that thieves take the outer end, and the host deals dynamic tiles
from the image's middle so that the last, which decide how evenly nodes finish, are the
border's."""

import numpy as np


def spiral_order(i: np.ndarray, j: np.ndarray) -> list[int]:
    """Indices of grid cells (column i, row j) from the middle outward: ring by ring (the
    Chebyshev distance from the middle), each ring walked round by angle (DESIGN.md 6)."""
    i, j = np.asarray(i, float), np.asarray(j, float)
    if len(i) == 0:
        return []
    ci, cj = (i.min() + i.max()) / 2, (j.min() + j.max()) / 2
    ring = np.maximum(np.abs(i - ci), np.abs(j - cj))
    return np.lexsort((np.arctan2(j - cj, i - ci), ring)).tolist()


def spiral_chunks(rect, side: int) -> list[tuple[int, int, int, int]]:
    """`rect` (x0, x1, y0, y1) cut into chunks of `side` pixels, ordered from the centre
    outward: ring by ring (Chebyshev distance of the chunk from the middle one), each ring
    walked round by angle. Traced from the front, stolen from the back (DESIGN.md 6)."""
    x0, x1, y0, y1 = rect
    xs, ys = list(range(x0, x1, side)), list(range(y0, y1, side))
    j, i = np.divmod(np.arange(len(xs) * len(ys)), len(xs))
    return [
        (xs[i[c]], min(xs[i[c]] + side, x1), ys[j[c]], min(ys[j[c]] + side, y1))
        for c in spiral_order(i, j)
    ]
