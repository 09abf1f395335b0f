"""A packet's vector row operations (`rows`): each ray of a packet gets, bit for bit, what the
scalar code gives it alone: the box entry of the binary walk's slab test, and
`intersect.hit_triangle`'s t, on random rays, rays lying in box planes, axial rays (the finite
huge reciprocal), rays through triangle edges and corners, rays in a triangle's plane, and
packets with inactive or padded columns."""

import math

import numba
import numpy as np

from meshnode.engine.bvh import HI, LANES, NODE_COLS, REF_COL, reciprocal
from meshnode.engine.intersect import hit_triangle
from meshnode.engine.packet import P_A, P_BOUND, P_CUR, P_D, P_E, P_LO, P_O, P_R, P_ROWS
from meshnode.engine.rows import (
    PACKET,
    copy_row,
    count_below,
    packet_slabs,
    packet_triangle,
    reciprocals,
    unit_directions,
)
from tests.test_bvh4 import _scalar


@numba.njit
def _slabs_both(planes, o, r, t_lo, bound):
    """(packet_slabs' entries and nearest, the scalar entries) for every node lane and packet
    of PACKET rays."""
    n_at = planes.shape[0] // NODE_COLS * LANES
    n_packets = o.shape[0] // PACKET
    vec = np.empty((n_packets, n_at, PACKET))
    near = np.empty((n_packets, n_at))
    ref = np.empty((n_packets, n_at, PACKET))
    f = np.zeros((P_ROWS, PACKET))
    for p in range(n_packets):
        for k in range(PACKET):
            i = p * PACKET + k
            for a in range(3):
                f[P_O + a, k] = o[i, a]
                f[P_R + a, k] = r[i, a]
            f[P_LO, k] = t_lo[i]
            f[P_BOUND, k] = bound[i]
        for q in range(n_at):
            at = q // LANES * NODE_COLS + q % LANES
            near[p, q] = packet_slabs(planes, at, f, P_E + 1, P_O, P_R, P_LO, P_BOUND)
            for k in range(PACKET):
                vec[p, q, k] = f[P_E + 1, k]
                i = p * PACKET + k
                ref[p, q, k] = _scalar(
                    planes,
                    q // LANES * NODE_COLS,
                    q % LANES,
                    o[i, 0],
                    o[i, 1],
                    o[i, 2],
                    r[i, 0],
                    r[i, 1],
                    r[i, 2],
                    t_lo[i],
                    bound[i],
                )
    return vec, near, ref


def test_packet_slabs_enter_as_the_scalar_slab_test():
    rng = np.random.default_rng(3)
    nodes = 30
    planes = np.zeros((nodes, NODE_COLS), np.float32)
    lo = rng.uniform(-2, 1, (nodes, 3, LANES)).astype(np.float32)
    hi = lo + rng.uniform(0, 1.5, (nodes, 3, LANES)).astype(np.float32)
    planes[:, :HI], planes[:, HI:REF_COL] = lo.reshape(nodes, -1), hi.reshape(nodes, -1)
    planes[::4, [3, 7, 11]], planes[::4, [15, 19, 23]] = np.inf, -np.inf  # empty lane 3
    n = 60 * PACKET
    o = rng.uniform(-3, 3, (n, 3))
    o[:nodes, 0] = planes[:, 0]  # on a box's lower x plane
    o[nodes : 2 * nodes, 1] = planes[:, HI + 4]  # on an upper y plane
    centre = (lo + hi).transpose(0, 2, 1).reshape(-1, 3) / 2
    d = centre[rng.integers(0, len(centre), n)] - o  # each aimed at some box
    d[100:160, 1:] = 0.0  # along x
    d[160:200, :2] = 0.0  # along z
    d[200:240, 1] = 0.0  # in a y plane
    d /= np.linalg.norm(d, axis=1)[:, None]
    r = np.array([[reciprocal(x) for x in row] for row in d])
    t_lo = np.where(rng.uniform(size=n) < 0.3, rng.uniform(0, 1, n), 0.0)
    bound = np.where(rng.uniform(size=n) < 0.3, rng.uniform(0.5, 3, n), math.inf)
    bound[::7] = -math.inf  # finished rays and padded columns
    vec, near, ref = _slabs_both(planes.reshape(-1), o, r, t_lo, bound)
    np.testing.assert_array_equal(vec, ref)
    np.testing.assert_array_equal(near, ref.min(axis=2))
    assert 0.02 < np.isfinite(ref).mean() < 0.5


