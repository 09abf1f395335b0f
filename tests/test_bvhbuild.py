"""The hierarchy's build (`bvhbuild`): a valid tree on random, clustered, degenerate and mixed
layouts (every object in exactly one leaf, each node's box holding its objects' and children's
boxes, leaves within the cap and of one kind, children where the depth-first layout puts them),
and first hits on a generated mesh equal brute force's."""

import numpy as np
import pytest

from bench.embree import flat_scene
from bench.generate import tetra_triangles
from meshnode.engine import Engine
from meshnode.engine.bvh import LEAF_CAP
from meshnode.engine.bvhbuild import Bvh, build_tree
from protocols.scene import View
from tests.test_bvh import assert_hits_as_brute_force


def check_tree(lo, hi, off):
    """Build over boxes lo, hi (n, 3) with kind offsets off and assert the tree's invariants."""
    box, meta, prims = build_tree(lo, hi, np.asarray(off, np.int64))
    n = len(lo)
    assert sorted(prims.tolist()) == list(range(n))
    held = np.zeros(n, int)  # leaves holding each position of prims
    # Walk from the root: each node's objects are within its box, a child's box within its
    # parent's, and every node is reached exactly once.
    reached = np.zeros(len(meta), int)
    todo = [0]
    while todo:
        k = todo.pop()
        reached[k] += 1
        if meta[k, 2] < 0:
            first, count = meta[k, 0], meta[k, 1]
            assert 1 <= count <= LEAF_CAP or n == 0
            held[first : first + count] += 1
            ids = prims[first : first + count]
            assert np.all(lo[ids] >= box[k, :3]) and np.all(hi[ids] <= box[k, 3:])
            kinds = np.searchsorted(off, ids, side="right")
            assert len(set(kinds.tolist())) <= 1  # one kind per leaf
        else:
            for child in (k + 1, meta[k, 0]):
                assert child > k
                assert np.all(box[child, :3] >= box[k, :3]) and np.all(box[child, 3:] <= box[k, 3:])
                todo.append(child)
    np.testing.assert_array_equal(reached, 1)
    np.testing.assert_array_equal(held, 1)
    return box, meta


def boxes(centres, sizes):
    return centres - sizes, centres + sizes


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_random_clustered_and_mixed_layouts_build_valid_trees(seed):
    rng = np.random.default_rng(seed)
    n = 3000
    # clusters of small boxes, a few huge ones (ground planes), duplicates, flat and zero boxes
    centres = rng.normal(0, 1, (n, 3)) * rng.choice([0.01, 1.0, 100.0], (n, 1))
    sizes = rng.uniform(0, 0.1, (n, 3))
    sizes[rng.random(n) < 0.01] = 1000.0
    sizes[rng.random(n) < 0.05, 2] = 0.0
    centres[n // 2 : n // 2 + 40] = centres[n // 2]
    lo, hi = boxes(centres, sizes)
    cuts = np.sort(rng.integers(0, n, 3))
    check_tree(lo, hi, [0, *cuts.tolist(), n])


def test_coincident_tiny_and_huge_coordinates_build_valid_trees():
    for centres in (
        np.zeros((100, 3)),  # nothing to split by: halves, then capped leaves
        np.arange(100)[:, None] * np.array([[5e-324, 0.0, 0.0]]),  # subnormal extents
        1e300 * (1 + 1e-15 * np.arange(100))[:, None] * np.ones((1, 3)),
    ):
        lo, hi = boxes(centres, np.full((100, 3), 1e-3 * (np.abs(centres).max() + 1)))
        check_tree(lo, hi, [0, 60, 60, 100, 100])
    for n in (0, 1, 2, 3):
        lo = np.arange(3 * n, dtype=float).reshape(n, 3)
        check_tree(lo, lo + 1, [0, n, n, n, n])


def test_generated_mesh_first_hits_equal_brute_force():
    """A 16,384-triangle tetrahedron: random rays through it hit what brute force hits, the
    nearest at the same distance and, on equal distances, the lower id."""
    scene = flat_scene(View((2.1, 1.3, 1.7), (0, 0, 0), (0, 0, 1), 45.0), tetra_triangles(7))
    engine = Engine(scene, structure="bvh")
    assert engine.structure == "bvh" and engine.stats["structure_build_seconds"] > 0
    assert_hits_as_brute_force(scene, engine, seed=5, n=3000, spread=1.5, least=1000)


def test_stats_report_the_tree():
    """A full binary tree over every object once, its leaves within the cap."""
    lo = np.random.default_rng(3).uniform(-1, 1, (500, 3))
    bvh = Bvh(lo, lo + 0.01, np.array([0, 0, 500, 500, 500]))
    s = bvh.stats
    assert s["leaves"] == s["inner_nodes"] + 1  # a full binary tree
    assert s["nodes"] == len(bvh.nodes) and s["inner_nodes"] / 3 <= s["nodes"] < s["inner_nodes"]
    assert s["max_leaf"] <= LEAF_CAP and s["build_seconds"] > 0
    assert sorted(bvh.order.tolist()) == list(range(500))
