"""Indices of the int64 counters array every tracing kernel adds to, and their names.

Every ray ends exactly once: created = eye + reflected + refracted + shadow rays, ended =
hits + escaped + shadow rays blocked + shadow rays lit; forwarded rays end on another node.
"""

EYE_RAYS, EYE_HITS, REFLECTED_RAYS, REFRACTED_RAYS, SHADOW_RAYS, SHADOW_BLOCKED = range(6)
TESTS, STEPS, SEGMENTS, ESCAPED, HITS, SHADOW_LIT, FORWARDED = range(6, 13)
N_COUNTERS = 13
COUNTER_NAMES = (
    "eye_rays", "eye_hits", "reflected_rays", "refracted_rays", "shadow_rays",
    "shadow_rays_blocked", "intersection_tests", "voxel_steps", "ray_segments", "escaped",
    "hits", "shadow_rays_lit", "rays_forwarded",
)  # fmt: skip
