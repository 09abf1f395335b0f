"""Sampling benchmark: tracing time against RMS error for camera-ray sampling methods on a
depth-of-field scene, the error measured against a many-ray reference of the same renderer.

    python -m bench.sampling [--scene bench/scenes/dof.nff] [--camera host/cameras/thin_f2.8.toml]
                             [--focus 2] [--width 160 --height 120] [--ref-rays 1024]
                             [--spp 1,4,9,16,64] [--threshold 0.05[,0.1...]] [--repeat 3]
                             [--seed 1] [--threads 0] [--out bench/out] [--json FILE]
    python -m bench.sampling --pinhole --ref-rays 256   # the scene's pinhole, no camera

With `--pinhole` the rows sample each pixel's area of the scene's own pinhole (anti-aliasing,
as `host render --sampling S --spp N` without --camera) instead of the lens.

Rows: uniform, jittered and adaptive sampling (one row set per threshold) of the lens (the
first element's ellipse, generation area 2) at each number of rays per pixel. Columns: rays per
pixel actually traced (adaptive traces two, and all N only where those differ by more than the
threshold; with one ray it is plain one-ray sampling), the share of refined pixels, the best of
`--repeat` tracing times (camera ray generation included, preprocessing and kernel loading not),
the RMS error of the linear image against the reference, RMS x sqrt(seconds) (lower is better:
it does not change with the sample count for plain Monte Carlo noise), and time and error
relative to jittered sampling at the same count. Uniform sampling with one ray is the pinhole
through the lens centre: its error is the depth of field missing altogether.

The reference is jittered with `--ref-rays` rays and a different seed, so its own noise is
independent of the measured runs' and adds to their error in quadrature; its size is printed,
extrapolated along the jittered rows' convergence rate.
Writes the reference image and a log-log plot of error against time (PNG, drawn with Pillow)
into `--out`.
"""

import argparse
import json
import math
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
if __package__ in (None, ""):  # run as `python bench/sampling.py`
    sys.path.insert(0, str(ROOT))

DEFAULT_SCENE = ROOT / "bench" / "scenes" / "dof.nff"
DEFAULT_CAMERA = ROOT / "host" / "cameras" / "thin_f2.8.toml"
METHODS = ("uniform", "jittered", "adaptive")
REF_SEED_OFFSET = 7919  # the reference's seed: far from the measured runs'

# ---------------------------------------------------------------------------- arguments


def _floats(text: str) -> list[float]:
    return [float(v) for v in text.split(",") if v.strip()]


def _ints(text: str) -> list[int]:
    return [int(v) for v in text.split(",") if v.strip()]


def parse_args(argv=None) -> argparse.Namespace:
    """Command line options."""
    p = argparse.ArgumentParser(prog="bench.sampling", description=__doc__.split("\n\n")[0])
    p.add_argument("--scene", type=Path, default=DEFAULT_SCENE, help="NFF scene")
    p.add_argument("--camera", type=Path, default=DEFAULT_CAMERA, help="camera file")
    p.add_argument(
        "--pinhole",
        action="store_true",
        help="sample the scene's pinhole (pixel areas) instead of the camera's lens",
    )
    p.add_argument("--focus", type=float, default=2.0, help="focus distance, metres (2)")
    p.add_argument("--width", type=int, default=160)
    p.add_argument("--height", type=int, default=120)
    p.add_argument("--ref-rays", type=int, default=1024, help="reference rays per pixel")
    p.add_argument(
        "--spp",
        type=_ints,
        default=[1, 4, 9, 16, 64],
        help="rays per pixel, comma-separated (1,4,9,16,64)",
    )
    p.add_argument(
        "--threshold",
        type=_floats,
        default=None,
        help="adaptive thresholds, comma-separated (renderer default)",
    )
    p.add_argument("--repeat", type=int, default=3, help="best of N timings (3)")
    p.add_argument("--seed", type=int, default=1, help="seed of the measured runs (1)")
    p.add_argument("--threads", type=int, default=0, help="tracing threads (0: one per core)")
    p.add_argument(
        "--out", type=Path, default=ROOT / "bench" / "out", help="folder for the PNGs (bench/out)"
    )
    p.add_argument("--json", type=Path, help="also write the rows to this JSON file")
    args = p.parse_args(argv)
    if args.threshold is None:
        from protocols.camera import CameraSampling
        from protocols.spec import default

        args.threshold = [default(CameraSampling, "threshold")]
    if min(args.spp) < 1 or args.ref_rays < 1 or args.repeat < 1:
        p.error("--spp, --ref-rays and --repeat must be at least 1")
    if args.ref_rays <= max(args.spp):
        p.error("--ref-rays must exceed the largest --spp")
    return args


