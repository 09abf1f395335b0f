"""Where to cut the image between mesh nodes (DESIGN.md 6, "cut positions chosen from a cheap
pre-pass that estimates cost per region").

A node's work is the rays it traces inside its box, wherever they came from, so the pre-pass
runs the mesh itself, in this process, on a coarse image: every node's NodeCore on its clipped
objects, rays passed between them as on the torus, and each node's cost counted as its
intersection tests, voxel steps and rays. The column cuts then move so that the columns of
nodes share the measured cost evenly (cost spread evenly over the pixels of each column band),
the row cuts likewise, and the pass repeats; the cuts with the smallest busiest node win.
Correctness never depends on the cuts, only the balance of work does.
"""

from collections import deque

import numpy as np

from host.partition import holders, node_boxes, rectangles, scene_box, splits, subset
from meshnode.node import NodeCore

COARSE = 64  # coarse samples along the longer image axis


def _bands(inner, n: int) -> list[int]:
    """Boundaries 0, inner..., n rounded to samples, kept ordered with every band non-empty."""
    out = [0]
    for k, b in enumerate(inner, 1):
        out.append(min(max(int(b), out[-1] + 1), n - (len(inner) + 1 - k)))
    return [*out, n]


def _coarse(bounds: list[int], n: int, coarse_n: int) -> list[int]:
    """Boundaries on an n-sample axis scaled to a coarse_n-sample one."""
    return _bands([round(b * coarse_n / n) for b in bounds[1:-1]], coarse_n)


def node_costs(scene, width, height, rows, cols, overlap, xs, ys, depth=5, camera=None):
    """Cost of every node on a coarse image cut at `xs`, `ys` (given on the full width x height
    sample grid): the mesh simulated in this process, one batch per node at a time."""
    scale = COARSE / max(width, height)
    cw, ch = max(cols, round(width * scale)), max(rows, round(height * scale))
    cx, cy = _coarse(xs, width, cw), _coarse(ys, height, ch)
    box = scene_box(scene)
    los, his = node_boxes(scene, box, cw, ch, rows, cols, overlap, cx, cy)
    keep = holders(scene, los, his)
    nodes = [NodeCore(n, subset(scene, keep[n]), los, his, box, max_depth=depth)
             for n in range(rows * cols)]  # fmt: skip
    queues = [deque() for _ in nodes]
    rects = rectangles(cw, ch, rows, cols, cx, cy)
    for n, rect in enumerate(rects):
        if camera is not None:
            nodes[n].use_camera(camera, cw, ch, rects)
            queues[n].extend(nodes[n].camera_pass(scene.view, cw, ch, second=False))
        else:
            queues[n].append(nodes[n].primary(scene.view, cw, ch, False, 1, 0, rect))
    cost = np.zeros(len(nodes))
    while any(queues):
        for n in range(len(nodes)):
            if queues[n]:
                rays = queues[n].popleft()
                out = nodes[n].trace(rays)
                c = out.counts
                cost[n] += c["intersection_tests"] + c["voxel_steps"] + len(rays)
                for dest, passed in out.outgoing.items():
                    queues[dest].append(passed)
    return cost


def _even_out(bounds: list[int], band_cost: np.ndarray, n: int) -> list[int]:
    """New boundaries giving each band an equal share of the cost, the cost of each current
    band spread evenly over its samples; every band keeps at least one sample."""
    cum = np.concatenate([[0.0], np.cumsum(band_cost)]) / max(band_cost.sum(), 1e-300)
    at = np.interp(np.arange(n + 1), bounds, cum)
    parts = len(band_cost)
    return _bands(np.searchsorted(at, np.arange(1, parts) / parts), n)


def balanced_cuts(scene, width, height, rows, cols, overlap, depth=5, camera=None,
                  rounds: int = 3):  # fmt: skip
    """(xs, ys, report): cuts of the width x height sample grid whose simulated busiest node
    is the least loaded over `rounds` re-cuts starting from even cuts."""
    xs, ys = splits(width, cols), splits(height, rows)
    tried = []
    for _ in range(rounds + 1):
        cost = node_costs(scene, width, height, rows, cols, overlap, xs, ys, depth, camera)
        tried.append((float(cost.max()), xs, ys, cost))
        grid = cost.reshape(rows, cols)
        xs = _even_out(xs, grid.sum(axis=0), width)
        ys = _even_out(ys, grid.sum(axis=1), height)
    best, bx, by, cost = min(tried, key=lambda t: t[0])
    even = tried[0][0]
    report = {"columns": bx, "rows": by, "simulated_busiest_vs_even": best / even if even else 1.0,
              "simulated_imbalance": float((cost.max() - cost.min()) / cost.max()) if best else 0.0}
    return bx, by, report
