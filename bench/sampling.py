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
threshold; with one ray it is plain one-ray sampling), the share of refined pixels, the frame's
CPU seconds (the process's, every tracing thread's: camera ray generation included,
preprocessing and kernel loading not; median over `--repeat` rounds, least-most beside it),
the RMS error of the linear image against the reference, RMS x sqrt(CPU seconds) (lower is
better: it does not change with the sample count for plain Monte Carlo noise), and time and
error relative to jittered sampling at the same count (time: the median of the rounds' paired
ratios, least-most beside it). Uniform sampling with one ray is the pinhole through the lens
centre: its error is the depth of field missing altogether.

Timed as `bench.timing` says, for a shared, noisy machine: CPU seconds, never the wall; the
methods of one ray count taking turns (uniform, jittered, adaptive ..., uniform, jittered ...)
so a round's renders share a spell of the machine; with `--threads 1` the process is pinned
to one core.

The reference is jittered with `--ref-rays` rays and a different seed, so its own noise is
independent of the measured runs' and adds to their error in quadrature; its size is printed,
extrapolated along the jittered rows' convergence rate.
Writes the reference image and a log-log plot of error against time (PNG, drawn with Pillow)
into `--out`.
"""

import argparse
import json
import os
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
if __package__ in (None, ""):  # run as `python bench/sampling.py`
    sys.path.insert(0, str(ROOT))

from bench.sampling_plot import plot  # noqa: E402 (after the path is set)
from bench.sampling_runs import REF_SEED_OFFSET, Bench, measure, reference_error  # noqa: E402
from bench.timing import pin_one_core, pinned_text  # noqa: E402

DEFAULT_SCENE = ROOT / "bench" / "scenes" / "dof.nff"
DEFAULT_CAMERA = ROOT / "host" / "cameras" / "thin_f2.8.toml"


def _floats(text: str) -> list[float]:
    """'0.05,0.1' -> [0.05, 0.1]: a list option in one argument."""
    return [float(v) for v in text.split(",") if v.strip()]


def _ints(text: str) -> list[int]:
    """'1,4,9' -> [1, 4, 9]: a list option in one argument."""
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
    p.add_argument("--repeat", type=int, default=3, help="rounds of turns (3)")
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


def format_table(rows: list[dict]) -> str:
    """The rows as a fixed-width text table."""
    head = (
        f"{'sampling':<15} {'spp':>4} {'thresh':>6} {'rays/px':>8} {'refined':>7} "
        f"{'CPU s':>8} {'least-most':>15} {'RMS error':>10} {'RMS*sqrt(s)':>11} {'t/jit':>6} "
        f"{'least-most':>11} {'err/jit':>7}"
    )
    lines = [head, "-" * len(head)]
    for r in rows:
        thresh = f"{r['threshold']:g}" if r["threshold"] is not None else "-"
        refined = f"{100 * r['refined']:.1f}%" if r["refined"] is not None else "-"
        seconds = f"{r['seconds_low']:.4f}-{r['seconds_high']:.4f}"
        ratios = f"{r['time_vs_jittered_low']:.2f}-{r['time_vs_jittered_high']:.2f}"
        lines.append(
            f"{r['method']:<15} {r['spp']:>4} {thresh:>6} {r['rays_per_pixel']:>8.2f} "
            f"{refined:>7} {r['seconds']:>8.4f} {seconds:>15} {r['rms']:>10.5f} "
            f"{r['merit']:>11.5f} {r['time_vs_jittered']:>6.2f} {ratios:>11} "
            f"{r['error_vs_jittered']:>7.2f}"
        )
    return "\n".join(lines)


def main(argv=None) -> int:
    """Measure every method against the reference, print the table and the reference's own
    error, write the plot and the reference image (and the rows as JSON)."""
    args = parse_args(argv)
    start = time.perf_counter()
    # one thread compared with itself: pinned before any thread starts (they inherit it)
    core = pin_one_core() if (args.threads or os.cpu_count() or 1) == 1 else None
    bench = Bench(args)
    reference, ref_stats, ref_seconds = bench.reference()
    cam = ref_stats["camera"]
    print_intro(args, ref_stats, ref_seconds, core)
    rows = measure(bench, reference)
    print()
    print(format_table(rows))
    print(
        "\nadaptive with 1 ray per pixel traces that one ray (no threshold, same as jittered); "
        "RMS*sqrt(s): lower is better (s: the median CPU seconds); t/jit: the median of the "
        "rounds' paired ratios"
    )
    slope, ref_error = reference_error(rows, args.ref_rays)
    print(
        f"jittered error ~ rays^{slope:.2f}; the reference's own error, extrapolated: "
        f"~{ref_error:.2g} (smallest measured {min(r['rms'] for r in rows):.2g})"
    )
    write_images(args, cam, reference, rows)
    if args.json:
        info = {
            "scene": str(args.scene),
            "camera": cam,
            "width": args.width,
            "height": args.height,
            "ref_rays": args.ref_rays,
            "ref_cpu_seconds": ref_seconds,
            "clock": "frame process CPU seconds, methods of a count in turns",
            "pinned_core": core,
            "repeat": args.repeat,
            "seed": args.seed,
            "jittered_rate": slope,
            "reference_error": ref_error,
            "rows": rows,
        }
        args.json.write_text(json.dumps(info, indent=2, default=str))
    print(f"whole run {time.perf_counter() - start:.1f} s (wall)")
    return 0


def print_intro(args: argparse.Namespace, ref_stats: dict, ref_seconds: float, core) -> None:
    """What was measured: scene, optics, image, threads (and the core pinned to), the
    reference, the seeds and how the methods were timed."""
    cam = ref_stats["camera"]
    optics = (
        cam["source"]
        if args.pinhole
        else f"{cam['source']}  f/{cam['f_number']:.2f} focused at {cam['focus_distance_m']:g} m"
    )
    threads = ref_stats["threads"]
    pinned = pinned_text(core) if threads == 1 else "not pinned"
    print(
        f"scene {args.scene}  camera {optics}  {args.width}x{args.height}  "
        f"{threads} thread{'s' if threads > 1 else ''}, {pinned}"
    )
    ref_seed = args.seed + REF_SEED_OFFSET
    print(
        f"reference: jittered, {args.ref_rays} rays/pixel, seed {ref_seed}, "
        f"{ref_seconds:.2f} CPU s;  measured runs: seed {args.seed}, each count's methods in "
        f"turns, {args.repeat} rounds, process CPU seconds of each frame"
    )


def write_images(args: argparse.Namespace, cam: dict, reference, rows: list[dict]) -> None:
    """The reference image and the error-against-time plot into `--out`, named for the mode."""
    from host.run.framebuffer import write_png

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


if __name__ == "__main__":
    sys.exit(main())
