"""`host` command line: argument parsing and wiring only."""

import argparse
import asyncio
import json
import os
import sys
from pathlib import Path

from host.localmesh import LocalMesh
from host.meshclient import MeshError, render_on_mesh
from host.nff import SceneError, read_nff
from host.render import RenderSettings, render
from protocols.camera import FILM_AREAS, SAMPLINGS


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
    r.add_argument("--mesh", default="auto",
                   help="ROWSxCOLS local meshnode processes; 1x1 traces in this process; "
                        "auto: one node per core")  # fmt: skip
    r.add_argument("--cluster", help="render on running nodes listed in FILE "
                   "(lines: ROW COL HOST:PORT)")  # fmt: skip
    r.add_argument("--camera", help="render through a camera file (.toml) or lens table")
    g = r.add_argument_group("camera (with --camera)")
    g.add_argument("--generation", type=int, default=2,
                   help="generation area type 0..7 (default 2: rays in the ellipse)")
    g.add_argument("--lens-rays", type=int, default=16,
                   help="rays per pixel for types 2 and 3, or with a film area (default 16)")
    g.add_argument("--sampling", choices=SAMPLINGS, default="jittered",
                   help="how a pixel's rays are placed; adaptive: two opposite corners first, "
                        "the rest where they differ by more than --threshold")  # fmt: skip
    g.add_argument("--threshold", type=float, default=0.05,
                   help="adaptive sampling's colour difference (default 0.05)")
    g.add_argument("--film-area", choices=FILM_AREAS, default="centre",
                   help="where on the pixel rays start (anti-aliasing in focus)")
    g.add_argument("--film-area-size", type=float, default=1.0, help="film area, pixels across")
    g.add_argument("--special-jitter", action="store_true",
                   help="jitter over the film area instead of the lens: no depth of field")
    g.add_argument("--adaptation", choices=("all", "left"), default="all",
                   help="average over all generated rays or those that left the camera")
    g.add_argument("--focus", help="focus distance in metres, 'infinity' or 'auto' (a probe "
                   "pass on the image centre); default: the camera file's")  # fmt: skip
    g.add_argument("--dof-near", type=float, help="depth of field: nearest sharp distance (m)")
    g.add_argument("--dof-far", type=float,
                   help="farthest sharp distance (m; default infinity with --dof-near)")
    g.add_argument("--dof-tolerance", type=float,
                   help="keep the focus distance +- this many metres sharp")
    g.add_argument("--coc", type=float,
                   help="largest circle of confusion on the film, m (default: diagonal/1500)")
    r.add_argument("--balance", choices=("even", "cost"), default="even",
                   help="mesh image cuts: even, or from a coarse simulated pass that evens "
                        "the nodes' work (costs a fraction of a second up front)")  # fmt: skip
    r.add_argument("--overlap", type=float, default=1.0,
                   help="grow each node's box by PERCENT of its size (default 1)")  # fmt: skip
    r.add_argument("--quiet", action="store_true", help="no progress bar or summary")
    c = sub.add_parser("camera", help="what a photographer asks of a camera or lens table")
    c.add_argument("camera", help="camera file (.toml, SI units) or lens table (mm)")
    c.add_argument("--focus", type=float, help="focus distance in metres (default: the file's)")
    c.add_argument("--coc", type=float, help="largest circle of confusion, m (default: d/1500)")
    c.add_argument("--json", action="store_true", help="print JSON")
    return p


def main(argv=None) -> int:
    args = _parser().parse_args(argv)
    if args.command == "camera":
        return _camera(args)
    return _render(args)


