"""Polygons cut into triangles the way the SPD library cuts them for POV-Ray 3 (which has no
concave polygon primitive), so a converted scene holds the very triangles of the SPD's own
POV-Ray output (gears' 144-vertex concave faces included), in the same order.

The rule, on the polygon projected onto the two axes its first three vertices span best: take
the leftmost vertex; if another vertex lies inside the triangle it makes with its two
neighbours, cut along the diagonal to the leftmost such vertex, else cut off that triangle.
Pieces wait on a stack, the piece outside the cut's index range first."""

from __future__ import annotations

import numpy as np


def split_polygon(pts: np.ndarray) -> list[tuple[int, int, int]]:
    """Triangles of the planar polygon `pts` (n, 3) as vertex index triples, in the order and
    vertex order the SPD library writes them."""
    a1, a2 = plane_axes(pts)
    x, y = pts[:, a1].tolist(), pts[:, a2].tolist()
    out: list[tuple[int, int, int]] = []
    stack = [list(range(len(pts)))]
    while stack:
        poly = stack.pop()
        if len(poly) == 3:
            out.append((poly[0], poly[1], poly[2]))
            continue
        lo, hi = _cut(poly, x, y)
        stack.append(poly[lo : hi + 1])  # the piece between the cut's two ends ...
        stack.append(poly[: lo + 1] + poly[hi:])  # ... waits for the rest, cut first
    return out


def plane_axes(pts: np.ndarray) -> tuple[int, int]:
    """The two coordinate axes to project on: those of the largest component of the normal
    of the first three vertices (ties favour the z normal, then y, as the SPD's do)."""
    nx, ny, nz = np.abs(np.cross(pts[1] - pts[0], pts[2] - pts[0]))
    if nx > ny and nx > nz:
        return 1, 2
    if ny > nx and ny > nz:
        return 0, 2
    return 0, 1


def _cut(poly: list[int], x: list[float], y: list[float]) -> tuple[int, int]:
    """Positions in `poly` of the two ends of the next cut, lower first."""
    n = len(poly)
    left = min(range(n), key=lambda i: x[poly[i]])  # the first leftmost
    after = 0 if left == n - 1 else left + 1
    before = n - 1 if left == 0 else left - 1
    inner = _inner_vertex(poly, left, after, before, x, y)
    if inner in (after, before):
        return min(after, before), max(after, before)  # cut off the ear at `left`
    return min(left, inner), max(left, inner)


def _inner_vertex(poly, left, after, before, x, y) -> int:
    """The leftmost vertex inside the triangle (before, left, after), else the neighbour of
    `left` farther right. Like the SPD's, the search skips the polygon's last vertex."""
    p = [poly[i] for i in (left, after, before)]
    xl, yl = x[p[0]], y[p[0]]
    top = max(y[v] for v in p)
    bottom = min(y[v] for v in p)
    upper, lower = (p[2], p[1]) if y[p[2]] > y[p[1]] else (p[1], p[2])
    best = before if x[p[2]] > x[p[1]] else after
    for k in range(len(poly) - 1):
        if k in (after, left, before):
            continue
        xk, yk = x[poly[k]], y[poly[k]]
        if not (bottom <= yk <= top and xk < x[poly[best]]):
            continue
        below_upper = (yk - yl) * (x[upper] - xl) <= (y[upper] - yl) * (xk - xl)
        above_lower = (yk - yl) * (x[lower] - xl) >= (y[lower] - yl) * (xk - xl)
        if below_upper and above_lower:
            best = k
    return best
