"""The bounding volume hierarchy: first hits equal brute force on hard layouts, every leaf a run
of one kind's ids within the leaf cap, packets of rays find exactly what single rays find, and
the engine's choice between it and the grid."""

import numpy as np
import pytest

from host.scene.nff import read_nff
from meshnode.engine import Engine
from meshnode.engine.bvh import LANES, LEAF_BITS, LEAF_CAP, NODE_COLS, REF_COL
from meshnode.engine.camera import eye_rays
from meshnode.engine.rows import PACKET
from protocols.dtypes import EYE, RAY, SHADOW
from protocols.render import ImageSpec
from tests.conftest import make_scene, spd_scene
from tests.test_grid import assert_same_hits, random_scene


def leaves(engine: Engine) -> list[tuple[int, int]]:
    """(first local id, count) of every leaf the hierarchy's nodes refer to."""
    refs = engine.bvh_arrays.ref.reshape(-1, NODE_COLS)[:, REF_COL : REF_COL + LANES].ravel()
    packed = ~refs[refs < 0]
    return [(int(p >> LEAF_BITS), int(p & LEAF_CAP)) for p in packed]


def assert_hits_as_brute_force(scene, engine: Engine, seed: int, n: int, spread, least: int):
    """`n` random rays from [-spread, spread]^3 toward near the origin hit, through `engine`,
    what brute force hits: the same objects at the same distances, bit for bit (more than
    `least` of them hit something, so the check is not of misses alone)."""
    rng = np.random.default_rng(seed)
    o = rng.uniform(-spread, spread, (n, 3))
    d = rng.uniform(-0.5, 0.5, (n, 3)) - o
    t_ref, g_ref = Engine(scene, brute=True).first_hits(o, d)
    assert (g_ref >= 0).sum() > least
    t, g = engine.first_hits(o, d)
    np.testing.assert_array_equal(g, g_ref)
    np.testing.assert_array_equal(t, t_ref)


def test_every_leaf_is_a_run_of_one_kind_and_every_object_is_in_one_leaf():
    engine = Engine(random_scene(np.random.default_rng(4), n=80), structure="bvh")
    off = engine.tables.offsets
    seen = np.zeros(engine.tables.n, int)
    for first, count in leaves(engine):
        if count:
            kind = np.searchsorted(off, first, side="right") - 1
            assert first + count <= off[kind + 1]  # one kind: a run inside its id range
            seen[first : first + count] += 1
    np.testing.assert_array_equal(seen, 1)


def test_objects_sharing_one_centre_split_into_capped_leaves_and_hit_as_brute_force():
    # 40 concentric spheres and 40 copies of one triangle: no centroid split exists.
    spheres = [((0, 0, 0), 0.1 + 0.05 * i, 0) for i in range(40)]
    tris = [((-1, -1, 0), (1, -1, 0), (0, 1, 0), 0)] * 40
    scene = make_scene(spheres=spheres, triangles=tris)
    engine = Engine(scene, structure="bvh")
    assert max(c for _, c in leaves(engine)) <= LEAF_CAP
    assert_hits_as_brute_force(scene, engine, seed=2, n=300, spread=4, least=100)


def test_empty_and_single_object_nodes():
    o, d = np.array([[0.0, 0, -5]]), np.array([[0.0, 0, 1]])
    t, g = Engine(make_scene(), structure="bvh").first_hits(o, d)
    assert g[0] == -1 and t[0] == np.inf
    t, g = Engine(make_scene(spheres=[((0, 0, 0), 1.0, 0)]), structure="bvh").first_hits(o, d)
    assert g[0] == 0 and t[0] == 4.0


def test_auto_takes_the_structure_expected_sooner_and_flags_force_either():
    # (tests/test_structure_choice.py: how the render's ray count and build times decide)
    tetra = Engine(read_nff(spd_scene("tetra_s3.nff")))
    estimates = tetra.stats["structure_estimates"]
    assert tetra.structure == "bvh"
    assert estimates["bvh"]["total_seconds"] < estimates["grid"]["total_seconds"]
    # (its figures, or where the grid could not win the grid's lower bound's)
    reason = tetra.stats["structure_reason"]
    assert "the hierarchy builds and traces sooner" in reason or (
        "sooner than the grid could be" in reason and estimates["grid"]["lower_bound"]
    )
    for flag in ("grid", "bvh"):
        forced = Engine(read_nff(spd_scene("tetra_s3.nff")), structure=flag)
        assert forced.structure == flag and forced.stats["structure_estimates"] is None
        assert forced.stats["structure_reason"] == f"forced by flag ({flag})"


