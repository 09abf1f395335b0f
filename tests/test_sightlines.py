"""The occupancy map seen from the eye and the lights (`meshnode.engine.sightlines`): no eye ray
meets a marked sub-voxel nearer than its block's bound and no segment told clear from its
light meets one (brute force over every sub-voxel); routing eye rays from the eye's map starts
each ray's work where the walk from the scene's box does or later, never past a marked
sub-voxel it meets; a mesh with either renders the same image and counts as without it."""

import itertools
import math

import numpy as np
import pytest

import meshnode.engine.engine as engine_module
import meshnode.mesh.node
from host.planning.cells import scene_box
from host.planning.occupancy import occupancy_map
from host.scene.nff import read_nff
from meshnode.engine.camera import eye_rays
from meshnode.engine.lightmaps import (
    LIGHT_MAP_BYTES,
    NO_LIGHT_MAPS,
    _faces,
    face_blocks,
    light_clear,
    light_maps,
)
from meshnode.engine.locator import cell_locator
from meshnode.engine.mapbounds import marked_box
from meshnode.engine.occupancy import SUB, occupancy_arrays
from meshnode.engine.routing import routed
from meshnode.engine.sightlines import NO_EYE_MAP, eye_map
from protocols.render import ImageSpec
from protocols.scene import View
from tests.conftest import spd_scene
from tests.meshsim import render_mesh
from tests.test_mesh_algorithm import SPD_COUNTS


def _views(scene, lo, hi):
    """The scene's own view, one straight down an axis through the box's centre (rays along
    voxel walls), one from inside the box (voxels behind the eye), and one level, just above
    the box's top (its upper half sees nothing; the box reaches behind the eye's plane)."""
    centre = (lo + hi) / 2
    size = float(np.max(hi - lo))
    level = (centre[0], centre[1], hi[2] + 0.02 * size)
    return [
        scene.view,
        View(tuple(centre - (0, 0, 2 * size)), tuple(centre), (0, 1, 0), 40.0),
        View(tuple(centre + 0.1 * (hi - lo)), tuple(hi), (0, 0, 1), 70.0),
        View(level, (level[0] + 1.0, level[1] + 0.5, level[2]), (0, 0, 1), 60.0),
    ]


def _cells(lo, hi):
    """A 3 x 2 x 1 cut of the box (cells as a mesh's tile the scene)."""
    xs, ys = np.linspace(lo[0], hi[0], 4), np.linspace(lo[1], hi[1], 3)
    los = np.array([(xs[i], ys[j], lo[2]) for j in range(2) for i in range(3)])
    his = np.array([(xs[i + 1], ys[j + 1], hi[2]) for j in range(2) for i in range(3)])
    return los, his


