"""The 4-wide hierarchy (`bvh.nodes_of`, `bvh.bvh_walk`, `packet.packet_walk`): its four-box
vector test enters exactly the boxes the scalar slab arithmetic enters, and its walks (alone
and in packets) find brute force's first hits to the bit on grazing rays (in faces, along
edges, through corners), random rays, trees of one leaf and degenerate trees; any-hit
queries agree with brute force."""

import math

import numba
import numpy as np
import pytest

from meshnode.engine import Engine
from meshnode.engine.bvh import HI, LANES, NODE_COLS, REF_COL, aligned, nodes_of
from meshnode.engine.bvhbuild import build_tree
from meshnode.engine.lanes import SLACK, slab4
from tests.conftest import make_scene
from tests.test_grid import random_scene


@numba.njit
def _scalar(planes, at, lane, ox, oy, oz, rx, ry, rz, t_lo, bound):
    """The binary walk's slab test of one box (lane `lane` of the node at `at`)."""
    o, r = (ox, oy, oz), (rx, ry, rz)
    t0, t1 = -math.inf, math.inf
    for a in range(3):
        lo = np.float64(planes[at + 4 * a + lane])
        hi = np.float64(planes[at + HI + 4 * a + lane])
        near, far = (lo, hi) if r[a] >= 0.0 else (hi, lo)
        t0 = max(t0, (near - o[a]) * r[a]) if a else (near - o[a]) * r[a]
        t1 = min(t1, (far - o[a]) * r[a]) if a else (far - o[a]) * r[a]
    t1 *= SLACK
    return t0 if t0 <= t1 and t1 > t_lo and t0 < bound else math.inf


@numba.njit
def _both(planes, o, r, t_lo, bound):
    """(slab4's entries and masks, the scalar test's entries) for every ray and node."""
    n_nodes = planes.shape[0] // NODE_COLS
    vec = np.empty((o.shape[0], n_nodes, LANES))
    ref = np.empty((o.shape[0], n_nodes, LANES))
    masks = np.empty((o.shape[0], n_nodes), np.int64)
    entry = np.empty(LANES)
    for i in range(o.shape[0]):
        ox, oy, oz, rx, ry, rz = o[i, 0], o[i, 1], o[i, 2], r[i, 0], r[i, 1], r[i, 2]
        nx = np.uint64(0) if rx >= 0.0 else np.uint64(HI)
        ny = np.uint64(0) if ry >= 0.0 else np.uint64(HI)
        nz = np.uint64(0) if rz >= 0.0 else np.uint64(HI)
        for q in range(n_nodes):
            at = np.uint64(q * NODE_COLS)
            masks[i, q] = slab4(planes, at, nx, ny, nz, ox, oy, oz, rx, ry, rz, t_lo, bound, entry)
            for j in range(LANES):
                vec[i, q, j] = entry[j]
                ref[i, q, j] = _scalar(
                    planes, q * NODE_COLS, j, ox, oy, oz, rx, ry, rz, t_lo, bound
                )
    return vec, masks, ref


def test_four_boxes_at_once_enter_exactly_as_one_at_a_time():
    """Random boxes, empty lanes, and rays whose origins lie on box planes or whose
    directions are axial (the finite huge reciprocal): the same entries, bit for bit, and
    the mask says which lanes are finite."""
    rng = np.random.default_rng(1)
    planes = np.zeros((40, NODE_COLS), np.float32)
    lo = rng.uniform(-2, 1, (40, 3, LANES)).astype(np.float32)
    hi = lo + rng.uniform(0, 1.5, (40, 3, LANES)).astype(np.float32)
    planes[:, :HI], planes[:, HI:REF_COL] = lo.reshape(40, -1), hi.reshape(40, -1)
    planes[::5, [3, 7, 11]], planes[::5, [15, 19, 23]] = np.inf, -np.inf  # empty lane 3
    o = rng.uniform(-3, 3, (300, 3))
    o[:40, 0] = planes[:, 0]  # on a box's lower x plane
    d = rng.normal(size=(300, 3))
    d[50:100, 1:] = 0.0  # along x
    d /= np.linalg.norm(d, axis=1)[:, None]
    r = np.where(np.abs(d) < 1e-300, 1e300, 1.0 / np.where(d == 0.0, 1.0, d))
    for t_lo, bound in ((0.0, math.inf), (0.5, 2.0)):
        vec, masks, ref = _both(planes.reshape(-1), o, r, t_lo, bound)
        np.testing.assert_array_equal(vec, ref)
        bits = (np.isfinite(ref) * (1 << np.arange(LANES))).sum(axis=2)
        np.testing.assert_array_equal(masks, bits)
        assert 0 < np.isfinite(ref).mean() < 1


def assert_as_brute_force(scene, o, d, t_max=None):
    """First hits (packets and single rays) and any-hit answers equal brute force's."""
    brute = Engine(scene, brute=True)
    t_ref, g_ref = brute.first_hits(o, d)
    for packets in (True, False):
        engine = Engine(scene, structure="bvh", packets=packets)
        t, g = engine.first_hits(o, d)
        np.testing.assert_array_equal(g, g_ref)
        np.testing.assert_array_equal(t, t_ref)
        ends = np.where(np.isfinite(t_ref), t_ref * 1.5, 10.0) if t_max is None else t_max
        np.testing.assert_array_equal(engine.occluded(o, d, ends), brute.occluded(o, d, ends))
    return g_ref


