"""Single-node rendering in this process: eye rays in row bands, traced on a thread pool.

The kernels release the GIL, so threads give real parallelism; each band is one kernel call with
its own mailbox and stack, and counters are summed at the end.
"""

import os
import sys
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

from host.framebuffer import Framebuffer
from meshnode.engine import Engine
from meshnode.engine.camera import eye_rays
from meshnode.engine.lenscamera import camera_rays
from protocols.scene import SceneData


@dataclass
class RenderSettings:
    """What to render: SPD corner sampling or spp samples per pixel, depth and grid options."""

    width: int | None = None
    height: int | None = None
    spd: bool = False
    spp: int = 1
    depth: int = 5
    seed: int = 0
    density: float = 1.0
    storage: str = "auto"
    threads: int = 0  # 0: one per core
    brute: bool = False
    progress: bool = True
    band_rows: int = 16
    camera: object = None  # host.camera.Camera: primary rays through its elements
    generation: int = 2  # generation area type 0..7
    lens_rays: int = 16  # rays per pixel for the random generation areas (types 2, 3)
    adaptation: str = "all"  # colour adaptation: over all generated rays, or those that left

    def size(self, scene: SceneData) -> tuple[int, int]:
        if self.spd:
            return 512, 512
        return (self.width or scene.view.width, self.height or scene.view.height)


def render(scene: SceneData, settings: RenderSettings, engine: Engine | None = None):
    """Render `scene` on one node; returns (linear float image, statistics dict)."""
    s = settings
    if s.spp < 1 or s.depth < 1:
        raise ValueError("--spp and --depth must be at least 1")
    engine = engine or Engine(scene, density=s.density, storage=s.storage, max_depth=s.depth,
                              brute=s.brute)  # fmt: skip
    engine.warmup()
    width, height = s.size(scene)
    cam = s.camera
    film_z = cam.focused_film_z() if cam is not None else None
    fb = Framebuffer(width, height, corners=s.spd, spp=1 if cam is not None else s.spp)
    grid_h = height + 1 if s.spd else height
    bands = [(y, min(y + s.band_rows, grid_h)) for y in range(0, grid_h, s.band_rows)]
    threads = s.threads or os.cpu_count() or 1

    def trace_band(rows):
        if cam is not None:
            rays = camera_rays(scene.view, width, height, cam.elements, cam.film_width,
                               cam.film_height, film_z, s.generation, s.lens_rays, s.seed,
                               s.adaptation, rows=rows)  # fmt: skip
        else:
            rays = eye_rays(scene.view, width, height, s.spd, s.spp, s.seed, rows=rows)
        rgb, counts = engine.trace(rays)
        counts["eye_rays"] = len(rays)
        return rays["pixel"], rgb, counts

    totals: dict[str, int] = {}
    start = time.perf_counter()
    bar = _progress(len(bands), s.progress)
    with ThreadPoolExecutor(max_workers=threads) as pool:
        for ids, rgb, counts in pool.map(trace_band, bands):
            fb.add(ids, rgb)
            for k, v in counts.items():
                totals[k] = totals.get(k, 0) + v
            bar.update(1)
    bar.close()
    trace_seconds = time.perf_counter() - start
    return fb.image(), _stats(engine, totals, trace_seconds, width, height, s, threads)


def _progress(total: int, enabled: bool):
    from tqdm import tqdm

    return tqdm(total=total, unit="band", desc="tracing", file=sys.stderr,
                disable=not enabled, leave=False)  # fmt: skip


def _stats(engine, totals, trace_seconds, width, height, s, threads) -> dict:
    rays = sum(totals[k] for k in ("eye_rays", "reflected_rays", "refracted_rays", "shadow_rays"))
    segments = max(totals["ray_segments"], 1)
    return {
        "scene": engine.scene.source,
        "image": {"width": width, "height": height, "spd": s.spd, "spp": 1 if s.spd else s.spp},
        "max_depth": s.depth,
        "threads": threads,
        "rays": {k: v for k, v in totals.items() if k not in ("intersection_tests", "voxel_steps")},
        "total_rays": rays,
        "intersection_tests": totals["intersection_tests"],
        "voxel_steps": totals["voxel_steps"],
        "tests_per_ray": totals["intersection_tests"] / segments,
        "steps_per_ray": totals["voxel_steps"] / segments,
        "engine": engine.stats,
        "preprocess_seconds": engine.preprocess_seconds,
        "trace_seconds": trace_seconds,
        "rays_per_second": rays / trace_seconds if trace_seconds > 0 else None,
    }
