"""Autofocus: a probe pass of pinhole rays through the centre of the image finds the average
depth there (DESIGN.md 7), measured along the view axis from the eye, where the camera's front
vertex sits. For a mesh render the host probes with an engine over just the objects inside the
probe's cone, not the whole scene."""

import math

import numpy as np

from host.scene.subset import subset
from meshnode.engine import Engine
from meshnode.engine.camera import view_basis
from meshnode.engine.tables import build_tables
from protocols.render import EngineSpec


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


def in_probe_cone(scene, width: int, height: int, fraction: float = 0.1) -> np.ndarray:
    """Objects (engine local order) whose bounding sphere meets the cone around every probe
    ray: the only ones a probe ray can hit (conservative)."""
    eye, fwd, _, _, step = view_basis(scene.view, width, height)
    half = 0.5 * fraction * step * math.hypot(width - 1, height - 1)
    cone = math.atan(half) * (1 + 1e-9) + 1e-12
    tb = build_tables(scene)
    centre, radius = (tb.lo + tb.hi) / 2, np.linalg.norm(tb.hi - tb.lo, axis=1) / 2
    v = centre - eye
    dist = np.linalg.norm(v, axis=1)
    with np.errstate(invalid="ignore", divide="ignore"):
        angle = np.arccos(np.clip((v @ fwd) / dist, -1.0, 1.0))
        spread = np.arcsin(np.clip(radius / dist, 0.0, 1.0))
    return (dist <= radius) | (angle - spread <= cone)


def probe_engine(scene, width: int, height: int, spec: EngineSpec = EngineSpec()) -> Engine:
    """An engine over the objects the probe can hit, as the render's `spec` says (depth 1:
    the probe only finds nearest hits)."""
    held = subset(scene, in_probe_cone(scene, width, height))
    engine = Engine.from_spec(held, spec, max_depth=1)
    engine.warmup(["probe"])  # it only finds nearest hits
    return engine


def autofocus_distance(
    engine, view, width: int, height: int, fraction: float = 0.1, grid: int = 16
) -> tuple[float, dict]:
    """Average depth of the image centre (infinity if the probe hits nothing), and what the
    probe saw, for the statistics."""
    o, d, fwd = probe_rays(view, width, height, fraction, grid)
    t, _ = engine.first_hits(o, d)
    hit = np.isfinite(t)
    depth = t[hit] * (d[hit] @ fwd)
    distance = float(depth.mean()) if hit.any() else math.inf
    return distance, {"probe_rays": len(t), "probe_hits": int(hit.sum()), "distance_m": distance}