def cube_triangles(c, h):
    """The 12 triangles of the axis-aligned cube of centre c and half side h."""
    corners = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)]) * h + c
    quads = ((0, 1, 3, 2), (4, 5, 7, 6), (0, 1, 5, 4), (2, 3, 7, 6), (0, 2, 6, 4), (1, 3, 7, 5))
    tris = []
    for a, b, e, f in quads:
        tris += [(corners[a], corners[b], corners[e], 0), (corners[a], corners[e], corners[f], 0)]
    return tris


def test_grazing_rays_in_faces_along_edges_and_through_corners():
    """A grid of touching cubes (faces in shared planes, boxes sharing planes): rays lying in
    the face planes, along the edges, through the corners, and just off them."""
    tris = []
    for c in np.array([[x, y, z] for x in range(3) for y in range(3) for z in range(2)]):
        tris += cube_triangles(c.astype(float), 0.5)
    scene = make_scene(triangles=tris)
    rng = np.random.default_rng(2)
    plane = rng.integers(-1, 3, (400, 3)) + 0.5  # on face planes
    o = plane + rng.uniform(-4, 4, (400, 3)) * np.array([1, 1, 0])  # in a z plane
    d = rng.normal(size=(400, 3)) * np.array([1, 1, 0])
    edge = rng.integers(-1, 3, (100, 3)) + np.array([0.5, 0.5, 0.0])  # on cube edges
    edge[:, 2] = -3.0
    corner_o = rng.uniform(-3, 5, (100, 3))
    corner_to = rng.integers(0, 3, (100, 3)) - 0.5  # towards a cube corner
    o = np.concatenate([o, edge, corner_o, corner_o + 1e-12])
    along_z = np.tile([[0.0, 0.0, 1.0]], (100, 1))
    d = np.concatenate([d, along_z, corner_to - corner_o, corner_to - corner_o])
    g = assert_as_brute_force(scene, o, d)
    assert (g >= 0).sum() > 300


def test_random_rays_on_random_layouts():
    for seed in (21, 22):
        rng = np.random.default_rng(seed)
        scene = random_scene(rng, n=80)
        o = rng.uniform(-8, 8, (1500, 3))
        d = rng.uniform(-5, 5, (1500, 3)) - o
        assert (assert_as_brute_force(scene, o, d, rng.uniform(0.1, 12, 1500)) >= 0).sum() > 300


@pytest.mark.parametrize("n", [0, 1, 2, 3, 5])
def test_trees_of_one_leaf(n):
    """Fewer objects than a leaf holds: the root is a leaf, a node of one lane."""
    spheres = [((1.5 * i, 0, 0), 0.5, 0) for i in range(n)]
    o = np.array([[1.5 * i, 0, -5] for i in range(n + 1)] + [[-3.0, 0.0, 0.0]])
    d = np.tile([0.0, 0.0, 1.0], (len(o), 1))
    d[-1] = (1.0, 0.0, 0.0)
    g = assert_as_brute_force(make_scene(spheres=spheres), o, d)
    assert (g >= 0).sum() == (n + 1 if n else 0)


def test_degenerate_trees():
    """All triangles in one plane (every box flat), a long chain of objects (a deep,
    lopsided tree), and objects sharing one centre."""
    rng = np.random.default_rng(5)
    flat = [(*np.c_[rng.uniform(-5, 5, (3, 2)), np.zeros(3)], 0) for _ in range(200)]
    chain = [((2.0**-i, 0, 0), 2.0**-i / 4, 0) for i in range(60)]
    same = [((0, 0, 0), 0.1 + 0.05 * i, 0) for i in range(40)]
    for spheres, tris in (((), flat), (chain, ()), (same, ())):
        scene = make_scene(spheres=spheres, triangles=tris)
        o = rng.uniform(-6, 6, (800, 3))
        d = rng.uniform(-1, 1, (800, 3)) * 0.2 - o
        assert (assert_as_brute_force(scene, o, d) >= 0).sum() > 20


def test_nodes_hold_every_leaf_once_and_are_aligned():
    """Collapsing keeps every binary leaf once in a non-empty lane, makes fewer nodes than
    2/3 of the leaves, and the nodes start on a 128-byte boundary."""
    rng = np.random.default_rng(6)
    lo = rng.uniform(-1, 1, (700, 3))
    hi = lo + rng.uniform(0, 0.1, (700, 3))
    box, meta, prims = build_tree(lo, hi, np.array([0, 0, 700, 700, 700]))
    nodes = aligned(nodes_of(box, meta, np.arange(700)))
    assert nodes.ctypes.data % 128 == 0
    refs = nodes.view(np.int32)[:, REF_COL : REF_COL + LANES]
    inner = refs[refs > 0]
    assert sorted(inner.tolist()) == list(range(1, len(nodes)))  # each node once
    packed = ~refs[(refs < 0) & (refs != ~0)].astype(np.int64)
    assert (packed & 15).sum() == 700 and len(packed) == (meta[:, 2] < 0).sum()
    assert 3 * len(nodes) < 2 * len(packed)  # the bound `holding.engine_bytes` counts on
    lanes_lo = nodes[:, :HI].reshape(-1, 3, LANES)
    assert np.isfinite(lanes_lo).any(axis=1).sum() == len(inner) + len(packed)