def test_directions_that_are_zero_or_not_finite_are_refused_by_index():
    engine = Engine(make_scene(spheres=[((0, 0, 0), 1.0, 0)]))
    o = np.zeros((3, 3))
    d = np.array([[0.0, 0, 1], [0.0, 0, 0], [1.0, 0, 0]])
    try:
        engine.first_hits(o, d)
    except ValueError as e:
        assert str(e).startswith("ray 1:")
    else:
        raise AssertionError("a zero direction was traced")
    # Huge but finite directions are scaled, not overflowed.
    t, g = engine.first_hits(np.array([[0.0, 0, -5]]), np.array([[0.0, 0, 1e300]]))
    assert g[0] == 0 and t[0] == 4.0


def test_random_layouts_equal_brute_force():
    for seed in (11, 12, 13):
        rng = np.random.default_rng(seed)
        scene = random_scene(rng, n=50)
        o = rng.uniform(-8, 8, (300, 3))
        d = rng.uniform(-5, 5, (300, 3)) - o
        t_ref, g_ref = Engine(scene, brute=True).first_hits(o, d)
        t, g = Engine(scene, structure="bvh").first_hits(o, d)
        assert_same_hits(t_ref, g_ref, t, g)


def test_extreme_coordinates_build_and_hit_as_brute_force():
    # Centres 5e-324 apart (a subnormal extent: a bin scale of inf) and objects near 1e100:
    # binning must stay inside its bins and the hits equal brute force.
    tiny = [((0.0, 0.0, 5e-324 * i), 1.0, 0) for i in range(20)]
    far = [((1e100, 1e100 * (1 + 1e-15 * i), 0.0), 1e90, 0) for i in range(20)]
    scene = make_scene(spheres=tiny + far)
    engine = Engine(scene, structure="bvh")
    o = np.array([[0.0, 0.0, -5.0], [1e100, 1e100, -1e91], [3.0, 3.0, 3.0]])
    d = np.array([[0.0, 0.0, 1.0], [0.0, 0.0, 1.0], [1.0, 0.0, 0.0]])
    t_ref, g_ref = Engine(scene, brute=True).first_hits(o, d)
    t, g = engine.first_hits(o, d)
    np.testing.assert_array_equal(g, g_ref)
    np.testing.assert_array_equal(t, t_ref)
    assert g[0] >= 0 and g[1] >= 20 and g[2] == -1


def mixed_batch(scene, lo, hi, rng, n_random=2001):
    """A batch of a scene's eye rays (coherent neighbours) then random rays from random points
    in the box lo, hi (incoherent, some starting inside objects), with shadow rays among
    them (not walked in packets) and a length that is no multiple of the packet size."""
    eye = eye_rays(scene.view, ImageSpec(width=41, height=37, spd=True))
    rays = np.zeros(n_random, RAY)
    rays["o"] = rng.uniform(lo, hi, (n_random, 3))
    d = rng.normal(size=(n_random, 3))
    rays["d"] = d / np.linalg.norm(d, axis=1)[:, None]
    rays["t_max"] = np.where(rng.random(n_random) < 0.3, rng.uniform(0.1, 5.0, n_random), np.inf)
    rays["w"], rays["origin"], rays["depth"], rays["pixel"] = 1.0, -1, 1, np.arange(n_random)
    rays["kind"] = np.where(rng.random(n_random) < 0.2, SHADOW, EYE)
    return np.concatenate([eye, rays])


@pytest.mark.parametrize("name", ["tetra_s1.nff", "teapot_s1.nff", "gears_s1.nff"])
def test_packets_of_rays_find_exactly_what_single_rays_find(name):
    """A batch's own rays walk the hierarchy in packets (`bvh.packet_walk`), on one node and
    on an image-space node (its box the scene's); with packets off each walks alone: colours
    and counts must be the same to the last bit, on coherent eye rays and scattered ones."""
    scene = read_nff(spd_scene(name))
    engine = Engine(scene, structure="bvh")
    single = Engine(scene, structure="bvh", packets=False)
    assert engine.stats["packet"] == 8 and single.stats["packet"] == 1
    rays = mixed_batch(scene, engine.scene_lo, engine.scene_hi, np.random.default_rng(7))
    rgb_ref, counts_ref = single.trace(rays)
    assert counts_ref["eye_hits"] > 100
    keys = ("eye_hits", "shadow_rays", "shadow_rays_blocked", "reflected_rays", "ray_segments")
    rgb, counts = engine.trace(rays)
    rgb_node, counts_node, passed = engine.trace_node(rays)
    assert len(passed) == 0  # nothing leaves a box that is the whole scene
    for got, n in ((rgb, counts), (rgb_node, counts_node)):
        np.testing.assert_array_equal(got, rgb_ref)
        assert {k: n[k] for k in keys} == {k: counts_ref[k] for k in keys}