# ---------------------------------------------------------------------------- measuring


class Bench:
    """The scene, its engine (built and warmed once, so no run pays for preprocessing or
    kernel loading), the camera and the options shared by every render."""

    def __init__(self, args: argparse.Namespace):
        from host.camera.lens import read_camera
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
        if a.pinhole:
            return (
                ImageSpec(width=a.width, height=a.height, seed=seed),
                EngineSpec(threads=a.threads),
                PinholeSetup.of(sampling, rays, threshold if sampling == "adaptive" else None),
            )
        sampled = CameraSampling(generation=2, rays=rays, sampling=sampling, threshold=threshold)
        return (
            ImageSpec(width=a.width, height=a.height, seed=seed),
            EngineSpec(threads=a.threads),
            CameraSetup(self.camera, sampled, Focus(a.focus)),
        )

    def render(self, settings, repeat: int = 1):
        """(image, stats, best tracing seconds of `repeat` identical renders)."""
        from host.run.oneprocess import render

        best, image, stats = math.inf, None, None
        for _ in range(repeat):
            image, stats = render(self.scene, *settings, built=self.engine)
            best = min(best, stats["trace_seconds"])
        return image, stats, best

    def reference(self):
        """The many-ray jittered image, with a seed of its own."""
        a = self.args
        return self.render(self.settings("jittered", a.ref_rays, a.seed + REF_SEED_OFFSET))

    def row(self, reference: np.ndarray, sampling: str, spp: int, threshold=None) -> dict:
        """One measured configuration against the reference."""
        s = self.settings(sampling, spp, self.args.seed, threshold or 0.0)
        image, stats, seconds = self.render(s, self.args.repeat)
        cam = stats["camera"]
        adaptive = cam["threshold"] is not None  # adaptive with one ray is one plain ray
        error = rms(image, reference)
        return {
            "method": method_name(sampling, threshold),
            "sampling": sampling,
            "spp": spp,
            "threshold": cam["threshold"] if adaptive else None,
            "rays_per_pixel": stats["rays"]["eye_rays"] / self.pixels,
            "refined": cam.get("refined_pixels", 0) / self.pixels if adaptive else None,
            "seconds": seconds,
            "rms": error,
            "merit": error * math.sqrt(seconds),
        }


def method_name(sampling: str, threshold) -> str:
    return f"adaptive {threshold:g}" if sampling == "adaptive" else sampling


def rms(image: np.ndarray, reference: np.ndarray) -> float:
    """Root mean square difference over every pixel and channel (linear values)."""
    return float(np.sqrt(np.mean((image - reference) ** 2)))


def measure(bench: Bench, reference: np.ndarray) -> list[dict]:
    """Every method at every sample count, with ratios to jittered at the same count."""
    a = bench.args
    plan = [("uniform", None), ("jittered", None)] + [("adaptive", t) for t in a.threshold]
    rows = [bench.row(reference, sampling, spp, t) for sampling, t in plan for spp in a.spp]
    jittered = {r["spp"]: r for r in rows if r["sampling"] == "jittered"}
    for r in rows:
        j = jittered[r["spp"]]
        r["time_vs_jittered"] = r["seconds"] / j["seconds"] if j["seconds"] > 0 else math.nan
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


# ---------------------------------------------------------------------------- table


def format_table(rows: list[dict]) -> str:
    """The rows as a fixed-width text table."""
    head = (
        f"{'sampling':<15} {'spp':>4} {'thresh':>6} {'rays/px':>8} {'refined':>7} "
        f"{'trace s':>8} {'RMS error':>10} {'RMS*sqrt(s)':>11} {'t/jit':>6} "
        f"{'err/jit':>7}"
    )
    lines = [head, "-" * len(head)]
    for r in rows:
        thresh = f"{r['threshold']:g}" if r["threshold"] is not None else "-"
        refined = f"{100 * r['refined']:.1f}%" if r["refined"] is not None else "-"
        lines.append(
            f"{r['method']:<15} {r['spp']:>4} {thresh:>6} {r['rays_per_pixel']:>8.2f} "
            f"{refined:>7} {r['seconds']:>8.4f} {r['rms']:>10.5f} {r['merit']:>11.5f} "
            f"{r['time_vs_jittered']:>6.2f} {r['error_vs_jittered']:>7.2f}"
        )
    return "\n".join(lines)


