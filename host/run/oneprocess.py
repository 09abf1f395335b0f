"""Single-node rendering in this process: eye rays in row bands, traced on a thread pool.

The kernels release the GIL, so threads give real parallelism; each band is one kernel call with
its own mailbox and stack, and counters are summed at the end.
"""

import os
import sys
import time
from collections import deque
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field

import numpy as np

from host.camera.setup import CameraSetup
from host.planning.occupancy import occupancy_map
from host.planning.request import Request
from host.run.aside import CompileAside
from host.run.firstrun import PINHOLE_STEPS, STEPS, Setup, say_on_stderr
from host.run.framebuffer import Framebuffer
from host.run.summary import common
from meshnode.engine import Engine
from meshnode.engine.camera import eye_rays
from meshnode.engine.kernelcache import compile_clock
from meshnode.engine.sky import counted, deposits, keep, looked_for, sky_of
from meshnode.engine.structure_cost import eye_ray_count
from protocols.render import EngineSpec, ImageSpec
from protocols.scene import SceneData

BAND_ROWS = 16  # sample rows per pinhole job: many jobs per thread, each one kernel call
# ... and at most this many rays (whole rows, else parts of one): 16 rows of tetra at 768
# wide and 78 spp were 958K rays, 100 MB of records a job; one-row jobs traced it in 0.92x
# the CPU (best of 5 pinned turns), as a mesh node's 65536-ray batches do.
BAND_RAYS = 65536


def render(
    request: Request,
    *,
    progress: bool = False,
    built: Engine | None = None,
    watch=None,
):
    """Render `request` in this process (its scene, image, engine and camera; one process
    has no plan to follow); returns (linear float image, statistics dict). `built`: an
    engine already built for this scene and engine spec (benchmarks reuse one); `watch`: a
    `host.live.monitor.Monitor` told of every traced job (the live view)."""
    scene, image, engine, camera = request.scene, request.sized, request.engine, request.camera
    say = say_on_stderr if progress else None
    # a first run's compiling told apart from the rest; its tracing kernel compiled aside
    with compile_clock() as clock, CompileAside(say) as aside:
        order = PINHOLE_STEPS if camera is None else STEPS
        setup = Setup(clock, say, order)
        announce = aside.announce(_compiling(order) if progress else None)
        # the structure ("auto") is chosen for the rays the whole render is expected to trace
        eye = eye_ray_count(image, camera is not None)
        tracer = built or setup.run(
            "structure build",
            lambda: Engine.from_spec(
                scene, engine, max_depth=image.depth, announce=announce, eye_rays_expected=eye
            ),
            loading=lambda e: e.stats["structure_load_seconds"],
        )
        if camera is None:  # compiled here, not while timed, and before the wait for aside
            sky = setup.run("primary rays", lambda: _sky(scene, image, tracer))
        setup.run("tracing kernel", lambda: aside.then(tracer.warmup))
        if camera is not None:  # the lens's focusing traces: after the kernel
            lens = setup.run("primary rays", lambda: _camera_ready(scene, image, camera, tracer))
    job = _Job(scene, image, engine, tracer, progress, watch, aside.account(setup.seconds()))
    if camera is not None:
        return _render_camera(job, *lens)
    width, height = image.size
    corners = image.corners()
    fb = Framebuffer(width, height, corners=corners, spp=image.spp)
    bands = pinhole_bands(*image.sample_grid(), image.spp)
    sky, why = sky

    def trace_band(band):
        rows, cols = band
        rays = eye_rays(scene.view, image, rows=rows, cols=cols, keep=keep(sky, rows, cols))
        return _traced(tracer, rays, deposits(sky, rows, cols))

    img, stats = _run_batches(job, fb, [(bands, fb)], trace_band, len(bands))
    return img, {**stats, "sky": why}


