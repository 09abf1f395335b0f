"""The host's occupancy map marks where the objects' surfaces are, not their bounds: every
point of every surface lies in a marked voxel (sampled on spheres, triangles, polygons' rims
and cones, SPD scenes and slanted shapes made here), the map lies within the objects' padded
bounds (rasterised here by NumPy, the map the host made before), and leaves out what the
bounds hold but no surface reaches; faces on voxel boundaries stop a walk in time. (A mesh
with it gives the image it gives without a map: `test_occupancy`.)"""

import numpy as np
import pytest

from host.planning.cells import scene_box
from host.planning.occupancy import occupancy_map
from host.scene.nff import read_nff
from meshnode.engine.occupancy import SUB
from protocols import dtypes
from protocols.scene import SceneData, View
from tests.conftest import spd_scene

SCENES = ["teapot_s1.nff", "mount_s1.nff", "rings_s1.nff", "tetra_s3.nff", "gears_s1.nff"]


def _slanted() -> SceneData:
    """Long thin triangles, cones and cylinders at odd angles, spheres of several sizes and
    a polygon: shapes whose bounds are mostly empty."""
    rng = np.random.default_rng(7)
    tri = np.zeros(40, dtypes.TRIANGLE)
    corner = rng.uniform(-1, 1, (40, 1, 3))
    tri["v"] = corner + rng.normal(scale=0.6, size=(40, 3, 3)) * [1.0, 0.05, 1.0]
    tri["gid"] = np.arange(40)
    cones = np.zeros(12, dtypes.CONE)
    cones["base"] = rng.uniform(-1, 1, (12, 3))
    cones["apex"] = cones["base"] + rng.normal(scale=0.8, size=(12, 3))
    cones["base_r"] = rng.uniform(0.01, 0.1, 12)
    cones["apex_r"] = np.where(np.arange(12) % 2, cones["base_r"], rng.uniform(0, 0.1, 12))
    cones["gid"] = 40 + np.arange(12)
    spheres = np.zeros(6, dtypes.SPHERE)
    spheres["center"] = rng.uniform(-1, 1, (6, 3))
    spheres["radius"] = [0.02, 0.05, 0.2, 0.5, -0.3, 0.9]
    spheres["gid"] = 52 + np.arange(6)
    polygons = np.zeros(1, dtypes.POLYGON)
    polygons[0] = (58, 0, 0, 5)
    angles = np.linspace(0, 2 * np.pi, 5, endpoint=False)
    vertices = np.stack([np.cos(angles), 0.3 * np.cos(angles) + np.sin(angles), np.sin(angles)], 1)
    materials = np.zeros(1, dtypes.MATERIAL)
    view = View((0.0, -5.0, 0.0), (0.0, 0.0, 0.0), (0.0, 0.0, 1.0), 40.0, 0.0, 16, 16)
    return SceneData(
        view,
        materials=materials,
        spheres=spheres,
        triangles=tri,
        polygons=polygons,
        vertices=vertices,
        cones=cones,
    )


