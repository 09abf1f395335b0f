"""`host` command line: argument parsing and wiring only."""

import argparse
import json
import sys
from pathlib import Path

from host.nff import SceneError, read_nff
from host.render import RenderSettings, render


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="host", description="Meshtrace host: render NFF scenes.")
    sub = p.add_subparsers(dest="command", required=True)
    r = sub.add_parser("render", help="render an NFF scene")
    r.add_argument("scene", help="NFF scene file")
    r.add_argument("-o", "--output", help="PNG image (default: SCENE name .png)")
    r.add_argument("--float", dest="float_path", help="float image, PFM (default: beside PNG)")
    r.add_argument("--spd", action="store_true",
                   help="SPD rules: 512x512 from 513x513 corner rays, depth 5")  # fmt: skip
    r.add_argument("--spp", type=int, default=1, help="jittered samples per pixel (default 1)")
    r.add_argument("--depth", type=int, default=5, help="maximum ray tree depth (eye ray = 1)")
    r.add_argument("--width", type=int, help="image width (default: the scene's resolution)")
    r.add_argument("--height", type=int, help="image height")
    r.add_argument("--seed", type=int, default=0, help="jitter seed")
    r.add_argument("--stats", help="write statistics as JSON to this file")
    r.add_argument("--storage", choices=("auto", "csr", "hash"), default="auto",
                   help="grid storage (default: the smaller in memory)")  # fmt: skip
    r.add_argument("--density", type=float, default=1.0,
                   help="grid density: voxels per object to start from, refined until a "
                        "voxel holds about 4/DENSITY objects (default 1)")  # fmt: skip
    r.add_argument("--threads", type=int, default=0, help="tracing threads (default: cores)")
    r.add_argument("--quiet", action="store_true", help="no progress bar or summary")
    return p


def main(argv=None) -> int:
    args = _parser().parse_args(argv)
    return _render(args)


def _render(args) -> int:
    from host.framebuffer import write_pfm, write_png

    try:
        scene = read_nff(args.scene)
    except SceneError as e:
        print(f"host: {e}", file=sys.stderr)
        return 2
    except OSError as e:
        print(f"host: cannot read scene: {e}", file=sys.stderr)
        return 2
    settings = RenderSettings(
        width=args.width, height=args.height, spd=args.spd, spp=args.spp,
        depth=5 if args.spd else args.depth, seed=args.seed, density=args.density,
        storage=args.storage, threads=args.threads, progress=not args.quiet,
    )  # fmt: skip
    try:
        image, stats = render(scene, settings)
    except ValueError as e:
        print(f"host: {e}", file=sys.stderr)
        return 2
    out = Path(args.output or Path(args.scene).with_suffix(".png").name)
    write_png(out, image)
    float_path = Path(args.float_path or out.with_suffix(".pfm"))
    write_pfm(float_path, image)
    if args.stats:
        Path(args.stats).write_text(json.dumps(stats, indent=2) + "\n")
    if not args.quiet:
        r = stats["rays"]
        print(
            f"{out}: {stats['image']['width']}x{stats['image']['height']}  "
            f"eye {r['eye_rays']} (hit {r['eye_hits']})  reflected {r['reflected_rays']}  "
            f"refracted {r['refracted_rays']}  shadow {r['shadow_rays']} "
            f"(blocked {r['shadow_rays_blocked']})\n"
            f"preprocess {stats['preprocess_seconds']:.3f} s  trace {stats['trace_seconds']:.3f} s"
            f"  {stats['rays_per_second']:.0f} rays/s  tests/ray {stats['tests_per_ray']:.2f}  "
            f"steps/ray {stats['steps_per_ray']:.2f}  [{stats['engine']['kernel_variant']}]",
            file=sys.stderr,
        )
    return 0


if __name__ == "__main__":
    sys.exit(main())