@numba.njit
def _triangles_both(tri, o, d, t_lo, cur, bound, origin, gids):
    """(packet_triangle's t, tested counts, hit masks; hit_triangle's t with the walk's
    conditions) for every triangle and packet of PACKET rays."""
    n_packets = o.shape[0] // PACKET
    nt = tri.shape[0]
    vec = np.empty((n_packets, nt, PACKET))
    ref = np.empty((n_packets, nt, PACKET))
    tested = np.empty((n_packets, nt), np.int64)
    masks = np.empty((n_packets, nt), np.int64)
    f = np.zeros((P_ROWS, PACKET))
    org = np.empty(PACKET, np.int64)
    for p in range(n_packets):
        for k in range(PACKET):
            i = p * PACKET + k
            for a in range(3):
                f[P_O + a, k] = o[i, a]
                f[P_D + a, k] = d[i, a]
            f[P_LO, k], f[P_CUR, k], f[P_BOUND, k] = t_lo[i], cur[i], bound[i]
            org[k] = origin[i]
        for j in range(nt):
            got = packet_triangle(tri, j, gids[j], f, org, P_O, P_D, P_LO, P_CUR, P_BOUND, P_A)
            tested[p, j] = got & 0xFF
            masks[p, j] = got >> 8
            for k in range(PACKET):
                vec[p, j, k] = f[P_A, k]
                i = p * PACKET + k
                t = math.inf
                if cur[i] < bound[i] and origin[i] != gids[j]:
                    t = hit_triangle(
                        tri, j, o[i, 0], o[i, 1], o[i, 2], d[i, 0], d[i, 1], d[i, 2], t_lo[i],
                        bound[i],
                    )[0]  # fmt: skip
                ref[p, j, k] = t
    return vec, tested, masks, ref


def _rows(v):
    """Triangle table rows (v0, e1, e2, unused normal) of (n, 3, 3) vertices."""
    e1, e2 = v[:, 1] - v[:, 0], v[:, 2] - v[:, 0]
    return np.ascontiguousarray(np.column_stack([v[:, 0], e1, e2, np.zeros_like(e1)]))


