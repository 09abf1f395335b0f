"""Autofocus: a probe pass of pinhole rays through the centre of the image finds the average
depth there (DESIGN.md 7), measured along the view axis from the eye, where the camera's front
vertex sits."""

import math

import numpy as np

from meshnode.engine.camera import view_basis


def probe_rays(view, width: int, height: int, fraction: float = 0.1, grid: int = 16):
    """Origins and directions of a grid x grid probe over the central `fraction` of the
    image, and the forward axis."""
    eye, fwd, right, up, step = view_basis(view, width, height)
    u = (np.arange(grid) + 0.5) / grid - 0.5
    px = u * fraction * (width - 1) * step
    py = u * fraction * (height - 1) * step
    gx, gy = np.meshgrid(px, py)
    d = fwd + gx.ravel()[:, None] * right + gy.ravel()[:, None] * up
    d /= np.linalg.norm(d, axis=1)[:, None]
    return np.broadcast_to(eye, d.shape).copy(), d, fwd


def autofocus_distance(engine, view, width: int, height: int, fraction: float = 0.1,
                       grid: int = 16) -> tuple[float, dict]:  # fmt: skip
    """Average depth of the image centre (infinity if the probe hits nothing), and what the
    probe saw, for the statistics."""
    o, d, fwd = probe_rays(view, width, height, fraction, grid)
    t, _ = engine.first_hits(o, d)
    hit = np.isfinite(t)
    depth = t[hit] * (d[hit] @ fwd)
    distance = float(depth.mean()) if hit.any() else math.inf
    return distance, {"probe_rays": len(t), "probe_hits": int(hit.sum()),
                      "distance_m": distance}  # fmt: skip