@pytest.mark.parametrize("name", ["tetra_s1.nff", "teapot_s1.nff", "gears_s1.nff"])
def test_an_object_space_node_walking_in_packets_finds_what_single_rays_find(name):
    """On a node holding half the scene, packets and single rays give the same colours,
    counts and rays passed on, to the bit: a packet's hit beyond the box is dropped as a
    single walk's is, and rays starting outside the box go on before either is read. The
    batch leads with eye rays whose directions have components exactly 0 (walked in packets,
    whose reciprocals their spans reuse: inf there, as a division-free span must give)."""
    from host.planning.clip import holders
    from host.scene.subset import subset
    from meshnode.engine.locator import owners

    scene = read_nff(spd_scene(name))
    whole = Engine(scene, structure="bvh")
    lo, hi = whole.scene_lo, whole.scene_hi
    axis = int(np.argmax(hi - lo))
    box_hi = hi.copy()
    box_hi[axis] = (lo[axis] + hi[axis]) / 2
    held = subset(scene, holders(scene, lo[None], box_hi[None])[0])
    options = dict(structure="bvh", box=(lo, box_hi), scene_box=(lo, hi))
    engine, single = Engine(held, **options), Engine(held, packets=False, **options)
    assert engine.stats["packet"] == 8 and single.stats["packet"] == 1
    rays = mixed_batch(scene, lo, hi, np.random.default_rng(3))
    axial = rays[:96].copy()
    axial["d"][:32, 0] = 0.0
    axial["d"][32:64, 1] = 0.0
    axial["d"][64:, :2] = 0.0
    axial["d"] /= np.linalg.norm(axial["d"], axis=1)[:, None]
    rays = np.concatenate([axial, rays])
    owners(rays, lo[None], box_hi[None])  # eye rays start where they enter the box, as made
    rgb_ref, counts_ref, passed_ref = single.trace_node(rays)
    rgb, counts, passed = engine.trace_node(rays)
    assert counts_ref["eye_hits"] > 50 and len(passed_ref) > 50
    np.testing.assert_array_equal(rgb, rgb_ref)
    assert passed.tobytes() == passed_ref.tobytes()
    keys = (
        "eye_hits",
        "shadow_rays",
        "shadow_rays_blocked",
        "reflected_rays",
        "ray_segments",
        "rays_forwarded",
    )
    assert {k: counts[k] for k in keys} == {k: counts_ref[k] for k in keys}


@pytest.mark.parametrize("name", ["teapot_s1.nff", "gears_s1.nff"])
def test_a_packet_s_steps_for_rays_that_entered_are_their_own_walks(name):
    """`packet_idle_steps` counts the steps a packet took for rays that had not entered the
    node: without them, a batch's steps are what its rays walk alone (the pre-pass's
    estimate of one node's tracing rests on it, `prepass.walked_units`). Eight copies of
    each ray make packets that walk as one ray: no idle step, the very steps of single
    walks. Scattered rays idle; less those, within 1% of single walks (a packet's rays
    meet nodes in the packet's order, so a ray's bound can fall later than alone)."""
    scene = read_nff(spd_scene(name))
    engine = Engine(scene, structure="bvh")
    single = Engine(scene, structure="bvh", packets=False)
    rays = mixed_batch(scene, engine.scene_lo, engine.scene_hi, np.random.default_rng(7))
    _, alone = single.trace(rays)
    _, packed = engine.trace(rays)
    assert alone["packet_idle_steps"] == 0 and packed["packet_idle_steps"] > 0
    own = packed["voxel_steps"] - packed["packet_idle_steps"]
    assert abs(own - alone["voxel_steps"]) <= 0.01 * alone["voxel_steps"]
    copies = np.repeat(rays, PACKET)
    _, alone = single.trace(copies)
    _, packed = engine.trace(copies)
    assert packed["packet_idle_steps"] == 0
    assert packed["voxel_steps"] == alone["voxel_steps"]