# ---------------------------------------------------------------------------- plot

PLOT_SIZE = (900, 620)
MARGIN = (90, 50, 30, 70)  # left, top, right, bottom
COLOURS = [(31, 119, 180), (214, 39, 40), (44, 160, 44), (148, 103, 189), (255, 127, 14)]


def _font(size: int):
    from PIL import ImageFont

    try:
        return ImageFont.load_default(size=size)
    except (TypeError, OSError):  # Pillow without FreeType: the fixed bitmap font
        return ImageFont.load_default()


def log_ticks(lo: float, hi: float) -> list[float]:
    """Tick values between lo and hi: 1-2-5 per decade over short ranges, decades otherwise."""
    mantissas = (1, 2, 5) if math.log10(hi / lo) <= 3 else (1,)
    first, last = math.floor(math.log10(lo)), math.ceil(math.log10(hi))
    ticks = [m * 10.0**e for e in range(first, last + 1) for m in mantissas]
    return [t for t in ticks if lo <= t <= hi]


def _log_range(values, pad: float = 0.08) -> tuple[float, float]:
    """Bounds padded by `pad` of the span, in log space (at least a factor 2 wide)."""
    lo, hi = math.log10(min(values)), math.log10(max(values))
    mid, half = 0.5 * (lo + hi), max(0.5 * (hi - lo), math.log10(2) / 2)
    half *= 1 + 2 * pad
    return 10 ** (mid - half), 10 ** (mid + half)


class LogAxes:
    """Maps (seconds, error) onto pixel positions of the plot area, both axes logarithmic."""

    def __init__(self, xs, ys):
        self.x0, self.x1 = _log_range(xs)
        self.y0, self.y1 = _log_range(ys)
        w, h = PLOT_SIZE
        left, top, right, bottom = MARGIN
        self.box = (left, top, w - right, h - bottom)

    def __call__(self, x: float, y: float) -> tuple[float, float]:
        left, top, right, bottom = self.box
        fx = math.log10(x / self.x0) / math.log10(self.x1 / self.x0)
        fy = math.log10(y / self.y0) / math.log10(self.y1 / self.y0)
        return left + fx * (right - left), bottom - fy * (bottom - top)


def _draw_axes(draw, image, ax: LogAxes, title: str) -> None:
    """Frame, grid lines, tick labels, axis titles and the plot title."""
    from PIL import Image, ImageDraw

    font, small = _font(16), _font(13)
    left, top, right, bottom = ax.box
    for x in log_ticks(ax.x0, ax.x1):
        px, _ = ax(x, ax.y0)
        draw.line([(px, top), (px, bottom)], fill=(225, 225, 225))
        draw.text((px, bottom + 6), f"{x:g}", fill="black", font=small, anchor="mt")
    for y in log_ticks(ax.y0, ax.y1):
        _, py = ax(ax.x0, y)
        draw.line([(left, py), (right, py)], fill=(225, 225, 225))
        draw.text((left - 6, py), f"{y:g}", fill="black", font=small, anchor="rm")
    draw.rectangle(ax.box, outline="black")
    draw.text(
        ((left + right) / 2, PLOT_SIZE[1] - 22),
        "tracing seconds (log)",
        fill="black",
        font=font,
        anchor="mm",
    )
    draw.text(((left + right) / 2, top / 2), title, fill="black", font=font, anchor="mm")
    label = "RMS error vs reference (log)"
    size = (int(draw.textlength(label, font=font)) + 4, 22)
    text = Image.new("RGBA", size, (255, 255, 255, 0))
    ImageDraw.Draw(text).text((2, 2), label, fill="black", font=font)
    text = text.rotate(90, expand=True)
    image.paste(text, (8, int((top + bottom - text.height) / 2)), text)


def _marker(draw, xy, shape: int, colour) -> None:
    """A filled circle, square or triangle (by index) centred on xy."""
    x, y, r = xy[0], xy[1], 5
    if shape % 3 == 0:
        draw.ellipse([x - r, y - r, x + r, y + r], fill=colour, outline="black")
    elif shape % 3 == 1:
        draw.rectangle([x - r, y - r, x + r, y + r], fill=colour, outline="black")
    else:
        draw.polygon(
            [(x, y - r - 1), (x + r + 1, y + r), (x - r - 1, y + r)], fill=colour, outline="black"
        )


