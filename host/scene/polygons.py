"""Polygon and patch records from flat vertex arrays, shared by every scene reader.

A face read from NFF, OBJ, PLY or Inventor goes through these same functions, so the same face
becomes the same records, bit for bit, whichever file it came from. All work is vectorised over
every polygon of a scene at once.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from protocols import dtypes

# Geometry tolerances, relative so that they hold at any scene scale.
AREA_EPS = 1e-12  # |Newell normal| <= eps * (longest edge)^2: no usable plane
PLANE_EPS = 1e-6  # a vertex farther than eps * (bounding-box diagonal) from the plane


class Planes(NamedTuple):
    """Per polygon: unit normal, no area (`flat`), a vertex off the plane (`off`); per vertex:
    distance from its polygon's plane (`dist`)."""

    unit: np.ndarray
    flat: np.ndarray
    off: np.ndarray
    dist: np.ndarray


def planes(pts: np.ndarray, counts: np.ndarray) -> Planes:
    """Unit normals of polygons given as consecutive vertices `pts` (n, 3), `counts` each.

    The normal is Newell's (sum of edge cross products about the first vertex), which uses
    every vertex and so stays right when the first three are nearly collinear; its length is
    twice the area, hence the zero-area test against the longest edge squared.
    """
    counts = np.asarray(counts, np.int64)
    starts = np.cumsum(counts) - counts
    owner = np.repeat(np.arange(len(counts)), counts)
    nxt = np.arange(1, len(pts) + 1)
    nxt[starts + counts - 1] = starts
    local = pts - pts[starts][owner]  # about the first vertex: no cancellation far from origin
    normal = np.add.reduceat(np.cross(local, local[nxt]), starts)
    length = np.linalg.norm(normal, axis=1)
    longest = np.maximum.reduceat(np.linalg.norm(local[nxt] - local, axis=1), starts)
    flat = length <= AREA_EPS * longest**2
    unit = normal / np.where(flat, 1.0, length)[:, None]

    centroid = np.add.reduceat(local, starts) / counts[:, None]
    dist = np.abs(np.einsum("ij,ij->i", local - centroid[owner], unit[owner]))
    size = np.linalg.norm(
        np.maximum.reduceat(pts, starts) - np.minimum.reduceat(pts, starts), axis=1
    )
    off = ~flat & (np.maximum.reduceat(dist, starts) > PLANE_EPS * size)
    return Planes(unit, flat, off, dist)


def flat_records(pts: np.ndarray, counts, ids: np.ndarray, unit: np.ndarray):
    """(triangles, polygons, vertices) of flat `p` polygons: triangles stay triangles with
    their geometric normal, larger ones are polygons over a vertex table. `ids`: (n, 2) gid,
    material per polygon; `unit`: their normals from `planes`."""
    counts = np.asarray(counts, np.int64)
    ids = np.asarray(ids, np.int64).reshape(-1, 2)
    owner = np.repeat(np.arange(len(counts)), counts)
    is_tri = counts == 3
    tri = np.zeros(int(is_tri.sum()), dtypes.TRIANGLE)
    tri["gid"], tri["mat"] = ids[is_tri, 0], ids[is_tri, 1]
    tri["v"] = pts[is_tri[owner]].reshape(-1, 3, 3)
    if len(tri):
        tri["n"] = unit[is_tri][:, None, :]

    big = ~is_tri
    poly = np.zeros(int(big.sum()), dtypes.POLYGON)
    poly["gid"], poly["mat"] = ids[big, 0], ids[big, 1]
    poly["count"] = counts[big]
    poly["start"] = np.cumsum(counts[big]) - counts[big]
    vertices = pts[big[owner]] if len(pts) else np.zeros((0, 3))
    return tri, poly, np.ascontiguousarray(vertices)


def fan(pos: np.ndarray, nrm: np.ndarray, counts, ids) -> np.ndarray:
    """Smooth triangles (v0, vi, vi+1) of each patch, sharing the patch's gid, normals unit."""
    if not len(counts):
        return np.zeros(0, dtypes.TRIANGLE)
    nrm = nrm / np.linalg.norm(nrm, axis=1)[:, None]
    counts = np.asarray(counts, np.int64)
    ids = np.asarray(ids, np.int64).reshape(-1, 2)
    starts = np.cumsum(counts) - counts
    per = counts - 2
    patch = np.repeat(np.arange(len(counts)), per)
    k = np.arange(int(per.sum())) - np.repeat(np.cumsum(per) - per, per) + 1
    idx = np.stack((starts[patch], starts[patch] + k, starts[patch] + k + 1), axis=1)
    rec = np.zeros(len(idx), dtypes.TRIANGLE)
    rec["gid"], rec["mat"] = ids[patch, 0], ids[patch, 1]
    rec["v"], rec["n"], rec["smooth"] = pos[idx], nrm[idx], 1
    return rec


def by_gid(*triangles: np.ndarray) -> np.ndarray:
    """Flat and smooth triangles in one table, in scene order (stable by gid)."""
    tri = np.concatenate(triangles)
    return tri[np.argsort(tri["gid"], kind="stable")]
