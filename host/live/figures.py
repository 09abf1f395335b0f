"""A render's numbers as the live view shows them: each node's panel, the rays it counts, and
at the end the figures and panels read from the render's statistics.

Kept apart from `monitor`, which holds the live state under its lock and calls these: they are
plain functions of a node's numbers or of the statistics, and `final_figures` is also what the
command line's summary prints, so the page and the terminal agree by construction.
"""

RAY_KINDS = ("eye_rays", "reflected_rays", "refracted_rays", "shadow_rays")


def node_panel(n: int, cols: int, objects: int, ready: bool = False) -> dict:
    """Node `n`'s panel before it reports (`ready`: one process, tracing as it starts)."""
    return {
        "node": n,
        "row": n // cols,
        "col": n % cols,
        "state": "trace" if ready else "download",
        "ready": ready,
        "setup": "ready" if ready else "objects",
        "busy": 0.0,
        "traced": 0,
        "objects": objects,
        "links": [],
        "tiles": 0,
    }


def rays_traced(rays: dict) -> int:
    """Rays of every kind traced (shadow rays included; the counts' other keys are not rays)."""
    return int(sum(rays.get(k, 0) for k in RAY_KINDS))


def final_nodes(stats: dict, nodes: list[dict], cols: int) -> list[dict]:
    """Node panels from the statistics (the figures the STATS messages carried); one process
    updates its one panel (`nodes[0]`) in place."""
    if "nodes" not in stats:  # one process
        node = nodes[0] if nodes else node_panel(0, 1, 0)
        threads = stats.get("threads", 1)
        wall = max(stats.get("trace_seconds", 0.0), 1e-9)
        busy = stats.get("trace_cpu_seconds", 0.0) / (wall * threads)
        node.update(
            state="done",
            setup="ready",
            traced=rays_traced(stats["rays"]),
            busy=min(busy, 1.0),
            objects=stats["engine"]["objects"],
            rays_per_second=stats.get("rays_per_second") or 0.0,
        )
        return [node]
    panels = []
    tiles = stats.get("tiles_per_node") or [0] * len(stats["nodes"])
    for n, s in enumerate(stats["nodes"]):
        total = s["busy_seconds"] + s["idle_seconds"]
        links = [
            {"peer": int(p), "rays": v["rays_sent"], "bytes": v["bytes_out"]}
            for p, v in sorted(s["links"].items(), key=lambda kv: int(kv[0]))
        ]
        node = node_panel(n, cols, s["objects"])
        traced = rays_traced(s["rays"])
        node.update(
            state="done",
            ready=True,
            setup="ready",
            traced=traced,
            links=links,
            busy=s["busy_seconds"] / total if total > 0 else 0.0,
            tiles=tiles[n],
            rays_per_second=traced / total if total > 0 else 0.0,
        )
        panels.append(node)
    return panels


def final_figures(stats: dict) -> dict:
    """Rays of every kind, rays per second and elapsed seconds as the command line's summary
    prints them (`host.run.summary.summary_line`): the render's COMMON figures, one process
    or a mesh alike (rays per second over the seconds after setup, elapsed its wall)."""
    return {
        "rays": int(stats["total_rays"]),
        "rays_per_second": stats["rays_per_second"],
        "seconds": stats["wall_seconds"],
        "trace_seconds": stats["trace_seconds"],
    }
