"""The scene's occupancy map: conservative (no ray with an object ahead is told the way is
clear), its distances exact, its wire form checked, and a mesh that skips empty space with it
gives the image and ray counts it gave without it, passing fewer segments; the cost pre-pass
gives it to the nodes where it lightens the busiest one."""

import math

import numpy as np
import pytest

import host.planning.partition
from host.planning.cells import scene_box
from host.planning.occupancy import occupancy_map
from host.scene.nff import read_nff
from meshnode.engine import Engine
from meshnode.engine.counters import N_COUNTERS, OCC_STEPS, STEPS
from meshnode.engine.mapwalk import first_occupied
from meshnode.engine.occupancy import OCTANTS, occupancy_arrays, reaches
from meshnode.engine.traverse import box_span
from protocols.partition import Partition
from protocols.render import EVERYWHERE, ImageSpec, MeshPlan, RenderSpec
from protocols.spec import SpecError
from tests.conftest import spd_scene
from tests.meshsim import render_mesh
from tests.test_mesh_algorithm import SPD_COUNTS


@pytest.mark.parametrize("seed", range(4))
def test_each_octants_side_is_its_largest_empty_cube(seed):
    """Brute force: for every voxel and octant, the largest k whose cube of k voxels a side,
    with the voxel at its corner and reaching the octant's way, holds no occupied voxel
    (space past the map empty), against `reaches`."""
    rng = np.random.default_rng(seed)
    full = rng.random((5, 7, 9)) < 0.03 * (seed + 1)
    full[0, 0, 0] |= seed == 0  # at least one occupied voxel
    got = reaches(full)
    assert got.shape == (OCTANTS, full.size) and got.dtype == np.uint8
    occupied = np.argwhere(full)  # (z, y, x)
    nz, ny, nx = full.shape
    for octant in range(OCTANTS):
        way = np.array([-1 if octant & 4 else 1, -1 if octant & 2 else 1, -1 if octant & 1 else 1])
        for z, y, x in np.ndindex(full.shape):
            # an occupied voxel o lies in the cube of side k iff 0 <= (o - v) * way < k
            ahead = (occupied - (z, y, x)) * way
            inside = (ahead >= 0).all(axis=1)
            want = min(int(ahead[inside].max(axis=1).min()) if inside.any() else 255, 255)
            assert got[octant, x + nx * (y + ny * z)] == want, (octant, z, y, x)


def test_an_empty_map_is_clear_everywhere():
    assert (reaches(np.zeros((4, 4, 4), bool)) == 255).all()
    # ... and a full one (one node's) needs no kernel: nothing is skipped
    assert (occupancy_arrays((0, 0, 0), (1, 1, 1), (1, 1, 1), b"\x80").clear == 0).all()


@pytest.mark.parametrize(
    "name",
    [
        "balls_s1.nff",
        "mount_s1.nff",
        "teapot_s1.nff",
        "gears_s1.nff",
        "tetra_s3.nff",
        "rings_s1.nff",
    ],
)
def test_no_ray_with_an_object_ahead_is_told_the_way_is_clear(name):
    """Rays from random points of the scene's box in random directions: the first occupied
    voxel comes no later than the first hit (brute force), and a ray told nothing lies
    ahead hits nothing."""
    scene = read_nff(spd_scene(name))
    lo, hi = scene_box(scene)
    occ = occupancy_arrays(lo, hi, *occupancy_map(scene, (lo, hi)))
    rng = np.random.default_rng(1)
    n = 3000
    origins = lo + rng.random((n, 3)) * (hi - lo)
    dirs = rng.normal(size=(n, 3))
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    t_hit, _ = Engine(scene, brute=True).first_hits(origins, dirs)
    counters = np.zeros(N_COUNTERS, np.int64)
    clear = early = 0
    for (ox, oy, oz), (dx, dy, dz), th in zip(origins, dirs, t_hit, strict=True):
        rx, ry, rz = (1.0 / v if v != 0.0 else math.inf for v in (dx, dy, dz))
        t0, t1 = box_span(ox, oy, oz, rx, ry, rz, 0.0, math.inf, *lo, *hi)
        t = first_occupied(ox, oy, oz, dx, dy, dz, rx, ry, rz, t0, t1, *occ, counters)
        assert t <= th, (name, (ox, oy, oz), (dx, dy, dz), t, th)
        clear += t == math.inf
        early += t0 < t < math.inf
    # The map must skip something: rays that reach no object, rays that start in empty space.
    assert clear > 0.05 * n and early > 0.05 * n, (clear, early)
    # Its steps are counted apart from a structure's (they cost differently: work units).
    assert counters[OCC_STEPS] >= n and counters[STEPS] == 0


