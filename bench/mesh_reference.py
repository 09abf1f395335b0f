"""One node in this process, the reference every row of `bench.mesh` divides by, and the
sizing of a render: samples raised until one node traces long enough that per-render costs
weigh as they do on a long render."""

import time
from pathlib import Path

from host.planning.request import Request

# Samples are raised for min_trace * SIZE_MARGIN seconds: one node's later runs in the rows
# (best of --repeat, caches warm) traced 10-20% less than the sizing run (session 10: balls
# and tetra 4.1-4.8 s at --min-trace 5 with a margin of 1.1).
SIZE_MARGIN = 1.3
SIZE_STEPS = 3  # measurements after the first, at most


def single(scene, image, warm: bool = True, camera=None):
    """(wall seconds, stats) of one node in this process, one thread: the CPU-seconds
    reference, after a warm run; `camera`: a host.camera.setup.CameraSetup, or the pinhole."""
    from host.run.oneprocess import render
    from protocols.render import EngineSpec

    if warm:
        render(Request(scene, image, EngineSpec(threads=1), camera))
    start = time.perf_counter()
    _, stats = render(Request(scene, image, EngineSpec(threads=1), camera))
    return time.perf_counter() - start, stats


def sized(scene, image, min_trace: float, camera=None):
    """(image, camera, single-node run) with the samples (through a camera: lens rays) per
    pixel raised, each step scaled from the last measurement, at most SIZE_STEPS times,
    until one node traces at least `min_trace` CPU seconds: the issue's work size for scenes
    that one node traces quickly (per-render costs then weigh as on a long render). One step
    was not enough where a few samples' tracing is mostly per-render cost: the 65,536-triangle
    tetra at --min-trace 3 traced 2.0-2.9 s."""
    import dataclasses
    import math

    run = single(scene, image, camera=camera)
    for _ in range(SIZE_STEPS):
        cpu = run[1]["trace_cpu_seconds"]
        if not min_trace or cpu >= min_trace:
            break
        scale = min_trace * SIZE_MARGIN / max(cpu, 1e-9)
        image = dataclasses.replace(image, spp=math.ceil(image.spp * max(scale, 1.1)))
        run = single(scene, image, camera=camera)
    return image, camera, run


def camera_setup(path: Path, rays: int, sampling: str, width: int):
    """(CameraSetup, its image: `width` wide, the film's shape, `rays` per pixel) for
    `--camera`, focused on the image centre (a probe pass)."""
    from host.camera.lensfile import read_camera
    from host.camera.setup import CameraSetup, Focus
    from protocols.camera import CameraSampling
    from protocols.render import ImageSpec

    camera = read_camera(path)
    height = max(1, round(width * camera.film_height / camera.film_width))
    setup = CameraSetup(camera, CameraSampling(sampling=sampling), Focus(distance="auto"))
    return setup, ImageSpec(width=width, height=height, spp=rays)
