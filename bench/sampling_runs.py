"""The sampling benchmark's measurements: one scene and engine built and warmed once, each
camera-ray sampling method rendered at each ray count and compared with a many-ray reference,
so methods differ only in how they place their rays. Timed as `bench.timing` says: each
frame's process CPU seconds, the methods of one ray count taking turns."""

import argparse
import math

import numpy as np

from bench.timing import Turns, turns

METHODS = ("uniform", "jittered", "adaptive")
REF_SEED_OFFSET = 7919  # the reference's seed: far from the measured runs'


class Bench:
    """The scene, its engine (built and warmed once, so no run pays for preprocessing or
    kernel loading), the camera and the options shared by every render."""

    def __init__(self, args: argparse.Namespace):
        from host.camera.lensfile import read_camera
        from host.scene.nff import read_nff
        from meshnode.engine import Engine

        self.args = args
        self.scene = read_nff(args.scene)
        self.camera = None if args.pinhole else read_camera(args.camera)
        self.engine = Engine(self.scene)
        self.engine.warmup()
        self.pixels = args.width * args.height

    def settings(self, sampling: str, rays: int, seed: int, threshold: float = 0.05):
        """Render settings: the camera's lens (or the pinhole's pixel areas) sampled with
        `rays` rays per pixel."""
        from host.camera.setup import CameraSetup, Focus, PinholeSetup
        from protocols.camera import CameraSampling
        from protocols.render import EngineSpec, ImageSpec

        a = self.args
        image = ImageSpec(width=a.width, height=a.height, spp=rays, seed=seed)
        if a.pinhole:
            return (
                image,
                EngineSpec(threads=a.threads),
                PinholeSetup.of(sampling, threshold if sampling == "adaptive" else None),
            )
        sampled = CameraSampling(generation=2, sampling=sampling, threshold=threshold)
        return (
            image,
            EngineSpec(threads=a.threads),
            CameraSetup(self.camera, sampled, Focus(a.focus)),
        )

    def render(self, settings):
        """(image, stats, the frame's CPU seconds): the renderer's own process CPU seconds for
        the frame, every thread's (making camera rays, tracing, adding them up; not the
        engine's build or kernel loading)."""
        from host.planning.request import Request
        from host.run.oneprocess import render

        image, stats = render(Request(self.scene, *settings), built=self.engine)
        return image, stats, stats["frame_cpu_seconds"]

    def reference(self):
        """The many-ray jittered image, with a seed of its own."""
        a = self.args
        return self.render(self.settings("jittered", a.ref_rays, a.seed + REF_SEED_OFFSET))

    def in_turns(self, plan: list[tuple[str, float | None]], spp: int) -> tuple[Turns, dict]:
        """Every (sampling, threshold) of `plan` at `spp` rays per pixel, taking turns
        `--repeat` rounds: (their CPU seconds, each one's last (image, stats) by method)."""
        a = self.args
        settings = {method_name(s, t): self.settings(s, spp, a.seed, t or 0.0) for s, t in plan}
        times, last = Turns(), {}
        for _, name in turns(list(settings), a.repeat):
            image, stats, seconds = self.render(settings[name])
            times.add(name, seconds)
            last[name] = image, stats
        return times, last

    def row(self, reference, sampling: str, spp: int, threshold, rendered, times: Turns) -> dict:
        """One measured configuration against the reference: `rendered` its (image, stats),
        `times` the CPU seconds of its count's turns (jittered's among them)."""
        image, stats = rendered
        name = method_name(sampling, threshold)
        cam = stats["camera"]
        adaptive = cam["threshold"] is not None  # adaptive with one ray is one plain ray
        error = rms(image, reference)
        seconds = times.figure(name)
        return {
            "method": name,
            "sampling": sampling,
            "spp": spp,
            "threshold": cam["threshold"] if adaptive else None,
            "rays_per_pixel": stats["rays"]["eye_rays"] / self.pixels,
            "refined": cam.get("refined_pixels", 0) / self.pixels if adaptive else None,
            **seconds.fields("seconds"),
            "rms": error,
            "merit": error * math.sqrt(seconds.median),
            # this method's CPU over jittered's in the same round: their median and spread
            **times.ratio(name, "jittered").fields("time_vs_jittered"),
        }


def method_name(sampling: str, threshold) -> str:
    """A row's method: its sampling, with the threshold when adaptive (one set per threshold)."""
    return f"adaptive {threshold:g}" if sampling == "adaptive" else sampling


def rms(image: np.ndarray, reference: np.ndarray) -> float:
    """Root mean square difference over every pixel and channel (linear values)."""
    return float(np.sqrt(np.mean((image - reference) ** 2)))


def measure(bench: Bench, reference: np.ndarray) -> list[dict]:
    """Every method at every sample count (the methods of one count in turns), with time and
    error relative to jittered at the same count; rows by method, then count."""
    a = bench.args
    plan = [("uniform", None), ("jittered", None)] + [("adaptive", t) for t in a.threshold]
    got = {}
    for spp in a.spp:
        times, last = bench.in_turns(plan, spp)
        for sampling, t in plan:
            rendered = last[method_name(sampling, t)]
            got[sampling, t, spp] = bench.row(reference, sampling, spp, t, rendered, times)
    rows = [got[sampling, t, spp] for sampling, t in plan for spp in a.spp]
    jittered = {r["spp"]: r for r in rows if r["sampling"] == "jittered"}
    for r in rows:
        j = jittered[r["spp"]]
        r["error_vs_jittered"] = r["rms"] / j["rms"] if j["rms"] > 0 else math.nan
    return rows


def reference_error(rows: list[dict], ref_rays: int) -> tuple[float, float]:
    """(convergence rate, the reference's own RMS error): the jittered rows' error against
    rays per pixel fitted as a power law (least squares in log-log) and extrapolated."""
    pts = [(r["spp"], r["rms"]) for r in rows if r["sampling"] == "jittered" and r["rms"] > 0]
    if len(pts) < 2:
        return math.nan, math.nan
    x, y = np.log([p[0] for p in pts]), np.log([p[1] for p in pts])
    slope, intercept = np.polyfit(x, y, 1)
    return float(slope), float(np.exp(intercept + slope * math.log(ref_rays)))