def _surface_points(scene: SceneData, per: int, rng) -> np.ndarray:
    """Points on every object's surface: spheres and cones all over, triangles inside and on
    their edges, polygons on their rims (their corners and edges)."""
    points = []
    for s in scene.spheres:
        d = rng.normal(size=(per, 3))
        points.append(s["center"] + abs(s["radius"]) * d / np.linalg.norm(d, axis=1)[:, None])
    for t in scene.triangles:
        u, v = rng.random((2, per))
        u[: per // 4] = 1 - v[: per // 4]  # a quarter on the third edge
        flip = u + v > 1
        u[flip], v[flip] = 1 - u[flip], 1 - v[flip]
        p0, p1, p2 = t["v"]
        points.append(p0 + u[:, None] * (p1 - p0) + v[:, None] * (p2 - p0))
    for c in scene.cones:
        axis = c["apex"] - c["base"]
        a = axis / np.linalg.norm(axis)
        side = np.cross(a, [1.0, 0.0, 0.0] if abs(a[0]) < 0.9 else [0.0, 1.0, 0.0])
        side /= np.linalg.norm(side)
        other = np.cross(a, side)
        s, angle = rng.random(per), rng.uniform(0, 2 * np.pi, per)
        r = abs(c["base_r"]) + s * (abs(c["apex_r"]) - abs(c["base_r"]))
        ring = np.cos(angle)[:, None] * side + np.sin(angle)[:, None] * other
        points.append(c["base"] + s[:, None] * axis + r[:, None] * ring)
    for p in scene.polygons:
        rim = scene.vertices[p["start"] : p["start"] + p["count"]]
        s = rng.random((len(rim), 1))
        points.append(rim + s * (np.roll(rim, -1, axis=0) - rim))
        points.append(rim)
    return np.concatenate(points)


def _marked(scene: SceneData, fine: bool = False):
    """(the map as a (z, y, x) bool array, its box's lo, a voxel's size); with `fine`, the
    map of its sub-voxels instead (SUB times finer: a voxel's marked sub-voxels)."""
    lo, hi = (np.asarray(b, float) for b in scene_box(scene))
    res, bits, masks = occupancy_map(scene, (lo, hi))
    full = np.unpackbits(np.frombuffer(bits, np.uint8), count=int(np.prod(res))).astype(bool)
    if not fine:
        return full.reshape(res[::-1]), lo, (hi - lo) / np.array(res)
    per = np.zeros((full.size, SUB**3), bool)  # bit x + SUB y + SUB^2 z of each voxel
    per[full] = np.unpackbits(np.frombuffer(masks, np.uint8), bitorder="little").reshape(-1, SUB**3)
    nx, ny, nz = res
    sub = per.reshape(nz, ny, nx, SUB, SUB, SUB).transpose(0, 3, 1, 4, 2, 5)
    return sub.reshape(nz * SUB, ny * SUB, nx * SUB), lo, (hi - lo) / (np.array(res) * SUB)


@pytest.mark.parametrize("fine", [False, True], ids=["voxel", "sub-voxel"])
@pytest.mark.parametrize("name", [*SCENES, "slanted"])
def test_every_surface_point_lies_in_a_marked_voxel(name, fine):
    """Surface points sampled on every object lie in marked voxels, and in marked
    sub-voxels of them (`Partition.occ_fine`), which a walk tests before it stops."""
    scene = _slanted() if name == "slanted" else read_nff(spd_scene(name))
    full, lo, cell = _marked(scene, fine)
    points = _surface_points(scene, 64, np.random.default_rng(3))
    at = np.clip(np.floor((points - lo) / cell).astype(np.int64), 0, np.array(full.shape[::-1]) - 1)
    missed = ~full[at[:, 2], at[:, 1], at[:, 0]]
    assert not missed.any(), (name, points[missed][:5])
    if fine:  # and the sub-voxels leave most of an occupied voxel out
        assert full.mean() < 0.45 * _marked(scene)[0].mean(), name


@pytest.mark.parametrize("name", [*SCENES, "slanted"])
def test_the_map_lies_within_the_bounds_and_leaves_out_what_no_surface_reaches(name):
    from bench.occupancy_map import bounds_map

    scene = _slanted() if name == "slanted" else read_nff(spd_scene(name))
    full, lo, cell = _marked(scene)
    bounds = bounds_map(scene, lo, lo + cell * full.shape[::-1], full.shape[::-1])
    assert not (full & ~bounds).any()
    if name != "gears_s1.nff":  # gears: flat polygons in axis planes fill their bounds
        assert full.sum() < 0.8 * bounds.sum(), (name, full.sum(), bounds.sum())


def test_a_face_on_a_voxel_boundary_stops_the_walk_before_its_hit_from_far_away():
    """Squares lying exactly on voxel faces (axis planes) and one a hair inside a voxel,
    hit by rays from a thousand boxes away at grazing and steep angles: the map's padding
    keeps the first occupied voxel at or before every hit, as the kernels need (a walk that
    stepped past a surface would resume beyond it and miss it)."""
    import math

    from meshnode.engine import Engine
    from meshnode.engine.counters import N_COUNTERS
    from meshnode.engine.mapwalk import first_occupied
    from meshnode.engine.occupancy import occupancy_arrays
    from meshnode.engine.traverse import box_span

    corners = np.zeros(2, dtypes.SPHERE)  # the scene's box: two small spheres far apart
    corners["center"] = [(-8.0, -8.0, -8.0), (8.0, 8.0, 8.0)]
    corners["radius"] = 0.01
    view = View((0.0, -50.0, 0.0), (0.0, 0.0, 0.0), (0.0, 0.0, 1.0), 40.0, 0.0, 16, 16)
    base = SceneData(view, materials=np.zeros(1, dtypes.MATERIAL), spheres=corners)
    lo, hi = (np.asarray(b, float) for b in scene_box(base))
    res = np.array(occupancy_map(base, (lo, hi))[0])
    cell = (hi - lo) / res
    squares = []
    for axis, k, shift in ((2, 40, 0.0), (0, 23, 0.0), (1, 31, 0.0), (2, 12, 1e-9)):
        at = lo[axis] + k * cell[axis] + shift  # a voxel face (or just past it)
        u, v = [a for a in range(3) if a != axis]
        quad = np.zeros((4, 3))
        quad[:, axis] = at
        quad[:, u] = [-3.0, 3.0, 3.0, -3.0]
        quad[:, v] = [-3.0, -3.0, 3.0, 3.0]
        squares += [quad[[0, 1, 2]], quad[[0, 2, 3]]]
    tri = np.zeros(len(squares), dtypes.TRIANGLE)
    tri["v"] = squares
    tri["gid"] = 2 + np.arange(len(squares))
    scene = SceneData(view, materials=np.zeros(1, dtypes.MATERIAL), spheres=corners, triangles=tri)
    assert np.allclose(scene_box(scene), (lo, hi))  # the squares leave the box as it was
    occ = occupancy_arrays(lo, hi, *occupancy_map(scene, (lo, hi)))
    rng = np.random.default_rng(5)
    n = 2000
    targets = np.asarray(squares)[rng.integers(len(squares), size=n)]
    w = rng.dirichlet(np.ones(3), size=n)
    points = (w[:, :, None] * targets).sum(axis=1)
    far = rng.normal(size=(n, 3))
    far[: n // 2] *= [1.0, 1.0, 0.02]  # half of them nearly in the squares' planes
    far /= np.linalg.norm(far, axis=1, keepdims=True)
    origins = points + 1000.0 * 16.0 * far
    dirs = points - origins
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    t_hit, _ = Engine(scene, brute=True).first_hits(origins, dirs)
    counters = np.zeros(N_COUNTERS, np.int64)
    for (ox, oy, oz), (dx, dy, dz), th in zip(origins, dirs, t_hit, strict=True):
        rx, ry, rz = (1.0 / v if v != 0.0 else math.inf for v in (dx, dy, dz))
        t0, t1 = box_span(ox, oy, oz, rx, ry, rz, 0.0, math.inf, *lo, *hi)
        t = first_occupied(ox, oy, oz, dx, dy, dz, rx, ry, rz, t0, t1, *occ, counters)
        assert t <= th, ((ox, oy, oz), (dx, dy, dz), t, th)
    assert np.isfinite(t_hit).mean() > 0.99  # the rays do hit the squares
