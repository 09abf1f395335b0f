"""Ray queries: an any-hit query (`Engine.occluded`) says a ray is blocked exactly when brute
force finds a first hit before its end, through the grid and the hierarchy, on random
layouts, a generated mesh and an SPD scene; a ray leaving a surface skips it."""

import numpy as np
import pytest

from bench.generate import tetra_triangles
from host.scene.nff import read_nff
from meshnode.engine import Engine
from tests.conftest import make_scene, spd_scene
from tests.test_grid import random_scene


def tetra_mesh():
    """A generated mesh: the recursive tetrahedron of 4^4 triangles."""
    return make_scene(triangles=[(*t, 0) for t in tetra_triangles(4)])


SCENES = {
    "random": lambda: random_scene(np.random.default_rng(11), n=60),
    "tetra mesh": tetra_mesh,
    "teapot_s1": lambda: read_nff(spd_scene("teapot_s1.nff")),
}


def random_rays(engine: Engine, rng, n: int):
    """Rays from points in and around the scene's box towards other such points."""
    lo, hi = engine.scene_lo, engine.scene_hi
    pad = 0.2 * (hi - lo)
    o = rng.uniform(lo - pad, hi + pad, (n, 3))
    d = rng.uniform(lo - pad, hi + pad, (n, 3)) - o
    return o, d


@pytest.mark.parametrize("structure", ["grid", "bvh"])
@pytest.mark.parametrize("name", sorted(SCENES))
def test_occluded_exactly_where_brute_force_hits_before_t_max(name, structure):
    scene = SCENES[name]()
    engine = Engine(scene, structure=structure)
    assert engine.structure == structure
    rng = np.random.default_rng(5)
    o, d = random_rays(engine, rng, 3000)
    t_first, _ = Engine(scene, brute=True).first_hits(o, d)
    # Ends before and beyond each first hit (far from it: no tie to round-off), some rays
    # unbounded, and ends for the rays that hit nothing.
    extent = float(np.max(engine.scene_hi - engine.scene_lo))
    t_max = np.where(
        np.isfinite(t_first),
        t_first * rng.choice([0.5, 0.9, 1.1, 2.0], len(o)),
        rng.uniform(0, 2 * extent, len(o)),
    )
    t_max[::7] = np.inf
    expected = t_first < t_max
    assert 300 < expected.sum() < len(o) - 300  # both answers well represented
    blocked = engine.occluded(o, d, t_max)
    assert blocked.dtype == bool
    np.testing.assert_array_equal(blocked, expected)
    # With t_min: blocked by a hit between it and t_max, the first hit past t_min.
    t_min = 0.3 * extent
    t_past, _ = Engine(scene, brute=True).first_hits(o, d, t_min)
    blocked = engine.occluded(o, d, t_max, t_min=t_min)
    np.testing.assert_array_equal(blocked, t_past < t_max)


@pytest.mark.parametrize("structure", ["grid", "bvh"])
def test_a_ray_leaving_a_surface_skips_it_as_brute_force_does(structure):
    scene = tetra_mesh()
    engine = Engine(scene, structure=structure)
    rng = np.random.default_rng(8)
    tris = scene.triangles
    pick = rng.integers(0, len(tris), 2000)
    w = rng.dirichlet((1, 1, 1), len(pick))
    o = np.einsum("nk,nkj->nj", w, tris["v"][pick])  # points on the triangles
    d = rng.normal(size=(len(pick), 3))
    leaving = tris["gid"][pick]
    brute = Engine(scene, brute=True).occluded(o, d, np.inf, leaving=leaving)
    blocked = engine.occluded(o, d, np.inf, leaving=leaving)
    np.testing.assert_array_equal(blocked, brute)
    assert 200 < blocked.sum() < len(o) - 200
    # A lone triangle never blocks the rays leaving it, either way they go.
    lone = make_scene(triangles=[((-1, -1, 0), (1, -1, 0), (0, 1, 0), 0)])
    starts = np.zeros((2, 3))
    up_down = np.array([[0.0, 0, 1], [0.0, 0, -1]])
    assert not Engine(lone, structure=structure).occluded(starts, up_down, 5.0, leaving=0).any()


def test_refused_rays_are_named_and_t_max_broadcasts():
    engine = Engine(make_scene(spheres=[((0, 0, 0), 1.0, 0)]), structure="bvh")
    o = np.array([[0.0, 0, -5], [0.0, 0, -5]])
    d = np.array([[0.0, 0, 1], [0.0, 0, 0]])
    with pytest.raises(ValueError, match="ray 1"):
        engine.occluded(o, d, 10.0)
    np.testing.assert_array_equal(engine.occluded(o[:1], d[:1], [3.0]), [False])
    np.testing.assert_array_equal(engine.occluded(o[:1], d[:1], 4.5), [True])
