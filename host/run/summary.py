"""The statistics of a mesh render, summed from every node's STATS: the rays, the time, how
evenly the nodes worked and how much of the scene each held (what object space saves).
"""

from protocols.render import MeshPlan


def summarise(stats, plan: MeshPlan, keep, deposits, setup, wall) -> dict:
    """The render's statistics from each node's STATS (`stats[n]`), the objects each holds
    (`keep`, nodes x objects), the deposits the host received and the seconds taken."""
    nodes = [stats[n] for n in range(plan.nodes)]
    totals: dict[str, int] = {}
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
        "wall_seconds": wall,
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
