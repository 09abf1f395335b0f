"""Indices of the int64 counters array every tracing kernel adds to, and their names.

Every ray ends exactly once: created = eye + reflected + refracted + shadow rays, ended =
hits + escaped + shadow rays blocked + shadow rays lit; forwarded rays end on another node.
`internal_reflections` counts hits on a transmitter where the refracted ray would be totally
reflected: the transmitted share joins the reflected ray (no ray is created for it), and the
SPD author's counter counts such an event as a refracted ray (`spd_counts`).
`voxel_steps` counts steps of a walk through the node's own structure (grid voxels or
hierarchy nodes), `occupancy_steps` steps through the scene's occupancy map (an object-space
node's segments leaving its box) and `occupancy_walks` the walks they make (a walk's start,
its box span and first voxel, costs several steps): each costs differently
(`meshnode.mesh.stats.work_units`). `packet_idle_steps` counts the hierarchy steps (of
`voxel_steps`) a packet took for rays that had not entered the node: the rest are what the
rays walk alone, however far apart they lie (`host.planning.prepass.tracing_seconds`).
"""

EYE_RAYS, EYE_HITS, REFLECTED_RAYS, REFRACTED_RAYS, SHADOW_RAYS, SHADOW_BLOCKED = range(6)
TESTS, STEPS, SEGMENTS, ESCAPED, HITS, SHADOW_LIT, FORWARDED, INTERNAL, OCC_STEPS = range(6, 15)
OCC_WALKS, PACKET_IDLE = 15, 16
N_COUNTERS = 17
COUNTER_NAMES = (
    "eye_rays",
    "eye_hits",
    "reflected_rays",
    "refracted_rays",
    "shadow_rays",
    "shadow_rays_blocked",
    "intersection_tests",
    "voxel_steps",
    "ray_segments",
    "escaped",
    "hits",
    "shadow_rays_lit",
    "rays_forwarded",
    "internal_reflections",
    "occupancy_steps",
    "occupancy_walks",
    "packet_idle_steps",
)
# Rays by kind, the six counts any two renders of one scene must agree on (one node and a mesh,
# grid and hierarchy, one process and another): what the tests and benchmarks compare.
RAY_COUNTS = COUNTER_NAMES[:6]
# The walks' work, not rays: kept apart from the ray counts in a render's statistics.
WALK_COUNTS = (
    "intersection_tests",
    "voxel_steps",
    "occupancy_steps",
    "occupancy_walks",
    "packet_idle_steps",
)
# What the SPD author's published table counts: eye rays that hit, reflected rays, refracted
# rays (total internal reflections included) and shadow rays.
SPD_COUNT_KEYS = ("eye_hits", "reflected_rays", "refracted_rays", "shadow_rays")


def spd_counts(rays: dict) -> dict:
    """Counts of a render's `rays` statistics as the SPD author's table counts them."""
    out = {k: rays[k] for k in SPD_COUNT_KEYS}
    out["refracted_rays"] += rays.get("internal_reflections", 0)
    return out