def _sky(scene: SceneData, image: ImageSpec, tracer: Engine):
    """(`Sky` of the pinhole eye rays that meet nothing, or None; why and its CPU seconds),
    from the scene's occupancy map over the engine's scene box (as object-space nodes get
    it), with the eye rays' kernel compiled."""
    eye_rays(scene.view, image, rows=(0, 1), cols=(0, 1))
    began, box = time.process_time(), (tracer.scene_lo, tracer.scene_hi)
    sky, why = None, looked_for(image)
    if not why:
        background = tracer.shading.background
        occ = occupancy_map(scene, box, sub_voxels=False)  # the sky reads the voxels alone
        sky, why = sky_of(box, occ, scene.view, image, background)
    untraced = 0 if sky is None else int(sky.cells.sum()) * sky.per_cell
    spent = time.process_time() - began
    return sky, {"eye_rays": why, "eye_rays_untraced": untraced, "cpu_seconds": spent}


def pinhole_bands(grid_w: int, grid_h: int, spp: int) -> list[tuple[tuple, tuple]]:
    """(rows, cols) of each pinhole job: BAND_ROWS sample rows, fewer where they would make
    more than BAND_RAYS rays, and a row in parts where one alone would."""
    per_row = grid_w * spp
    rows = max(1, min(BAND_ROWS, BAND_RAYS // max(per_row, 1)))
    cols = grid_w if per_row <= BAND_RAYS else max(1, BAND_RAYS // spp)
    return [
        ((y, min(y + rows, grid_h)), (x, min(x + cols, grid_w)))
        for y in range(0, grid_h, rows)
        for x in range(0, grid_w, cols)
    ]


def _compiling(order):
    """A first run compiles for tens of seconds before any progress: say why, and say the
    variant again if the engine announces another (the structure chosen is not the one
    foreseen: `Engine`)."""
    said = []

    def say(variant: str) -> None:
        if said:
            line = f"host: compiling kernels for {variant} instead (the structure chosen)"
        else:
            line = f"host: compiling kernels for {variant}, first run only: the "
            line += ", the ".join(order)
        said.append(variant)
        print(line, file=sys.stderr, flush=True)

    return say


@dataclass(frozen=True)
class _Job:
    """What a single-node render's helpers share."""

    scene: SceneData
    image: ImageSpec  # sized
    engine: EngineSpec
    tracer: Engine
    progress: bool
    watch: object = None  # host.live.monitor.Monitor, or None
    setup: dict = field(default_factory=dict)  # compile, load and setup seconds (`firstrun`)


def _run_batches(job: _Job, fb, passes, trace_job, total, camera=None):
    """Trace jobs on the thread pool: `passes` are (jobs, sink) pairs taken one after the
    other (adaptive sampling's second pass is made only once the first is traced), each job's
    deposits added to its sink (the framebuffer, or an adaptive film); `total` jobs or None."""
    threads = job.engine.threads or os.cpu_count() or 1
    totals: dict[str, int] = {}
    cpu = 0.0
    start, frame_cpu = time.perf_counter(), time.process_time()
    bar = _progress(total, job.progress)
    watch, done = job.watch, 0
    if watch is not None:
        watch.start(fb, 1, 1, [job.tracer.stats["objects"]], total, unit="batches")
    with ThreadPoolExecutor(max_workers=threads) as pool:
        for jobs, sink in passes:
            for ids, rgb, counts in _bounded_map(pool, trace_job, jobs, 2 * threads):
                sink.add(ids, rgb)
                cpu += counts.pop("cpu_seconds")
                for k, v in counts.items():
                    totals[k] = totals.get(k, 0) + v
                bar.update(1)
                done += 1
                if watch is not None:
                    watch.local(done, totals, cpu, threads)
    bar.close()
    stats = _stats(job, totals, time.perf_counter() - start, threads)
    stats["trace_cpu_seconds"] = cpu
    # the whole process's CPU for the frame (making rays, tracing, adding them up): what a
    # mesh node's frame CPU compares with
    stats["frame_cpu_seconds"] = time.process_time() - frame_cpu
    if camera is not None:
        stats["camera"] = camera
    return fb.image(), stats


def _camera_ready(scene: SceneData, image: ImageSpec, camera: CameraSetup, tracer: Engine):
    """(camera spec, its info for the stats), focused (autofocus probes the scene) and its
    ray kernels compiled, before the frame is timed."""
    from meshnode.engine.lenscamera import camera_rays, rect_pixels  # a camera's only

    spec, info = camera.spec(scene, image, lambda: tracer)
    width, height = image.size
    pixel = rect_pixels((0, width, 0, height), width)[:1]
    camera_rays(spec, image.spp, scene.view, width, height, pixel)
    return spec, info


def _render_camera(job: _Job, spec, info):
    """Camera rays, in batches of bounded size; adaptive sampling in two passes."""
    from meshnode.engine.lenscamera import camera_batches, rect_pixels  # a camera's only
    from meshnode.mesh.adaptive import RAYS_PER_BATCH, AdaptiveFilm

    view, (width, height), seed = job.scene.view, job.image.size, job.image.seed
    spp = job.image.spp  # rays per pixel asked for, of which the camera traces per_pixel
    fb = Framebuffer(width, height, corners=False, spp=1)
    pixels = rect_pixels((0, width, 0, height), width)

    def trace_batch(rays):
        return _traced(job.tracer, rays)

    if not spec.adaptive(spp):  # batches made as the pool takes them: memory stays bounded
        batches = camera_batches(spec, spp, view, width, height, pixels, seed, RAYS_PER_BATCH)
        count = -(-len(pixels) // max(1, RAYS_PER_BATCH // spec.per_pixel(spp)))
        return _run_batches(job, fb, [(batches, fb)], trace_batch, count, info)
    film = AdaptiveFilm(spec, spp, (0, width, 0, height), width, height, seed)
    passes = ((make(view, width, height), film) for make in (film.pass1, film.pass2))
    _, stats = _run_batches(job, fb, passes, trace_batch, None, info)
    ids, rgb = film.finish()
    fb.add(ids, rgb)
    stats["camera"]["refined_pixels"] = int(film.refined.sum())
    stats["camera"]["rays_per_pixel_traced"] = stats["rays"]["eye_rays"] / len(pixels)
    return fb.image(), stats


def _traced(tracer: Engine, rays, sky=None):
    """(sample ids, colour, counts) of one job, counts with the tracing thread's CPU seconds
    (the figure a mesh node's busiest CPU time compares with, on a loaded machine too);
    `sky`: (ids, colours) of its eye rays that meet nothing (`meshnode.engine.sky`), not
    made, deposited and counted as if traced."""
    cpu = time.thread_time()
    rgb, counts = tracer.trace(rays)
    ids, counts["eye_rays"] = rays["pixel"], len(rays)
    if sky is not None and len(sky[0]):
        ids, rgb = np.concatenate((ids, sky[0])), np.concatenate((rgb, sky[1]))
        counted(counts, len(sky[0]))
    counts["cpu_seconds"] = time.thread_time() - cpu
    return ids, rgb, counts


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


class _NoBar:
    """A quiet render's progress bar: nothing, and tqdm not even imported."""

    def update(self, n: int = 1) -> None:
        pass

    def close(self) -> None:
        pass


def _progress(total, enabled: bool):
    if not enabled:
        return _NoBar()
    from tqdm import tqdm

    return tqdm(total=total, unit="band", desc="tracing", file=sys.stderr, leave=False)


def _stats(job: _Job, totals, trace_seconds, threads) -> dict:
    """The COMMON figures (`host.run.summary`; setup: compiling, loading and building), then
    what one process adds: its threads, the engine's stats and its work per ray segment."""
    segments = max(totals["ray_segments"], 1)
    tracer, split = job.tracer, job.setup
    setup = split["compile_seconds"] + split["load_seconds"] + split["build_seconds"]
    return {
        **common(
            tracer.scene.source,
            job.image,
            job.engine,
            totals,
            split["compile_seconds"],
            setup,
            trace_seconds,
        ),
        **split,
        "max_depth": job.image.depth,
        "threads": threads,
        "tests_per_ray": totals["intersection_tests"] / segments,
        "steps_per_ray": totals["voxel_steps"] / segments,
        "engine": tracer.stats,
        "preprocess_seconds": tracer.preprocess_seconds,
    }
