"""An in-process mesh for tests: every node's NodeCore, message queues instead of sockets, and
a seeded random schedule (plus optional delays on one link) instead of a network.

It checks the distributed algorithm itself (partition, clipping, ray passing, routing, colour
deposits, counts) against the single-node image; the asyncio service runs the same NodeCore.
"""

from collections import deque

import numpy as np

from host.framebuffer import Framebuffer
from host.partition import holders, node_boxes, rectangles, scene_box, subset
from meshnode.node import NodeCore

COUNTED = (
    "eye_rays", "eye_hits", "reflected_rays", "refracted_rays", "shadow_rays",
    "shadow_rays_blocked", "hits", "escaped", "shadow_rays_lit", "rays_forwarded",
)  # fmt: skip


def render_mesh(scene, rows, cols, overlap, width, height, corners=False, spp=1, depth=5,
                seed=0, batch=512, delay=None):  # fmt: skip
    """Image, summed counters and per-node stats of a rows x cols mesh render.

    `delay` = (src, dst, rounds): messages on that link are held back that many rounds."""
    box = scene_box(scene)
    los, his = node_boxes(scene, box, width, height, rows, cols, overlap)
    keep = holders(scene, los, his)
    n_nodes = rows * cols
    nodes = [NodeCore(n, subset(scene, keep[n]), los, his, box, max_depth=depth)
             for n in range(n_nodes)]  # fmt: skip
    gw, gh = (width + 1, height + 1) if corners else (width, height)
    fb = Framebuffer(width, height, corners, spp)
    queues = [deque() for _ in range(n_nodes)]
    totals = dict.fromkeys(COUNTED, 0)
    per_node = [{"objects": int(keep[n].sum()), "received": 0, "sent": 0, "batches": 0}
                for n in range(n_nodes)]  # fmt: skip
    for n, rect in enumerate(rectangles(gw, gh, rows, cols)):
        rays = nodes[n].primary(scene.view, width, height, corners, spp, seed, rect)
        totals["eye_rays"] += len(rays)
        for start in range(0, len(rays), batch):
            queues[n].append(rays[start : start + batch])
    held = []  # (release round, destination, rays)
    rng = np.random.default_rng(seed)
    rounds = 0
    while any(queues) or held:
        rounds += 1
        for due in [h for h in held if h[0] <= rounds]:
            held.remove(due)
            queues[due[1]].appendleft(due[2])
        busy = [n for n in range(n_nodes) if queues[n]]
        for n in rng.permutation(busy):
            rays = queues[n].popleft()
            out = nodes[n].trace(rays)
            per_node[n]["batches"] += 1
            fb.add(out.deposits["pixel"], out.deposits["rgb"])
            out.counts.pop("cpu_seconds")
            for k in COUNTED:
                if k != "eye_rays":
                    totals[k] += out.counts[k]
            for dest, passed in out.outgoing.items():
                per_node[n]["sent"] += len(passed)
                per_node[dest]["received"] += len(passed)
                if delay and (n, dest) == delay[:2]:
                    held.append((rounds + delay[2], dest, passed))
                else:
                    queues[dest].appendleft(passed)  # incoming rays first
    return fb.image(), totals, per_node, rounds
