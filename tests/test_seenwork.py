"""The first guess of where a render's work lies (`host.planning.seenwork`): where the coarse
image's eye rays first meet an occupied voxel, checked against a slab test of the objects'
bounds in NumPy, and a guess the re-cuts start from."""

import numpy as np

from host.planning.cells import scene_box
from host.planning.prepass import coarse_spec
from host.planning.seenwork import SEEN, first_guess, seen_starts
from host.scene.nff import parse_nff
from meshnode.engine.camera import eye_rays
from protocols.render import ImageSpec, MeshPlan, RenderSpec

# two spheres with a gap between them, seen from the front: rays through the gap cross the
# scene's box and meet nothing
SCENE = """v
from 2 0 -10
at 2 0 0
up 0 1 0
angle 30
hither 1
resolution 64 64
l 2 5 -10
f 1 1 1 1 0 0 0 0
s 0 0 0 1
s 4 0 0 1
"""


def _sphere_hits(o, d, centre, radius) -> np.ndarray:
    """Whether each ray (o, d) meets the sphere ahead of its origin (d need not be unit)."""
    w = o - np.asarray(centre, float)
    a, b, c = (d * d).sum(axis=1), (w * d).sum(axis=1), (w * w).sum(axis=1) - radius**2
    disc = b * b - a * c
    return (disc >= 0) & (-b + np.sqrt(np.maximum(disc, 0)) >= 0)


def test_seen_starts_count_the_rays_meeting_an_object_at_its_near_side():
    scene = parse_nff(SCENE)
    spec = RenderSpec(ImageSpec(width=64, height=64), plan=MeshPlan(2, 2, balance="objects"))
    box = scene_box(scene)
    bins = 8
    seen = seen_starts(scene, spec, box, bins)
    width, height = coarse_spec(spec).image.size
    rays = eye_rays(scene.view, ImageSpec(width=width, height=height))
    o, d = rays["o"], rays["d"]
    # the map marks the voxels the spheres' surfaces reach, so a ray meeting a sphere counts,
    # and one missing it by more than a map voxel's diagonal (64^3 over the box) does not
    voxel = (box[1] - box[0]) / 40.0  # larger than a map voxel (about 6 / 133) on every axis
    centres, reach = ((0, 0, 0), (4, 0, 0)), float(np.linalg.norm(voxel))
    least = sum(_sphere_hits(o, d, c, 1.0) for c in centres) > 0
    most = sum(_sphere_hits(o, d, c, 1.0 + reach) for c in centres) > 0
    assert least.sum() <= seen.sum() <= most.sum()
    assert 0 < least.sum() < len(rays)  # some rays pass through the gap or beside
    # no start lies in the gap between the spheres (a ray through it may meet a sphere's
    # side further in, so starts are not all on the front face)
    edges = np.linspace(box[0][0], box[1][0], bins + 1)
    gap = (edges[:-1] >= 1.0 + voxel[0]) & (edges[1:] <= 3.0 - voxel[0])
    assert gap.any() and seen[gap].sum() == 0


def test_the_first_guess_is_mostly_where_the_work_starts_and_a_little_everywhere():
    scene = parse_nff(SCENE)
    spec = RenderSpec(ImageSpec(width=64, height=64), plan=MeshPlan(2, 2, balance="objects"))
    box = scene_box(scene)
    guess = first_guess(scene, spec, box, 8)
    assert abs(guess.sum() - 1.0) < 1e-12
    assert (guess > 0).all()  # rays cross empty space too
    seen = seen_starts(scene, spec, box, 8) > 0
    assert guess[seen].sum() >= SEEN
    assert guess[seen].sum() < 1.0
