"""Which objects each node holds: the scene's shapes clipped against every node's box.

Conservative by design: a node may hold an object it never meets, never miss one it does,
so correctness never depends on how tight the test is, only the memory and the work do.

The tests run in one kernel (`_touching`), box by object. It calls no engine kernel, so
numba's cache of this file alone keys it (`meshnode.engine.jit`: the engine's cache folder is
named after the engine's kernel sources, which this file is not one of).
"""

import numpy as np

from host.scene.derived import kept, scene_tables
from meshnode.engine.jit import kernel
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
    """`holders`, computed (`_touching`: tetra8's 65,536 triangles against 256 cells took 3.2 s
    as NumPy arrays of every box by every object, 45 ms here)."""
    tb = scene_tables(scene)
    empty = np.zeros((0, 3))
    spheres = tb.spheres if tb.spheres is not None else np.zeros((0, 4))
    tri = tb.triangles
    tri_p0, tri_n = (tri[:, :3], triangle_normals(tri)) if tri is not None else (empty, empty)
    poly = tb.polygons
    poly_p0, poly_n = (poly[:, :3], poly[:, 3:6]) if poly is not None else (empty, empty)
    verts, starts, counts = kept(scene, "flat shapes", lambda: _flat_shapes(scene, tb))
    return _touching(
        np.ascontiguousarray(los),
        np.ascontiguousarray(his),
        tb.lo,
        tb.hi,
        np.ascontiguousarray(spheres),
        np.ascontiguousarray(tri_p0),
        np.ascontiguousarray(tri_n),
        np.ascontiguousarray(poly_p0),
        np.ascontiguousarray(poly_n),
        tb.offsets,
        verts,
        starts,
        counts,
        EDGE_TESTS_UP_TO,
    )


@kernel
def _touching(
    los,
    his,
    lo,
    hi,
    spheres,
    tri_p0,
    tri_n,
    poly_p0,
    poly_n,
    offsets,
    verts,
    starts,
    counts,
    edge_tests_up_to,
):
    """(boxes, objects) bool, as `holders` says: bounds overlap, then a sphere's reach, a
    triangle's or polygon's plane, and for a flat shape of at most `edge_tests_up_to`
    vertices crossing the box's faces its edges crossed with the box axes."""
    boxes, n = los.shape[0], lo.shape[0]
    out = np.zeros((boxes, n), np.bool_)
    first_flat, first_cone = offsets[1], offsets[3]
    first_poly = offsets[2]
    centre, half = np.empty(3), np.empty(3)
    for b in range(boxes):
        for k in range(3):
            centre[k] = (los[b, k] + his[b, k]) / 2
            half[k] = (his[b, k] - los[b, k]) / 2
        for i in range(n):
            if not _overlap(lo[i], hi[i], los[b], his[b]):
                continue
            if i < first_flat:
                out[b, i] = _sphere_reaches(spheres[i], centre, half)
                continue
            if i >= first_cone:
                out[b, i] = True  # a cone keeps its bounds' test only
                continue
            if i < first_poly:
                p0, nrm = tri_p0[i - first_flat], tri_n[i - first_flat]
            else:
                p0, nrm = poly_p0[i - first_poly], poly_n[i - first_poly]
            if not _plane_reaches(p0, nrm, centre, half):
                continue
            s = i - first_flat
            if counts[s] > edge_tests_up_to or _inside(lo[i], hi[i], los[b], his[b]):
                out[b, i] = True
                continue
            out[b, i] = not _edges_separate(verts, starts[s], counts[s], centre, half)
    return out


@kernel
def _overlap(lo, hi, box_lo, box_hi) -> bool:
    for k in range(3):
        if not (lo[k] <= box_hi[k] and hi[k] >= box_lo[k]):
            return False
    return True


@kernel
def _inside(lo, hi, box_lo, box_hi) -> bool:
    for k in range(3):
        if not (lo[k] >= box_lo[k] and hi[k] <= box_hi[k]):
            return False
    return True


@kernel
def _sphere_reaches(sphere, centre, half) -> bool:
    """Whether the sphere (x, y, z, r) reaches the box: its centre's distance to the box."""
    d2 = 0.0
    for k in range(3):
        gap = max(abs(sphere[k] - centre[k]) - half[k], 0.0)
        d2 += gap**2
    return d2 <= (sphere[3] * (1 + 1e-9)) ** 2


@kernel
def _plane_reaches(p0, nrm, centre, half) -> bool:
    """Whether the plane through p0 of normal nrm crosses the box."""
    dist = (centre[0] - p0[0]) * nrm[0] + (centre[1] - p0[1]) * nrm[1]
    dist = abs(dist + (centre[2] - p0[2]) * nrm[2])
    reach = abs(nrm[0]) * half[0] + abs(nrm[1]) * half[1] + abs(nrm[2]) * half[2]
    return dist <= reach * (1 + 1e-9) + 1e-12


@kernel
def _edges_separate(verts, start, count, centre, half) -> bool:
    """Does some axis edge x box-axis separate the flat shape (verts[start:start + count],
    in order) from the box? Each edge's axes project the whole shape."""
    for j in range(count):
        a, z = verts[start + j], verts[start + (j + 1) % count]
        e0, e1, e2 = z[0] - a[0], z[1] - a[1], z[2] - a[2]
        for k in range(3):
            # edge x unit axis k, as np.cross makes it
            b0, b1, b2 = 1.0 if k == 0 else 0.0, 1.0 if k == 1 else 0.0, 1.0 if k == 2 else 0.0
            x0, x1, x2 = e1 * b2 - e2 * b1, e2 * b0 - e0 * b2, e0 * b1 - e1 * b0
            reach = abs(x0) * half[0] + abs(x1) * half[1] + abs(x2) * half[2]
            reach = reach * (1 + 1e-9) + 1e-12  # a zero axis separates nothing
            least, most = np.inf, -np.inf
            for m in range(count):
                v = verts[start + m]
                proj = (v[0] - centre[0]) * x0 + (v[1] - centre[1]) * x1
                proj += (v[2] - centre[2]) * x2
                least, most = min(least, proj), max(most, proj)
            if least > reach or most < -reach:
                return True
    return False