def _marked_boxes(occ):
    """(lo, hi) of every marked sub-voxel of the map (each occupied voxel's 4x4x4 sub-voxels
    its mask sets; the whole voxel where the map has no masks)."""
    res = occ.res
    v = np.flatnonzero(occ.clear[0] == 0)
    index = np.stack([v % res[0], (v // res[0]) % res[1], v // (res[0] * res[1])], axis=1)
    if not occ.fine.shape[0]:
        return occ.lo + index * occ.cell, occ.lo + (index + 1) * occ.cell
    bits = (occ.fine[v][:, None] >> np.arange(SUB**3, dtype=np.uint64)) & np.uint64(1)
    which, bit = np.nonzero(bits)
    sub = np.stack([bit % SUB, bit // SUB % SUB, bit // SUB**2], axis=1)
    corner = occ.lo + (index[which] + sub / SUB) * occ.cell
    return corner, corner + occ.cell / SUB


def _first_marked_brute(rays, occ):
    """Per ray the least t at which it enters a marked sub-voxel (slab test against every
    one), inf where it meets none."""
    vlo, vhi = _marked_boxes(occ)
    out = np.full(len(rays), math.inf)
    with np.errstate(divide="ignore", invalid="ignore"):
        for i, r in enumerate(rays):
            inv = 1.0 / r["d"]
            a, b = (vlo - r["o"]) * inv, (vhi - r["o"]) * inv
            near = np.nanmax(np.minimum(a, b), axis=1)
            far = np.nanmin(np.maximum(a, b), axis=1)
            hit = (near <= far) & (far >= r["t_min"])
            if hit.any():
                out[i] = max(float(near[hit].min()), r["t_min"])
    return out


@pytest.mark.parametrize("name", ["tetra_s3.nff", "gears_s1.nff"])
def test_each_voxel_s_box_of_marked_sub_voxels_bounds_exactly_those_sub_voxels(name):
    scene = read_nff(spd_scene(name))
    lo, hi = scene_box(scene)
    occ = occupancy_arrays(lo, hi, *occupancy_map(scene, (lo, hi), voxels=16**3))
    boxes = marked_box(occ.clear.shape[1], occ.fine)
    vlo, vhi = _marked_boxes(occ)  # every marked sub-voxel, by brute force over the bits
    corner = (vlo - occ.lo) / occ.cell
    voxel = np.floor(corner + 1e-9).astype(np.int64)  # the voxel each sub-voxel lies in
    v = voxel[:, 0] + occ.res[0] * (voxel[:, 1] + occ.res[1] * voxel[:, 2])
    frac_lo, frac_hi = corner - voxel, corner - voxel + 1 / SUB
    assert len(np.unique(v)) > 10
    for u in np.unique(v):
        mine = v == u
        np.testing.assert_allclose(boxes[:3, u], frac_lo[mine].min(axis=0), atol=1e-9)
        np.testing.assert_allclose(boxes[3:, u], frac_hi[mine].max(axis=0), atol=1e-9)
    empty = np.setdiff1d(np.arange(occ.clear.shape[1]), v)  # no mask: the whole voxel
    assert (boxes[:3, empty] == 0).all() and (boxes[3:, empty] == 1).all()


@pytest.mark.parametrize("name", ["tetra_s3.nff", "balls_s1.nff", "mount_s1.nff", "rings_s1.nff"])
def test_no_eye_ray_meets_a_marked_sub_voxel_nearer_than_its_bound(name):
    scene = read_nff(spd_scene(name))
    lo, hi = scene_box(scene)
    occ = occupancy_arrays(lo, hi, *occupancy_map(scene, (lo, hi), voxels=12**3))
    rng = np.random.default_rng(3)
    met = open_rays = 0
    for view in _views(scene, lo, hi):
        image = ImageSpec(width=40, height=30, spp=4)
        eye, reason = eye_map(occ, view, image)
        assert eye.near.size and "blocks" in reason
        rays = eye_rays(view, image)
        rays = rays[rng.choice(len(rays), 600, replace=False)]
        bound = _bound(eye, rays)
        first = _first_marked_brute(rays, occ)
        assert (first >= bound).all(), (view, first[first < bound], bound[first < bound])
        met += np.isfinite(first).sum()
        open_rays += np.isinf(bound).sum()
    assert met > 100 and open_rays > 100, "nothing tested"


@pytest.mark.parametrize(
    "name", ["tetra_s3.nff", "balls_s1.nff", "mount_s1.nff", "teapot_s1.nff", "gears_s1.nff"]
)
@pytest.mark.parametrize("spd", [False, True])
def test_routing_eye_rays_with_the_eye_map_starts_their_work_in_time(name, spd):
    """Each ray's work starts never past the first marked sub-voxel it meets (brute force),
    in the cell holding that point: seeing the cells, where it enters the cell its block
    sees nearest before any other's sub-voxels; else where the walk from its block's bound
    starts it (for many, later than the walk from the scene's box). A ray of a block that
    sees no marked sub-voxel is marked t_min inf (a kernel ends it at once) and meets none,
    and the map spares walks (such blocks)."""
    scene = read_nff(spd_scene(name))
    lo, hi = scene_box(scene)
    occ = occupancy_arrays(lo, hi, *occupancy_map(scene, (lo, hi), voxels=16**3))
    los, his = _cells(lo, hi)
    loc = cell_locator(los, his)
    opens, later = [], 0
    for view, cells in itertools.product(_views(scene, lo, hi), (None, (los, his))):
        image = ImageSpec(width=48, height=40, spp=1 if spd else 9, spd=spd)
        eye, _ = eye_map(occ, view, image, cells)
        opens.append(np.mean(np.isinf(eye.near)))
        rays = eye_rays(view, image)
        box = (np.asarray(lo, float), np.asarray(hi, float))
        got, starts, lost = routed(rays, True, 2, *box, occ, los, his, loc, eye)
        want, _, want_lost = routed(rays, True, 2, *box, occ, los, his, loc, NO_EYE_MAP)
        assert lost == want_lost == 0
        cell = np.repeat(np.arange(len(los)), np.diff(starts))
        got_order, want_order = np.argsort(got["pixel"]), np.argsort(want["pixel"])
        got, cell, want = got[got_order], cell[got_order], want[want_order]
        ended = got["t_min"] == np.inf
        assert np.array_equal(ended, np.isinf(_bound(eye, got))), (name, view)
        assert (cell[ended] == 2).all(), "a ray that meets nothing is the fallback's"
        later += int((got["t_min"] > want["t_min"])[~ended].sum())
        # against brute force over every sub-voxel, on a sample of the rays
        some = np.random.default_rng(len(opens)).choice(len(got), 250, replace=False)
        got, cell, ended = got[some], cell[some], ended[some]
        first = _first_marked_brute(got, occ)
        assert np.isinf(first[ended]).all(), "a ray ended meets no marked sub-voxel"
        t = got["t_min"][~ended]
        assert (t <= first[~ended]).all(), (name, view)
        at = got["o"][~ended] + got["d"][~ended] * t[:, None]
        reach = 1e-9 * (np.abs(at) + 1.0)
        c = cell[~ended]
        inside = (at >= los[c] - reach) & (at <= his[c] + reach)
        meets = np.isfinite(first[~ended])
        assert inside[meets].all(), (name, view)  # taken on by the cell holding its start
    assert later > 0, "the sub-voxels' boxes started no ray later than the walk"
    # The level view's upper half sees nothing, although the box reaches behind the eye's
    # plane: the voxels there bound only the blocks whose rays can reach them.
    assert max(opens[:4]) > 0 and opens[6] >= 0.45, opens


@pytest.mark.parametrize("name", ["tetra_s3.nff", "balls_s1.nff"])
def test_a_mesh_routing_with_the_eye_map_renders_as_without_passing_no_more(name, monkeypatch):
    scene = read_nff(spd_scene(name))
    node, made = meshnode.mesh.node, []
    own = node.node_eye_map
    runs = {}
    # the eye map alone: which node makes an eye ray is `test_claims`'s
    monkeypatch.setattr(node, "node_claims", lambda *a: (None, "off"))
    for use in (True, False):
        made_here = (lambda *a: made.append(own(*a)) or made[-1]) if use else None
        monkeypatch.setattr(node, "node_eye_map", made_here or (lambda *a: (NO_EYE_MAP, "off")))
        runs[use] = render_mesh(scene, 2, 2, 1, 32, 32, spp=4, mode="object")
    (img, totals, nodes, _), (ref, ref_totals, ref_nodes, _) = runs[True], runs[False]
    # the eye rays the map shows meet nothing are not made (`meshnode.engine.sky`), so the
    # batches differ and deposits from several nodes may reach a pixel in another order
    np.testing.assert_allclose(img, ref, rtol=0, atol=1e-12)
    for k in (*SPD_COUNTS, "hits", "escaped", "shadow_rays_lit"):
        assert totals[k] == ref_totals[k], k
    assert sum(n.rays_sent for n in nodes) <= sum(n.rays_sent for n in ref_nodes)
    assert made and all(eye.near.size for eye, _ in made), "the mesh did not use the map"


def _bound(eye, rays):
    """Each eye ray's bound in the `EyeMap` eye: its block's `near`, found from RAY.pixel
    here in numpy, apart from the kernels' `eye_cell`."""
    g = rays["pixel"] // eye.per_cell
    return eye.near[(g // eye.columns) // eye.side * eye.blocks_x + g % eye.columns // eye.side]


def _entry(rays, los, his):
    """Each ray's t entering its box (numpy slabs; inf where it misses)."""
    o, d = rays["o"], rays["d"]
    with np.errstate(divide="ignore", invalid="ignore"):
        a, b = (los - o) / d, (his - o) / d
    near = np.nanmax(np.minimum(a, b), axis=1)
    far = np.nanmin(np.maximum(a, b), axis=1)
    near = np.maximum(near, rays["t_min"])
    return np.where(near <= far, near, np.inf)


def _meets_brute(a, b, occ, boxes):
    """Whether the segment a..b meets any of `boxes` (the map's marked sub-voxels: slab test
    against every one)."""
    vlo, vhi = boxes
    d = b - a
    with np.errstate(divide="ignore", invalid="ignore"):
        t0, t1 = (vlo - a) / d, (vhi - a) / d
        near = np.nanmax(np.where(d == 0, -np.inf, np.minimum(t0, t1)), axis=1)
        far = np.nanmin(np.where(d == 0, np.inf, np.maximum(t0, t1)), axis=1)
        inside = ((d != 0) | ((a >= vlo) & (a <= vhi))).all(axis=1)
    return bool(((near <= far) & (far >= 0) & (near <= 1) & inside).any())


@pytest.mark.parametrize("name", ["balls_s1.nff", "rings_s1.nff", "gears_s1.nff", "tetra_s3.nff"])
def test_a_segment_told_clear_from_its_light_meets_no_marked_sub_voxel(name):
    """Brute force: lights (the scene's, and points inside its box) to random points of the
    box; a segment `light_clear` calls clear meets no marked sub-voxel, and many are clear."""
    scene = read_nff(spd_scene(name))
    lo, hi = (np.asarray(b, float) for b in scene_box(scene))
    occ = occupancy_arrays(lo, hi, *occupancy_map(scene, (lo, hi), voxels=12**3))
    rng = np.random.default_rng(5)
    points = np.vstack([scene.lights["pos"], lo + rng.random((2, 3)) * (hi - lo)])
    maps = light_maps(occ, points)
    assert maps.shape == (len(points), 6 * face_blocks(len(points)) ** 2)
    told, boxes = 0, _marked_boxes(occ)
    for li, light in enumerate(points):
        for x in lo + rng.random((150, 3)) * (hi - lo):
            if light_clear(maps, li, *light, *x):
                told += 1
                assert not _meets_brute(light, x, occ, boxes), (light, x)
    assert told > 10, told  # not vacuous


def test_the_lights_maps_fit_their_bytes_and_only_shrink_a_bound():
    """Any number of lights: the maps take at most LIGHT_MAP_BYTES (past the least blocks a
    face), as float32 bounds each at most the float64 one `_faces` made, and as close."""
    scene = read_nff(spd_scene("balls_s1.nff"))
    lo, hi = (np.asarray(b, float) for b in scene_box(scene))
    occ = occupancy_arrays(lo, hi, *occupancy_map(scene, (lo, hi), voxels=12**3))
    rng = np.random.default_rng(3)
    for n in (1, 3, 40, 300):
        points = lo + rng.random((n, 3)) * (hi - lo) * 1.5
        maps = light_maps(occ, points)
        blocks = face_blocks(n)
        assert maps.dtype == np.float32 and maps.shape == (n, 6 * blocks**2)
        assert maps.nbytes <= LIGHT_MAP_BYTES or blocks == 16, (n, maps.nbytes)
        exact = _faces(
            occ.clear[0],
            marked_box(occ.clear.shape[1], occ.fine),
            occ.lo,
            occ.cell,
            occ.res,
            points[0],
            blocks,
        )
        assert (maps[0] <= exact).all()
        finite = np.isfinite(exact)
        assert np.isinf(maps[0][~finite]).all()
        np.testing.assert_allclose(maps[0][finite], exact[finite], rtol=1e-6)


@pytest.mark.parametrize("name", ["balls_s1.nff", "rings_s1.nff"])
def test_shadow_rays_clear_from_their_light_end_without_a_walk(name, monkeypatch):
    """A mesh with the lights' maps: the same image and counts as without, fewer walks."""
    scene = read_nff(spd_scene(name))
    runs = {}
    for use in (True, False):
        if not use:
            monkeypatch.setattr(engine_module, "light_maps", lambda occ, lights: NO_LIGHT_MAPS)
        runs[use] = render_mesh(scene, 2, 2, 1, 32, 32, spp=4, mode="object")
    (img, totals, _, _), (ref, ref_totals, _, _) = runs[True], runs[False]
    assert img.tobytes() == ref.tobytes()
    for k in (*SPD_COUNTS, "hits", "escaped", "shadow_rays_lit", "ray_segments"):
        assert totals[k] == ref_totals[k], k
    assert totals["occupancy_walks"] < 0.9 * ref_totals["occupancy_walks"]