def test_a_partition_checks_its_occupancy_map():
    part = Partition.make(
        [(0, 4, 0, 4)],
        [(0, 0, 0)],
        [(1, 1, 1)],
        ((0, 0, 0), (1, 1, 1)),
        occupancy=((4, 4, 2), bytes(4)),
    )
    again = Partition.from_wire(part.to_wire())
    assert again.occ_res == (4, 4, 2) and again.occ_bits == bytes(4)
    with pytest.raises(SpecError, match=r"occ_bits is 3 bytes: must be 4 bytes.*4x4x2"):
        Partition.make(
            [(0, 4, 0, 4)],
            [(0, 0, 0)],
            [(1, 1, 1)],
            ((0, 0, 0), (1, 1, 1)),
            occupancy=((4, 4, 2), bytes(3)),
        )
    with pytest.raises(SpecError, match="occ_res"):
        Partition.make(
            [(0, 4, 0, 4)],
            [(0, 0, 0)],
            [(1, 1, 1)],
            ((0, 0, 0), (1, 1, 1)),
            occupancy=((0, 4, 2), b""),
        )


@pytest.mark.parametrize("name", ["balls_s1.nff", "teapot_s1.nff", "rings_s1.nff", "tetra_s3.nff"])
def test_skipping_empty_space_changes_nothing_but_the_passing(name, monkeypatch):
    scene = read_nff(spd_scene(name))
    runs = {}
    for skip in (True, False):
        if not skip:  # one occupied voxel: every segment goes on as it did before the map
            monkeypatch.setattr(host.planning.partition, "occupancy_map", lambda *_: EVERYWHERE)
        runs[skip] = render_mesh(scene, 2, 2, 2, 32, 32, spp=2)
    (img, totals, nodes, _), (ref, ref_totals, ref_nodes, _) = runs[True], runs[False]
    np.testing.assert_allclose(img, ref, rtol=0, atol=1e-12)
    for k in (*SPD_COUNTS, "hits", "escaped", "shadow_rays_lit"):
        assert totals[k] == ref_totals[k], k
    sent, ref_sent = (sum(n.rays_sent for n in ns) for ns in (nodes, ref_nodes))
    assert sent < 0.8 * ref_sent, (sent, ref_sent)


@pytest.mark.parametrize("name", ["balls_s1.nff", "tetra_s3.nff"])
def test_the_pre_pass_gives_the_map_where_it_lightens_the_busiest_node(name):
    # Walking the map costs (a fractal leaves many small empty cubes to step through) and
    # saves passes; on the cuts it chose, the pre-pass simulates the mesh with and without
    # the map and keeps whichever leaves the busiest node less work, and says so.
    from host.planning.balance import balanced_cuts
    from host.planning.prepass import node_costs

    scene = read_nff(spd_scene(name))
    spec = RenderSpec(
        ImageSpec(width=48, height=48).sized(scene.view), plan=MeshPlan(2, 2, 2.0, balance="cost")
    )
    cuts = balanced_cuts(scene, spec)
    busiest = {
        on: node_costs(scene, spec, cuts.xs, cuts.ys, cuts.cells, on).max() for on in (True, False)
    }
    assert cuts.occupancy == (busiest[True] <= busiest[False])
    assert cuts.report["occupancy_map"] == cuts.occupancy
    ratio = cuts.report["simulated_busiest_without_map_vs_with"]
    # cells cut by the objects carry the busiest node simulated before they are moved onto
    # linked nodes (`objectwork._placed`: only which rays are relayed changes, 1e-4 of it)
    assert ratio == pytest.approx(busiest[False] / busiest[True], rel=1e-3)
    if name == "balls_s1.nff":  # a floor and spheres: most of the scene's box is empty
        assert cuts.occupancy and ratio > 1.05, ratio


