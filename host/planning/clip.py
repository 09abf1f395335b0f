"""Which objects each node holds: the scene's shapes clipped against every node's box.

Conservative by design: a node may hold an object it never meets, never miss one it does,
so correctness never depends on how tight the test is, only the memory and the work do.
"""

import numpy as np

from host.scene.derived import kept, scene_tables
from meshnode.engine.tables import segments, triangle_normals
from protocols.scene import SceneData

KEPT_BYTES = 64 << 20  # boxes' holders kept for a scene at most (`holders`: a byte a object)
EDGE_TESTS_UP_TO = 16  # vertices: a polygon with more keeps its bounds and plane tests only
# (its edge tests cost a pair per edge and vertex: gears' 128 faces of 144 vertices took 1 s
# of a 3x3 plan; conservative, so at worst a node holds a face it never meets)


def _flat_shapes(scene: SceneData, tb):
    """Triangles then polygons as one vertex list: (vertices, first vertex, count) per shape.
    A polygon's vertices are moved along its dropped axis onto the plane the engine hits it
    on (through the first vertex, Newell normal): for a polygon that is not quite flat, that
    is the shape the engine tests, not the outline of the vertices."""
    tri = scene.triangles["v"].reshape(-1, 3)
    poly = scene.polygons
    n_vert = poly["count"].astype(np.int64)
    counts = np.concatenate([np.full(len(scene.triangles), 3), n_vert]).astype(np.int64)
    starts = np.concatenate([[0], np.cumsum(counts)[:-1]]).astype(np.int64)
    rows, _, owner, _ = segments(poly["start"], n_vert)
    pv = scene.vertices[rows].reshape(-1, 3).copy()
    if len(pv):
        p0, n = tb.polygons[owner, :3], tb.polygons[owner, 3:6]
        info = tb.poly_info[owner]
        drop = 3 - info[:, 2] - info[:, 3]  # the axis that is neither u nor v
        at = np.arange(len(pv))
        off = ((pv - p0) * n).sum(axis=1)  # distance off the plane, times |n| = 1
        pv[at, drop] -= off / n[at, drop]
    return np.concatenate([tri, pv]), starts, counts


def _edges_separate(verts, starts, counts, lo, hi) -> np.ndarray:
    """Per shape: does some axis edge x box-axis separate it from the box [lo, hi]?"""
    centre, half = (lo + hi) / 2, (hi - lo) / 2
    _, _, shape_of, nxt = segments(starts, counts)
    edges = verts[nxt] - verts  # edge j of its shape, one per vertex
    # Every (edge, vertex of the same shape) pair: each edge's axes project its whole shape.
    per_edge = counts[shape_of]
    pair_vert, edge_first, pair_edge, _ = segments(np.repeat(starts, counts), per_edge)
    rel = verts[pair_vert] - centre
    apart = np.zeros(len(verts), np.bool_)
    for k in range(3):
        axis = np.cross(edges, np.eye(3)[k])
        reach = (np.abs(axis) @ half) * (1 + 1e-9) + 1e-12  # a zero axis separates nothing
        proj = (rel * axis[pair_edge]).sum(axis=1)
        apart |= np.minimum.reduceat(proj, edge_first) > reach
        apart |= np.maximum.reduceat(proj, edge_first) < -reach
    return np.logical_or.reduceat(apart, starts)


def _edge_separated(scene: SceneData, tb, los, his, candidates: np.ndarray) -> np.ndarray:
    """(boxes, flat shapes) bool: the separating-axis tests that bounds and plane tests leave
    out (edges crossed with the box axes), run only on each box's remaining candidates. With
    those, exact for triangles and convex polygons; a concave polygon may be kept needlessly."""
    verts, starts, counts = kept(scene, "flat shapes", lambda: _flat_shapes(scene, tb))
    separated = np.zeros(candidates.shape, np.bool_)
    for b in range(len(los)):  # one pass per node box, over the shapes its bounds admit
        idx = np.flatnonzero(candidates[b])
        if len(idx):
            rows, first, _, _ = segments(starts[idx], counts[idx])
            separated[b, idx] = _edges_separate(verts[rows], first, counts[idx], los[b], his[b])
    return separated


def holders(scene: SceneData, los: np.ndarray, his: np.ndarray) -> np.ndarray:
    """(boxes, objects) bool: which boxes each object touches, objects in the engine's local
    order (spheres, triangles, polygons, cones). Bounds must overlap; spheres must also reach
    the box; triangles and polygons must pass the separating-axis tests (their plane, and
    their edges crossed with the box axes, for those crossing the box's faces with at most
    EDGE_TESTS_UP_TO vertices); cones only their bounds (conservative: a node may hold an
    object it never meets, never miss one it does). A box clipped before against this scene
    is not clipped again (a plan clips the same cells many times: `host.scene.derived`),
    within KEPT_BYTES."""
    los, his = np.asarray(los, float).reshape(-1, 3), np.asarray(his, float).reshape(-1, 3)
    boxes = kept(scene, "holders", dict)
    keys = [lo.tobytes() + hi.tobytes() for lo, hi in zip(los, his, strict=True)]
    new = [i for i, k in enumerate(keys) if k not in boxes]
    if new:
        if (len(boxes) + len(new)) * scene_tables(scene).n > KEPT_BYTES:
            boxes.clear()
        for i, row in zip(new, _clipped(scene, los[new], his[new]), strict=True):
            boxes[keys[i]] = row
    return np.array([boxes[k] for k in keys]).reshape(len(keys), scene_tables(scene).n)


def _clipped(scene: SceneData, los: np.ndarray, his: np.ndarray) -> np.ndarray:
    """`holders`, computed."""
    tb = scene_tables(scene)
    touch = (tb.lo[None] <= his[:, None]) & (tb.hi[None] >= los[:, None])
    touch = touch.all(axis=2)
    centre, half = (los + his) / 2, (his - los) / 2
    if tb.spheres is not None:
        s = tb.spheres
        gap = np.maximum(np.abs(s[None, :, :3] - centre[:, None]) - half[:, None], 0.0)
        reach = (gap**2).sum(axis=2) <= (s[None, :, 3] * (1 + 1e-9)) ** 2
        touch[:, : len(s)] &= reach
    planes = (
        (tb.triangles, tb.offsets[1], triangle_normals),
        (tb.polygons, tb.offsets[2], lambda p: p[:, 3:6]),
    )
    for table, first, normals in planes:
        if table is None:
            continue
        p0, n = table[:, :3], normals(table)
        dist = np.abs(((centre[:, None] - p0[None]) * n[None]).sum(axis=2))
        reach = (np.abs(n)[None] * half[:, None]).sum(axis=2)
        touch[:, first : first + len(table)] &= dist <= reach * (1 + 1e-9) + 1e-12
    a, b = tb.offsets[1], tb.offsets[3]  # triangles and polygons
    if b > a:
        # A shape whose bounds lie inside the box touches it: only those crossing the box's
        # faces need the edge tests (gears' 144-vertex polygons: a pair per edge and vertex;
        # planning 3x3 took 1.2 s, 1.1 s of it here)
        inside = ((tb.lo[None, a:b] >= los[:, None]) & (tb.hi[None, a:b] <= his[:, None])).all(2)
        many = np.concatenate(
            [np.zeros(len(scene.triangles), bool), scene.polygons["count"] > EDGE_TESTS_UP_TO]
        )
        touch[:, a:b] &= ~_edge_separated(scene, tb, los, his, touch[:, a:b] & ~inside & ~many)
    return touch