def plot(rows: list[dict], path: Path, title: str) -> None:
    """Log-log PNG of RMS error against tracing seconds: one line per method, points labelled
    with their rays per pixel, and a legend."""
    from PIL import Image, ImageDraw

    image = Image.new("RGB", PLOT_SIZE, "white")
    draw = ImageDraw.Draw(image)
    ax = LogAxes([r["seconds"] for r in rows], [r["rms"] for r in rows])
    _draw_axes(draw, image, ax, title)
    methods = list(dict.fromkeys(r["method"] for r in rows))
    small = _font(12)
    for i, method in enumerate(methods):
        colour = COLOURS[i % len(COLOURS)]
        points = [(ax(r["seconds"], r["rms"]), r["spp"]) for r in rows if r["method"] == method]
        points.sort(key=lambda p: p[1])
        draw.line([p for p, _ in points], fill=colour, width=2)
        for xy, spp in points:
            _marker(draw, xy, i, colour)
            draw.text((xy[0] + 7, xy[1] - 7), str(spp), fill=colour, font=small, anchor="lb")
    _legend(draw, ax, methods)
    image.save(path)


def _legend(draw, ax: LogAxes, methods: list[str]) -> None:
    """Method names with their colour and marker, in the top right corner of the plot area."""
    font = _font(14)
    width = max(draw.textlength(m, font=font) for m in methods) + 50
    _, top, right, _ = ax.box
    x0, y0 = right - width - 10, top + 10
    draw.rectangle(
        [x0, y0, right - 10, y0 + 22 * len(methods) + 8], fill="white", outline=(160, 160, 160)
    )
    for i, method in enumerate(methods):
        colour, y = COLOURS[i % len(COLOURS)], y0 + 15 + 22 * i
        draw.line([(x0 + 8, y), (x0 + 36, y)], fill=colour, width=2)
        _marker(draw, (x0 + 22, y), i, colour)
        draw.text((x0 + 44, y), method, fill="black", font=font, anchor="lm")


# ---------------------------------------------------------------------------- main


def main(argv=None) -> int:
    args = parse_args(argv)
    from host.run.framebuffer import write_png

    start = time.perf_counter()
    bench = Bench(args)
    reference, ref_stats, ref_seconds = bench.reference()
    cam = ref_stats["camera"]
    optics = (
        cam["source"]
        if args.pinhole
        else f"{cam['source']}  f/{cam['f_number']:.2f} focused at {cam['focus_distance_m']:g} m"
    )
    print(
        f"scene {args.scene}  camera {optics}  {args.width}x{args.height}  "
        f"{ref_stats['threads']} threads"
    )
    ref_seed = args.seed + REF_SEED_OFFSET
    print(
        f"reference: jittered, {args.ref_rays} rays/pixel, seed {ref_seed}, {ref_seconds:.2f} s;"
        f"  measured runs: seed {args.seed}, best of {args.repeat}"
    )
    rows = measure(bench, reference)
    print()
    print(format_table(rows))
    print(
        "\nadaptive with 1 ray per pixel traces that one ray (no threshold, same as jittered); "
        "RMS*sqrt(s): lower is better"
    )
    slope, ref_error = reference_error(rows, args.ref_rays)
    print(
        f"jittered error ~ rays^{slope:.2f}; the reference's own error, extrapolated: "
        f"~{ref_error:.2g} (smallest measured {min(r['rms'] for r in rows):.2g})"
    )
    args.out.mkdir(parents=True, exist_ok=True)
    name = "sampling_pinhole" if args.pinhole else "sampling"
    ref_png, plot_png = args.out / f"{name}_reference.png", args.out / f"{name}.png"
    write_png(ref_png, reference)
    optics = (
        "pinhole"
        if args.pinhole
        else f"f/{cam['f_number']:.1f} focused at {cam['focus_distance_m']:g} m"
    )
    title = (
        f"{args.scene.stem}: {optics}, {args.width}x{args.height}, reference "
        f"{args.ref_rays} rays/pixel"
    )
    plot(rows, plot_png, title)
    print(f"\nplot: {plot_png}\nreference image: {ref_png}")
    if args.json:
        info = {
            "scene": str(args.scene),
            "camera": cam,
            "width": args.width,
            "height": args.height,
            "ref_rays": args.ref_rays,
            "ref_seconds": ref_seconds,
            "repeat": args.repeat,
            "seed": args.seed,
            "jittered_rate": slope,
            "reference_error": ref_error,
            "rows": rows,
        }
        args.json.write_text(json.dumps(info, indent=2, default=str))
    print(f"whole run {time.perf_counter() - start:.1f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