def test_the_hosts_map_is_made_once_per_scene_box_and_size():
    from unittest import mock

    from host.planning import occupancy

    scene = read_nff(spd_scene("balls_s1.nff"))
    box = scene_box(scene)
    half = (box[0], (np.asarray(box[0]) + np.asarray(box[1])) / 2)
    made = []
    real = occupancy._mapped
    with mock.patch.object(occupancy, "_mapped", lambda *a: made.append(a) or real(*a)):
        first = occupancy.occupancy_map(scene, box)
        assert occupancy.occupancy_map(scene, tuple(np.array(b) for b in box)) is first
        assert occupancy.occupancy_map(scene, box, 8**3) != first  # another size
        assert occupancy.occupancy_map(scene, half) != first  # another box
        again = read_nff(spd_scene("balls_s1.nff"))  # another scene: made anew, alike
        assert occupancy.occupancy_map(again, box) == first
    assert len(made) == 4


def _voxel_by_voxel(o, d, t0, t1, occ) -> float:
    """The first occupied voxel's entry between t0 and t1 whose marked sub-voxels the ray's
    path through it may cross, found one voxel at a time (no empty cubes, no walls kept): the
    reference `first_occupied` must agree with. The path's sub-voxels as the walk takes them:
    each half's span, widened by `mapwalk.SUB_MARGIN`."""
    from meshnode.engine.mapwalk import SUB_MARGIN
    from meshnode.engine.occupancy import SUB, SUB_RANGES

    res, lo, cell = occ.res, occ.lo, occ.cell
    i = np.clip(np.floor((o + t0 * d - lo) / cell).astype(int), 0, res - 1)
    up = (d > 0).astype(int)
    t = t0
    for _ in range(int(res.sum()) + 3):
        v = i[0] + res[0] * (i[1] + res[1] * i[2])
        walls = [
            (lo[a] + (i[a] + up[a]) * cell[a] - o[a]) / d[a] if d[a] else math.inf for a in range(3)
        ]
        t_end = min(min(walls), t1)
        if occ.clear[0, v] == 0:
            points = [
                (o + s * d - lo) / cell * SUB - i * SUB for s in (t, 0.5 * (t + t_end), t_end)
            ]
            bits = np.uint64(0)
            for a, b in ((points[0], points[1]), (points[1], points[2])):
                span = np.uint64(2**64 - 1)
                for axis in range(3):
                    first = int(min(max(min(a[axis], b[axis]) - SUB_MARGIN, 0.0), SUB - 1.0))
                    last = int(min(max(max(a[axis], b[axis]) + SUB_MARGIN, 0.0), SUB - 1.0))
                    span &= SUB_RANGES[axis, first, last]
                bits |= span
            if occ.fine[v] & bits:
                return t
        t = min(walls)
        if t > t1:
            return math.inf
        axis = int(np.argmin(walls))
        i[axis] += 1 if d[axis] > 0 else -1
        if not 0 <= i[axis] < res[axis]:
            return math.inf
    raise AssertionError("the reference walk did not end")


@pytest.mark.parametrize("name", ["rings_s1.nff", "balls_s1.nff", "tetra_s3.nff"])
def test_the_walk_stops_where_a_voxel_by_voxel_walk_does(name):
    """The walk jumps empty cubes, keeps the current voxel's walls and tests sub-voxels in
    its own units; from random points in random directions it stops where a walk of every
    voxel on the way, each tested afresh, stops (the same voxel entry, or none)."""
    scene = read_nff(spd_scene(name))
    lo, hi = scene_box(scene)
    occ = occupancy_arrays(lo, hi, *occupancy_map(scene, (lo, hi)))
    assert len(occ.fine)  # a map with sub-voxels
    rng = np.random.default_rng(7)
    n = 300
    origins = lo + rng.random((n, 3)) * (hi - lo)
    dirs = rng.normal(size=(n, 3))
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    counters = np.zeros(N_COUNTERS, np.int64)
    stopped = 0
    for o, d in zip(origins, dirs, strict=True):
        r = [1.0 / v if v != 0.0 else math.inf for v in d]
        t0, t1 = box_span(*o, *r, 0.0, math.inf, *lo, *hi)
        t = first_occupied(*o, *d, *r, t0, t1, *occ, counters)
        want = _voxel_by_voxel(o, d, t0, t1, occ)
        assert t == pytest.approx(want, rel=1e-12, abs=1e-12), (name, o, d, t, want)
        stopped += t < math.inf
    assert 0.1 * n < stopped < 0.9 * n, stopped  # walks that stop and walks that end
    assert counters[OCC_STEPS] > 2 * n  # many walks went on past their first voxel
