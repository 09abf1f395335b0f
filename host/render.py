"""Single-node rendering in this process: eye rays in row bands, traced on a thread pool.

The kernels release the GIL, so threads give real parallelism; each band is one kernel call with
its own mailbox and stack, and counters are summed at the end.
"""

import os
import sys
import time
from collections import deque
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, replace

import numpy as np

from host.autofocus import autofocus_distance
from host.camera import describe, focused
from host.framebuffer import Framebuffer
from meshnode.adaptive import RAYS_PER_BATCH, AdaptiveFilm
from meshnode.engine import Engine
from meshnode.engine.camera import eye_rays
from meshnode.engine.lenscamera import camera_batches, camera_rays, rect_pixels
from protocols.camera import CameraRays
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
    lens_rays: int = 16  # rays per pixel for generation areas 2 and 3 (or a film area)
    adaptation: str = "all"  # colour adaptation: over all generated rays, or those that left
    sampling: str = "jittered"  # uniform | jittered | random | adaptive
    threshold: float = 0.05  # adaptive: corner colours differing by more get every ray
    film_area: str = "centre"  # where on the pixel camera rays start: centre|ellipse|rectangle
    film_area_size: float = 1.0  # film area across, in pixels
    special: bool = False  # jitter over the film area instead of the lens (no depth of field)
    focus: object = None  # metres, "infinity" or "auto" (a probe pass); None: the camera's own
    dof_near: float | None = None  # depth of field: nearest and farthest sharp distances
    dof_far: float | None = None
    dof_tolerance: float | None = None  # or: focus +- this stays sharp
    coc: float | None = None  # largest circle of confusion (m); default film diagonal / 1500
    balance: str = "even"  # mesh cuts: "even", or "cost" (a coarse simulated pass evens them)

    def size(self, scene: SceneData) -> tuple[int, int]:
        if self.spd:
            return 512, 512
        return (self.width or scene.view.width, self.height or scene.view.height)

    def camera_rays(self, scene: SceneData, engine_for_probe) -> tuple[CameraRays, dict]:
        """The camera focused and stopped as asked, as the spec every node makes rays from;
        `engine_for_probe()` gives a whole-scene engine if autofocus needs a probe pass."""
        probe: dict = {}
        w, h = self.size(scene)

        def autofocus():
            distance, seen = autofocus_distance(engine_for_probe(), scene.view, w, h)
            probe.update(seen)
            return distance

        cam = focused(self.camera, self.focus, self.dof_near, self.dof_far, self.dof_tolerance,
                      self.coc, autofocus)  # fmt: skip
        spec = CameraRays(cam.elements, cam.film_width, cam.film_height, cam.focused_film_z(),
                          self.generation, self.lens_rays, self.sampling, self.threshold,
                          self.film_area, self.film_area_size, self.special, self.adaptation,
                          self.seed)  # fmt: skip
        d = describe(cam)
        probe_spec = replace(spec, rays=256, sampling="uniform", film_area="centre",
                             special=False)  # fmt: skip
        centre = np.array([(h // 2) * w + w // 2])
        _, alive = camera_rays(probe_spec, scene.view, w, h, centre)
        info = {"source": cam.source, "notes": cam.notes, "f_number": d["f_number"],
                "focus_distance_m": cam.focus_distance, "film_z_m": spec.film_z,
                "effective_focal_length_m": d["effective_focal_length_m"],
                "generation": spec.generation, "rays_per_pixel": spec.per_pixel,
                "sampling": spec.sampling, "threshold": spec.threshold if spec.adaptive else None,
                "film_area": spec.film_area, "special_jittering": spec.special,
                "adaptation": spec.adaptation, "autofocus": probe or None,
                "centre_rays_leaving_camera": float(alive.mean())}  # fmt: skip
        return spec, info


def render(scene: SceneData, settings: RenderSettings, engine: Engine | None = None):
    """Render `scene` on one node; returns (linear float image, statistics dict)."""
    s = settings
    if s.spp < 1 or s.depth < 1:
        raise ValueError("--spp and --depth must be at least 1")
    engine = engine or Engine(scene, density=s.density, storage=s.storage, max_depth=s.depth,
                              brute=s.brute)  # fmt: skip
    engine.warmup()
    width, height = s.size(scene)
    if s.camera is not None:
        return _render_camera(scene, s, engine, width, height)
    fb = Framebuffer(width, height, corners=s.spd, spp=s.spp)
    grid_h = height + 1 if s.spd else height
    bands = [(y, min(y + s.band_rows, grid_h)) for y in range(0, grid_h, s.band_rows)]

    def trace_band(rows):
        rays = eye_rays(scene.view, width, height, s.spd, s.spp, s.seed, rows=rows)
        return rays, *engine.trace(rays)

    return _run_batches(engine, fb, [(bands, fb)], trace_band, s, width, height, len(bands))


def _run_batches(engine, fb, passes, trace_job, s, width, height, total, camera=None):
    """Trace jobs on the thread pool: `passes` are (jobs, sink) pairs taken one after the
    other (adaptive sampling's second pass is made only once the first is traced), each job's
    deposits added to its sink (the framebuffer, or an adaptive film); `total` jobs or None."""
    threads = s.threads or os.cpu_count() or 1
    totals: dict[str, int] = {}
    start = time.perf_counter()
    bar = _progress(total, s.progress)
    with ThreadPoolExecutor(max_workers=threads) as pool:
        for jobs, sink in passes:
            for rays, rgb, counts in _bounded_map(pool, trace_job, jobs, 2 * threads):
                sink.add(rays["pixel"], rgb)
                counts["eye_rays"] = len(rays)
                for k, v in counts.items():
                    totals[k] = totals.get(k, 0) + v
                bar.update(1)
    bar.close()
    trace_seconds = time.perf_counter() - start
    stats = _stats(engine, totals, trace_seconds, width, height, s, threads)
    if camera is not None:
        stats["camera"] = camera
    return fb.image(), stats


def _render_camera(scene, s, engine, width, height):
    """Camera rays, in batches of bounded size; adaptive sampling in two passes."""
    spec, info = s.camera_rays(scene, lambda: engine)
    fb = Framebuffer(width, height, corners=False, spp=1)
    pixels = rect_pixels((0, width, 0, height), width)

    def trace_batch(rays):
        return rays, *engine.trace(rays)

    if not spec.adaptive:  # batches made as the pool takes them: memory stays bounded
        batches = camera_batches(spec, scene.view, width, height, pixels, RAYS_PER_BATCH)
        count = -(-len(pixels) // max(1, RAYS_PER_BATCH // spec.per_pixel))
        return _run_batches(engine, fb, [(batches, fb)], trace_batch, s, width, height, count,
                            info)  # fmt: skip
    film = AdaptiveFilm(spec, (0, width, 0, height), width, height)
    passes = ((make(scene.view, width, height), film) for make in (film.pass1, film.pass2))
    _, stats = _run_batches(engine, fb, passes, trace_batch, s, width, height, None, info)
    ids, rgb = film.finish()
    fb.add(ids, rgb)
    stats["camera"]["refined_pixels"] = int(film.refined.sum())
    stats["camera"]["rays_per_pixel_traced"] = stats["rays"]["eye_rays"] / len(pixels)
    return fb.image(), stats


def _bounded_map(pool, fn, jobs, inflight: int):
    """pool.map in order, with at most `inflight` jobs submitted: jobs may be generators of
    big ray batches, which pool.map would all make up front."""
    pending: deque = deque()
    for job in jobs:
        pending.append(pool.submit(fn, job))
        if len(pending) >= inflight:
            yield pending.popleft().result()
    while pending:
        yield pending.popleft().result()


def _progress(total, enabled: bool):
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
