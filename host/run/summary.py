"""A render's statistics: the figures every render carries, one process or a mesh, with one
meaning (`COMMON`, made by `common`) and printed by one summary (`summary_line`); and a mesh
render's, summed from every node's STATS: how evenly the nodes worked and how much of the
scene each held (what object space saves).
"""

from meshnode.engine.counters import RAY_COUNTS, WALK_COUNTS, spd_counts
from meshnode.mesh.stats import RAY_KINDS
from protocols.render import EngineSpec, ImageSpec, MeshPlan

# What every render's statistics say, one process or a mesh, each with one meaning: the scene
# file, the sized image and the engine spec asked for (wire forms), the rays by kind and in
# all (the walks' work counted apart: WALK_COUNTS), the four counts of the SPD author's
# published table counted as that table counts them (`spd_counts`: a hit on a transmitter
# that reflects totally counts as a refracted ray), seconds compiling kernels (a first run),
# the seconds before the first primary ray could be traced (setup: building, loading, on a
# mesh connecting and configuring too), the seconds after it (trace) and in all (wall), and
# rays per second over the trace seconds.
COMMON = (
    "scene",
    "image",
    "engine_spec",
    "rays",
    "total_rays",
    "spd_counts",
    "compile_seconds",
    "setup_seconds",
    "trace_seconds",
    "wall_seconds",
    "rays_per_second",
    *WALK_COUNTS,
)


def common(
    source: str,
    image: ImageSpec,
    engine: EngineSpec,
    rays: dict,
    compile_seconds: float,
    setup: float,
    trace: float,
) -> dict:
    """The COMMON figures of a render (its wall seconds are setup's and trace's) from its
    counters (`rays`: the walks' among them, taken apart)."""
    total = sum(rays.get(k, 0) for k in RAY_KINDS)
    return {
        "scene": source,
        "image": image.to_wire(),
        "engine_spec": engine.to_wire(),
        "rays": {k: v for k, v in rays.items() if k not in WALK_COUNTS},
        **{k: rays.get(k, 0) for k in WALK_COUNTS},
        "total_rays": total,
        "spd_counts": spd_counts(rays),
        "compile_seconds": compile_seconds,
        "setup_seconds": setup,
        "trace_seconds": trace,
        "wall_seconds": setup + trace,
        "rays_per_second": total / trace if trace > 0 else 0.0,
    }


def summary_line(out, stats: dict) -> str:
    """The one summary of a render, from its COMMON figures: the image, the rays by kind (with
    total internal reflections, the refracted count as the SPD author's table counts them),
    the times and the rate; then a mesh's passes and imbalance, or one process's work per ray
    and kernel variant."""
    r, image = stats["rays"], stats["image"]
    refracted = f"{r.get('refracted_rays', 0)}"
    if r.get("internal_reflections", 0):
        refracted += (
            f" (SPD {spd_counts(r)['refracted_rays']}: +{r['internal_reflections']} "
            "total internal reflections)"
        )
    text = (
        f"{out}: {image['width']}x{image['height']}  eye {r.get('eye_rays', 0)} (hit "
        f"{r.get('eye_hits', 0)})  reflected {r.get('reflected_rays', 0)}  refracted "
        f"{refracted}  shadow {r.get('shadow_rays', 0)} (blocked "
        f"{r.get('shadow_rays_blocked', 0)})\n"
        f"setup {stats['setup_seconds']:.3f} s (compile {stats['compile_seconds']:.1f} s)  "
        f"trace {stats['trace_seconds']:.3f} s  wall {stats['wall_seconds']:.3f} s  "
        f"{stats['rays_per_second']:.0f} rays/s"
    )
    if untraced := stats.get("sky", {}).get("eye_rays_untraced", 0):  # counted, not traced
        text += f" ({untraced} eye rays meet nothing: not traced)"
    if tiles := stats.get("sky_tiles", {}).get("tiles", 0):  # dealt to no node
        text += f" ({tiles} of {stats['sky_tiles']['of']} tiles all sky: deposited by the host)"
    if "mesh" in stats:
        mesh = stats["mesh"]
        return (
            f"{text}  mesh {mesh['rows']}x{mesh['cols']}  passed {stats['rays_passed']}  "
            f"imbalance {stats['imbalance']:.2f}"
        )
    return (
        f"{text}  (load {stats['load_seconds']:.2f} s, build {stats['build_seconds']:.3f} s)  "
        f"tests/ray {stats['tests_per_ray']:.2f}  "
        f"steps/ray {stats['steps_per_ray']:.2f}  [{stats['engine']['kernel_variant']}]"
    )


def summarise(stats, plan: MeshPlan, keep, deposits, setup) -> dict:
    """The render's statistics from each node's STATS (`stats[n]`), the objects each holds
    (`keep`, nodes x objects), the deposits the host received and the seconds to set up
    (the wall's and the rest of COMMON are the whole render's: `common`)."""
    nodes = [stats[n] for n in range(plan.nodes)]
    totals: dict[str, int] = dict.fromkeys(RAY_COUNTS, 0)  # every count, though no node traced
    for s in nodes:
        for k, v in s["rays"].items():
            totals[k] = totals.get(k, 0) + v
    busy = [s["busy_cpu_seconds"] for s in nodes]
    own = keep.sum(axis=1)
    return {
        "mesh": plan.to_wire(),
        "rays": totals,
        "deposits_received": deposits,
        "rays_passed": sum(s["rays_sent"] for s in nodes),
        "setup_seconds": setup,  # planned, configured, every engine built and link up
        # ... of which the slowest-compiling node compiled kernels (a first run)
        "compile_seconds": max(s.get("compile_seconds", 0.0) for s in nodes),
        "busiest_node_cpu_seconds": max(busy),
        # the whole process's CPU for the frame (kernels, routing, deposits, framing, the
        # event loop): what a speedup counts; a simulated node reports none
        "busiest_node_frame_cpu_seconds": max(s.get("frame_cpu_seconds", 0.0) for s in nodes),
        # with routing rays and deposits around the kernels: what a node's batches cost
        "busiest_node_batch_cpu_seconds": max(s.get("batch_cpu_seconds", 0.0) for s in nodes),
        # sum of node tracing CPU / (nodes x busiest): 1 when every node works as long
        "parallel_efficiency": sum(busy) / (len(busy) * max(busy)) if max(busy) > 0 else 1.0,
        "imbalance": (max(busy) - min(busy)) / max(busy) if max(busy) > 0 else 0.0,
        "objects_per_node": own.tolist(),
        # with the neighbours' copies (MeshPlan.copies)
        "objects_held_per_node": [int(own[plan.held(n)].sum()) for n in range(plan.nodes)],
        # bytes of every engine each node built (its own and its copies), as it reports them
        "engine_bytes_held_per_node": [s.get("engine_bytes_held", 0) for s in nodes],
        # the share of the scene's objects the node holding most holds, each counted once:
        # what the object-space mesh saves against image space (where it is 1)
        "objects_held_max_share": max(
            float(keep[plan.held(n)].any(axis=0).mean()) for n in range(plan.nodes)
        )
        if keep.shape[1]
        else 1.0,
        "nodes": nodes,
    }