def _camera(args) -> int:
    from host.camera import CameraError, describe, read_camera

    try:
        d = describe(read_camera(args.camera), args.focus, args.coc)
    except (CameraError, ValueError, OSError) as e:
        print(f"host: {e}", file=sys.stderr)
        return 2
    if args.json:
        print(json.dumps(d, indent=2))
        return 0
    fov = d["field_of_view_deg"]
    mm = 1000.0
    print(f"effective focal length  {d['effective_focal_length_m'] * mm:.2f} mm\n"
          f"principal planes        front z = {d['front_principal_plane_z_m'] * mm:.2f} mm, "
          f"rear z = {d['rear_principal_plane_z_m'] * mm:.2f} mm\n"
          f"front focal distance    {d['front_focal_distance_m'] * mm:.2f} mm\n"
          f"back focal distance     {d['back_focal_distance_m'] * mm:.2f} mm\n"
          f"f-number                f/{d['f_number']:.2f} (entrance pupil "
          f"{d['entrance_pupil_diameter_m'] * mm:.2f} mm)\n"
          f"focus distance          {d['focus_distance_m']:g} m -> film at z = "
          f"{d['film_z_m'] * mm:.3f} mm\n"
          f"field of view           {fov['horizontal']:.1f} x {fov['vertical']:.1f} deg "
          f"({fov['diagonal']:.1f} diagonal)\n"
          f"hyperfocal distance     {d['hyperfocal_distance_m']:.2f} m (circle of confusion "
          f"{d['circle_of_confusion_m'] * mm:.3f} mm)")  # fmt: skip
    return 0


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
        balance=args.balance,
    )  # fmt: skip
    if args.camera:
        from host.camera import CameraError, read_camera

        if args.spp != 1:
            print("host: --spp is for the pinhole; through a camera, rays per pixel are "
                  "--lens-rays N", file=sys.stderr)  # fmt: skip
            return 2

        try:
            settings.camera = read_camera(args.camera)
        except (CameraError, OSError) as e:
            print(f"host: {e}", file=sys.stderr)
            return 2
        focus = args.focus
        if focus not in (None, "auto", "infinity"):
            try:
                focus = float(focus)
            except ValueError:
                print(f"host: --focus wants metres, 'infinity' or 'auto', not {focus!r}",
                      file=sys.stderr)  # fmt: skip
                return 2
        for name in ("generation", "lens_rays", "sampling", "threshold", "film_area",
                     "film_area_size", "adaptation", "dof_near", "dof_far", "dof_tolerance",
                     "coc"):  # fmt: skip
            setattr(settings, name, getattr(args, name))
        settings.special, settings.focus = args.special_jitter, focus
    try:
        image, stats = _run(scene, settings, args)
    except (ValueError, OSError) as e:  # CameraError included
        print(f"host: {e}", file=sys.stderr)
        return 2
    except MeshError as e:
        print(f"host: render failed: {e}", file=sys.stderr)
        return 1
    out = Path(args.output or Path(args.scene).with_suffix(".png").name)
    write_png(out, image)
    float_path = Path(args.float_path or out.with_suffix(".pfm"))
    write_pfm(float_path, image)
    if args.stats:
        Path(args.stats).write_text(json.dumps(stats, indent=2) + "\n")
    leaving = stats.get("camera", {}).get("centre_rays_leaving_camera", 1.0)
    if leaving < 0.5:
        print(f"host: only {leaving:.0%} of the camera rays leave the camera (the rest are "
              "stopped by rims or diaphragms): aim them at the stop by listing it first "
              "(film side)", file=sys.stderr)  # fmt: skip
    if not args.quiet and "mesh" in stats:
        r = {k: stats["rays"].get(k, 0) for k in ("eye_rays", "reflected_rays",
             "refracted_rays", "shadow_rays", "shadow_rays_blocked")}  # fmt: skip
        print(f"{out}: mesh {stats['mesh']['rows']}x{stats['mesh']['cols']}  eye {r['eye_rays']}"
              f"  reflected {r['reflected_rays']}  refracted {r['refracted_rays']}  shadow "
              f"{r['shadow_rays']} (blocked {r['shadow_rays_blocked']})  passed "
              f"{stats['rays_passed']}  wall {stats['wall_seconds']:.2f} s  imbalance "
              f"{stats['imbalance']:.2f}", file=sys.stderr)  # fmt: skip
    elif not args.quiet:
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


def parse_mesh(text: str) -> tuple[int, int]:
    """'2x3' -> (2, 3); 'auto' -> one row with a node per core."""
    if text == "auto":
        return 1, max(1, os.cpu_count() or 1)
    try:
        rows, cols = (int(v) for v in text.lower().split("x"))
    except ValueError:
        raise ValueError(f"--mesh wants ROWSxCOLS, like 2x2, not {text!r}") from None
    if rows < 1 or cols < 1:
        raise ValueError(f"--mesh {text}: rows and columns must be at least 1")
    return rows, cols


def read_cluster(path) -> tuple[int, int, list[str]]:
    """Cluster file: one `ROW COL HOST:PORT` per node, `#` comments; every cell once."""
    cells = {}
    for number, line in enumerate(Path(path).read_text().splitlines(), 1):
        words = line.split("#", 1)[0].split()
        if not words:
            continue
        ok = len(words) == 3 and words[0].isdigit() and words[1].isdigit() and ":" in words[2]
        if not ok:
            raise ValueError(f"{path}:{number}: expected ROW COL HOST:PORT")
        key = (int(words[0]), int(words[1]))
        if key in cells:
            raise ValueError(f"{path}:{number}: node {key} listed twice")
        cells[key] = words[2]
    if not cells:
        raise ValueError(f"{path}: no nodes listed")
    rows = max(r for r, _ in cells) + 1
    cols = max(c for _, c in cells) + 1
    missing = [(r, c) for r in range(rows) for c in range(cols) if (r, c) not in cells]
    if missing:
        raise ValueError(f"{path}: no address for node(s) {missing}")
    return rows, cols, [cells[(r, c)] for r in range(rows) for c in range(cols)]


def _run(scene, settings, args):
    """Single node in this process, a local mesh of processes, or a running cluster."""
    if args.cluster:
        rows, cols, addresses = read_cluster(args.cluster)
        return _mesh(scene, settings, addresses, rows, cols, args)
    rows, cols = parse_mesh(args.mesh)
    if rows * cols == 1:
        return render(scene, settings)
    with LocalMesh(rows * cols) as addresses:
        return _mesh(scene, settings, addresses, rows, cols, args)


def _mesh(scene, settings, addresses, rows, cols, args):
    from tqdm import tqdm

    w, h = settings.size(scene)
    total = None  # camera rays lost inside the camera are never traced: no known total
    if settings.camera is None:
        total = (w + 1) * (h + 1) if settings.spd else w * h * settings.spp
    bar = tqdm(total=total, unit=" rays", desc=f"mesh {rows}x{cols} primary", file=sys.stderr,
               disable=args.quiet, leave=False)  # fmt: skip
    try:
        return asyncio.run(render_on_mesh(scene, settings, addresses, rows, cols,
                                          args.overlap, progress=bar.update))  # fmt: skip
    finally:
        bar.close()


if __name__ == "__main__":
    sys.exit(main())