def test_packet_triangle_hits_as_hit_triangle():
    rng = np.random.default_rng(4)
    v = rng.uniform(-1, 1, (12, 3, 3))
    v[0] = [[0, 0, 0], [1, 0, 0], [0, 1, 0]]  # in the z = 0 plane
    v[1] = [[0, 0, 0], [1, 0, 0], [2, 0, 0]]  # degenerate: det 0
    tri = _rows(v)
    gids = np.arange(12, dtype=np.int64) + 100
    n = 80 * PACKET
    # aimed at random barycentric points, vertices and edge points of random triangles
    which = rng.integers(0, 12, n)
    bary = rng.uniform(0, 1, (n, 3))
    bary[: n // 4] = np.eye(3)[rng.integers(0, 3, n // 4)]  # corners
    bary[n // 4 : n // 2, 0] = 0.0  # on an edge
    bary /= bary.sum(axis=1)[:, None]
    target = np.einsum("ij,ijk->ik", bary, v[which])
    o = rng.uniform(-3, 3, (n, 3))
    o[n // 2 : n // 2 + 40] = [0.2, 0.2, 0.0] + rng.uniform(-2, 2, (40, 3)) * [1, 1, 0]
    d = target - o
    d[n // 2 : n // 2 + 40] = rng.normal(size=(40, 3)) * [1, 1, 0]  # in triangle 0's plane
    d /= np.linalg.norm(d, axis=1)[:, None]
    t_lo = np.where(rng.uniform(size=n) < 0.2, rng.uniform(0, 2, n), 0.0)
    cur = np.where(rng.uniform(size=n) < 0.1, 5.0, t_lo)  # some enter beyond their bound
    bound = np.where(rng.uniform(size=n) < 0.3, rng.uniform(0.5, 4, n), math.inf)
    bound[::9] = -math.inf
    origin = np.where(rng.uniform(size=n) < 0.1, gids[which], -1)
    vec, tested, masks, ref = _triangles_both(tri, o, d, t_lo, cur, bound, origin, gids)
    np.testing.assert_array_equal(vec, ref)
    live = (cur < bound).reshape(-1, 1, PACKET)
    np.testing.assert_array_equal(tested, np.broadcast_to(live, ref.shape).sum(axis=2))
    bits = (np.isfinite(ref) * (1 << np.arange(PACKET))).sum(axis=2)
    np.testing.assert_array_equal(masks, bits)
    assert 0.05 < np.isfinite(ref).mean() < 0.9


@numba.njit
def _copy_and_count(a, b):
    out = np.zeros_like(a)
    counts = np.empty(a.shape[0], np.int64)
    for r in range(a.shape[0]):
        copy_row(out, r, a, r)
        counts[r] = count_below(a, r, b, r)
    return out, counts


def test_copy_row_and_count_below():
    rng = np.random.default_rng(5)
    a = rng.normal(size=(7, PACKET))
    b = rng.normal(size=(7, PACKET))
    b[0] = a[0]  # equal: not below
    b[1] = math.inf
    a[2, ::2] = -math.inf
    out, counts = _copy_and_count(a, b)
    np.testing.assert_array_equal(out, a)
    np.testing.assert_array_equal(counts, (a < b).sum(axis=1))


@numba.njit
def _directions_both(d):
    """(unit_directions' then reciprocals' rows, the scalar ones) for packets of d."""
    n_packets = d.shape[0] // PACKET
    vec = np.empty((n_packets, 6, PACKET))
    ref = np.empty((n_packets, 6, PACKET))
    f = np.zeros((P_ROWS, PACKET))
    for p in range(n_packets):
        for k in range(PACKET):
            dx, dy, dz = d[p * PACKET + k, 0], d[p * PACKET + k, 1], d[p * PACKET + k, 2]
            f[P_D, k], f[P_D + 1, k], f[P_D + 2, k] = dx, dy, dz
            # queries.ray_hits' scalar normalisation
            big = max(abs(dx), max(abs(dy), abs(dz)))
            s = 1.0 / big
            c = s / math.sqrt((dx * s) ** 2 + (dy * s) ** 2 + (dz * s) ** 2)
            ref[p, 0, k], ref[p, 1, k], ref[p, 2, k] = dx * c, dy * c, dz * c
            for a in range(3):
                ref[p, 3 + a, k] = reciprocal(ref[p, a, k])
        unit_directions(f, P_D)
        reciprocals(f, P_D, P_R)
        for a in range(3):
            for k in range(PACKET):
                vec[p, a, k] = f[P_D + a, k]
                vec[p, 3 + a, k] = f[P_R + a, k]
    return vec, ref


def test_unit_directions_and_reciprocals_as_one_ray_at_a_time():
    """Random lengths from 1e-200 to 1e200, axial directions, zero and tiny components (the
    finite huge reciprocal), negative zeros."""
    rng = np.random.default_rng(6)
    n = 50 * PACKET
    d = rng.normal(size=(n, 3)) * 10.0 ** rng.uniform(-200, 200, (n, 1))
    d[:40, 1:] = 0.0
    d[40:80, 0] = -0.0
    d[80:120, 2] = 1e-310
    d[120:160] = np.sign(d[120:160])  # equal components
    vec, ref = _directions_both(d)
    np.testing.assert_array_equal(vec, ref)
    np.testing.assert_array_equal(np.signbit(vec), np.signbit(ref))
