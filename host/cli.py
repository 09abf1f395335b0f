"""`host` command line: argument parsing and wiring only.

Every render option is one field of a record of `protocols.render` (or `protocols.camera`,
`host.camera.setup`); the option's default and its checks are the field's, shown in --help.
"""

import argparse
import asyncio
import json
import math
import os
import secrets
import sys
from dataclasses import replace
from pathlib import Path

from host.camera.setup import CameraSetup, Focus, PinholeSetup
from host.planning.balance import OVERLAPS
from host.planning.plan import PLAN_MODES
from host.run.cluster import parse_mesh, read_cluster, statefulset_cluster
from host.run.framebuffer import exr_missing, write_exr, write_pfm, write_png
from host.run.localmesh import LocalMesh
from host.run.meshclient import NODE_LOSS, MeshError, primary_rays, render_on_mesh
from host.run.oneprocess import render
from host.scene.formats import FORMATS, SceneError, read_scene
from meshnode.transport.tls import TlsFiles, add_tls_options
from protocols.camera import ADAPTATIONS, FILM_AREAS, SAMPLINGS, CameraSampling
from protocols.render import (
    BALANCES,
    ORDERS,
    STORAGES,
    STRUCTURES,
    TILINGS,
    EngineSpec,
    ImageSpec,
    MeshPlan,
)
from protocols.spec import default

CAMERA_ONLY = (CameraSampling, Focus)
PINHOLE_TOO = ("sampling", "threshold")  # CameraSampling fields the pinhole takes as well
FLAGS: dict[str, str] = {}  # "Record.field" -> the option that sets it, for messages
WRITERS = {".png": write_png, ".pfm": write_pfm, ".exr": write_exr}
AUTO_WHY = (
    "on one machine, threads in one process beat a local mesh of processes: no rays or "
    "pixels cross process boundaries; --mesh ROWSxCOLS starts a local mesh"
)


def _version() -> str:
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("meshtrace")
    except PackageNotFoundError:
        return "unknown (not installed)"


def _field(group, flag: str, record: type, name: str, help: str, **kw) -> None:
    """An option that sets `record.name`; unset, the record's own default applies."""
    d = default(record, name)
    FLAGS[f"{record.__name__}.{name}"] = flag
    shown = "" if d is None or kw.get("action") == "store_true" else f" (default {d})"
    group.add_argument(
        flag, dest=f"{record.__name__}.{name}", default=argparse.SUPPRESS, help=help + shown, **kw
    )


def _given(args, record: type) -> dict:
    """The fields of `record` set on the command line."""
    prefix = f"{record.__name__}."
    return {k[len(prefix) :]: v for k, v in vars(args).items() if k.startswith(prefix)}


def _prog() -> str:
    """`meshtrace` when run by that name (the same commands as `host`, which /usr/bin/host,
    the DNS lookup tool, shadows outside a virtual environment), else `host`."""
    return "meshtrace" if Path(sys.argv[0]).name == "meshtrace" else "host"


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog=_prog(), description="Meshtrace host: render scenes (NFF, OBJ, PLY, Open Inventor)."
    )
    p.add_argument("--version", action="version", version=f"%(prog)s {_version()}")
    sub = p.add_subparsers(dest="command", required=True)
    formats = "; ".join(f"{ext} {what}" for ext, what in FORMATS.items())
    r = sub.add_parser("render", help="render a scene file")
    r.add_argument("scene", help=f"scene file, read by its extension: {formats}")
    r.add_argument(
        "--settings",
        help="view, lights and material of a .obj / .ply mesh (or "
        "resolution and background of a .iv) as TOML (default: SCENE's name .toml "
        "beside it, if there is one; what neither gives is defaulted, with a note)",
    )
    r.add_argument(
        "-o",
        "--output",
        help="image: .png (8-bit sRGB) or .exr (linear float) (default: SCENE name .png)",
    )
    r.add_argument(
        "--float",
        dest="float_path",
        help="linear float image, .pfm or .exr (default: a .pfm beside a .png output)",
    )
    r.add_argument("--stats", help="write statistics as JSON to this file")
    r.add_argument("--quiet", action="store_true", help="no progress bar or summary")
    r.add_argument(
        "--serve",
        metavar="[HOST:]PORT",
        help="watch the render in a browser at "
        "http://HOST:PORT/ (HOST default 127.0.0.1; PORT 0: any free port); the "
        "page stays until Ctrl-C",
    )
    r.add_argument(
        "--serve-exit",
        action="store_true",
        help="with --serve: exit when the render is done and open pages have the final image",
    )
    _field(
        r,
        "--spd",
        ImageSpec,
        "spd",
        "SPD rules: 512x512 from 513x513 corner rays, depth 5",
        action="store_true",
    )
    _field(r, "--spp", ImageSpec, "spp", "pinhole rays per pixel (placed by --sampling)", type=int)
    _field(r, "--depth", ImageSpec, "depth", "maximum ray tree depth (eye ray = 1)", type=int)
    _field(r, "--width", ImageSpec, "width", "image width (default: the scene's)", type=int)
    _field(r, "--height", ImageSpec, "height", "image height", type=int)
    _field(r, "--seed", ImageSpec, "seed", "seed of jitter, lens and film samples", type=int)
    _field(
        r,
        "--storage",
        EngineSpec,
        "storage",
        "grid storage (auto: the smaller in memory)",
        choices=STORAGES,
    )
    _field(
        r,
        "--structure",
        EngineSpec,
        "structure",
        "the engine's structure: uniform grid or "
        "bounding volume hierarchy (auto: chosen per node by its objects)",
        choices=STRUCTURES,
    )
    _field(
        r,
        "--density",
        EngineSpec,
        "density",
        "grid density: voxels per object to start "
        "from, refined until a voxel holds about 4/DENSITY objects",
        type=float,
    )
    _field(
        r,
        "--threads",
        EngineSpec,
        "threads",
        "tracing threads (0: one per core; on a mesh, at most this many per node)",
        type=int,
    )
    r.add_argument(
        "--mesh",
        default="auto",
        help="ROWSxCOLS local meshnode processes; 1x1 traces in this process; "
        "auto (default): on this one machine, 1x1 on every core",
    )
    r.add_argument(
        "--cluster", help="render on running nodes listed in FILE (lines: ROW COL HOST:PORT)"
    )
    r.add_argument(
        "--wait",
        type=float,
        default=60.0,
        metavar="SECONDS",
        help="with --cluster: how long to wait for every node to accept a "
        "connection (nodes still starting) before naming the first that does "
        "not (default 60)",
    )
    r.add_argument(
        "--secret-file",
        help="the cluster's secret (default: $MESHTRACE_SECRET); a local mesh makes its own",
    )
    add_tls_options(r.add_argument_group("TLS to the nodes (with --cluster)"), "the host's client")
    r.add_argument(
        "--on-node-loss",
        choices=NODE_LOSS,
        default="replan",
        help="when a node dies or falls silent mid-frame: replan (finish the frame "
        "on the nodes left, same image) or fail (default replan)",
    )
    _field(
        r,
        "--overlap",
        MeshPlan,
        "overlap",
        "grow each node's box by PERCENT of its size; "
        f"auto: the simulated pre-pass picks of {', '.join(f'{o:g}' for o in OVERLAPS)} the "
        "fastest whose largest node fits the nodes' memory",
        type=_overlap,
    )
    _field(
        r,
        "--balance",
        MeshPlan,
        "balance",
        "mesh cuts: even image rectangles, or image "
        "cuts or object-space cells from a coarse simulated pass that evens the nodes' "
        "work (costs a few seconds up front)",
        choices=BALANCES,
    )
    r.add_argument(
        "--mode",
        choices=PLAN_MODES,
        default="auto",
        help="object: each node holds its box of space and passes rays; image: "
        "every node holds the whole scene and traces pixel tiles; auto "
        "(default): image when the scene's engine fits comfortably in every "
        "node's memory (the nodes report it), else object",
    )
    r.add_argument(
        "--node-memory",
        type=_bytes,
        help="plan --mode auto as if every node had "
        "this much memory (e.g. 512M, 8G) instead of what the nodes report",
    )
    _field(
        r,
        "--tiles",
        MeshPlan,
        "tiles",
        "image space: none (a band of rows a node), "
        "static (tiles dealt round-robin) or dynamic (dealt by the host as nodes finish)",
        choices=TILINGS,
    )
    _field(
        r,
        "--tile",
        MeshPlan,
        "tile",
        "image-space tile side, or object-space chunk side with --steal, pixels",
        type=int,
    )
    _field(r, "--buffer", MeshPlan, "buffer", "dynamic tiles each node holds ahead", type=int)
    _field(
        r,
        "--order",
        MeshPlan,
        "order",
        "dynamic tiles dealt row by row, or from the "
        "image's centre outward (the border last: even ends where it is background)",
        choices=ORDERS,
    )
    _field(
        r,
        "--steal",
        MeshPlan,
        "steal",
        "object space: nodes trace their rectangles in "
        "--tile chunks spiralling out from the centre, and one that runs out takes "
        "unstarted chunks from a busy neighbour's outer end",
        action="store_true",
    )
    _field(
        r,
        "--copies",
        MeshPlan,
        "copies",
        "object space: each node also holds its linked "
        "neighbours' objects and traces the rays they would take on (with --steal, a stolen "
        "chunk's work moves too; with --balance cost, also the cells the pre-pass shares)",
        action="store_true",
    )
    r.add_argument("--camera", help="render through a camera file (.toml) or lens table")
    _sampling_options(r.add_argument_group("sampling (pinhole --spp, or --camera --lens-rays)"))
    _camera_options(r.add_argument_group("camera (with --camera)"))
    k = sub.add_parser(
        "cluster-file",
        help="the cluster file of a Kubernetes StatefulSet of "
        "nodes (pod i is node i // COLS, i %% COLS)",
    )
    k.add_argument("--statefulset", required=True, help="the nodes' StatefulSet name")
    k.add_argument("--service", required=True, help="its headless Service (pod DNS names)")
    k.add_argument("--rows", type=int, required=True, help="mesh rows")
    k.add_argument("--cols", type=int, required=True, help="mesh columns")
    k.add_argument("--port", type=int, default=7700, help="the nodes' port (default 7700)")
    k.add_argument("--namespace", help="write full names (POD.SERVICE.NS.svc.cluster.local)")
    k.add_argument("-o", "--output", help="write to FILE (default: standard output)")
    c = sub.add_parser("camera", help="what a photographer asks of a camera or lens table")
    c.add_argument("camera", help="camera file (.toml, SI units) or lens table (mm)")
    c.add_argument("--focus", type=float, help="focus distance in metres (default: the file's)")
    c.add_argument("--coc", type=float, help="largest circle of confusion, m (default: d/1500)")
    c.add_argument("--f-number", type=float, help="stop the lens to this f-number")
    c.add_argument("--film-size", type=_film_size, help=FILM_SIZE_HELP)
    c.add_argument("--json", action="store_true", help="print JSON")
    return p


FILM_SIZE_HELP = "film WIDTHxHEIGHT in mm (default: the file's; 36x24 for a lens table)"


def _film_size(text: str) -> tuple[float, float]:
    """'36x24' (mm) -> (0.036, 0.024) metres."""
    try:
        w, h = (float(v) for v in text.lower().split("x"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not WIDTHxHEIGHT in mm") from None
    if not (0 < w < 1e6 and 0 < h < 1e6):
        raise argparse.ArgumentTypeError(f"{text!r}: both sides must be positive mm")
    return w / 1000, h / 1000


def _sampling_options(g) -> None:
    _field(
        g,
        "--sampling",
        CameraSampling,
        "sampling",
        "how a pixel's rays are placed; "
        "adaptive: two opposite corners first, the rest where they differ by more than "
        "--threshold",
        choices=SAMPLINGS,
    )
    _field(
        g,
        "--threshold",
        CameraSampling,
        "threshold",
        "adaptive sampling's colour difference",
        type=float,
    )


def _camera_options(g) -> None:
    _field(
        g,
        "--generation",
        CameraSampling,
        "generation",
        "generation area type 0..7 (2: rays in the first element's ellipse)",
        type=int,
    )
    _field(
        g,
        "--lens-rays",
        CameraSampling,
        "rays",
        "rays per pixel for types 2 and 3, or with a film area",
        type=int,
    )
    _field(
        g,
        "--film-area",
        CameraSampling,
        "film_area",
        "where on the pixel rays start (anti-aliasing in focus)",
        choices=FILM_AREAS,
    )
    _field(
        g,
        "--film-area-size",
        CameraSampling,
        "film_area_size",
        "film area, pixels across",
        type=float,
    )
    _field(
        g,
        "--special-jitter",
        CameraSampling,
        "special",
        "jitter over the film area instead of the lens: no depth of field",
        action="store_true",
    )
    _field(
        g,
        "--adaptation",
        CameraSampling,
        "adaptation",
        "average over all generated rays or those that left the camera",
        choices=ADAPTATIONS,
    )
    _field(
        g,
        "--focus",
        Focus,
        "distance",
        "focus distance in metres, 'infinity' or 'auto' "
        "(a probe pass on the image centre); default: the camera file's",
        type=_focus,
    )
    _field(
        g, "--dof-near", Focus, "dof_near", "depth of field: nearest sharp distance (m)", type=float
    )
    _field(
        g,
        "--dof-far",
        Focus,
        "dof_far",
        "farthest sharp distance (m; default infinity with --dof-near)",
        type=float,
    )
    _field(
        g,
        "--dof-tolerance",
        Focus,
        "dof_tolerance",
        "keep the focus distance +- this many metres sharp",
        type=float,
    )
    _field(
        g,
        "--coc",
        Focus,
        "coc",
        "largest circle of confusion on the film, m (default: diagonal/1500)",
        type=float,
    )
    _field(g, "--f-number", Focus, "f_number", "stop the lens to this f-number", type=float)
    g.add_argument("--film-size", type=_film_size, help=FILM_SIZE_HELP)


def _overlap(text: str) -> float | str:
    """An overlap in percent, or "auto"."""
    if text.strip().lower() == "auto":
        return "auto"
    try:
        return float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is neither a percentage nor auto") from None


def _bytes(text: str) -> int:
    """A memory size: bytes, or a number with K, M, G or T (powers of 1024)."""
    units = {"": 1, "K": 1 << 10, "M": 1 << 20, "G": 1 << 30, "T": 1 << 40}
    t = text.strip().upper().removesuffix("B").removesuffix("I")
    unit = t[-1:] if t[-1:] in units else ""
    try:
        value = float(t[: len(t) - len(unit)]) * units[unit]
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a memory size (e.g. 512M, 8G)") from None
    if not 0 < value < 1 << 62:
        raise argparse.ArgumentTypeError(f"{text!r}: a memory size must be positive")
    return int(value)


def _focus(text: str):
    """Metres as a number; words as they are (Focus says which words it takes)."""
    try:
        return float(text)
    except ValueError:
        return text


def main(argv=None) -> int:
    args = _parser().parse_args(argv)
    try:
        run = {"camera": _camera, "cluster-file": _cluster_file, "render": _render}
        code = run[args.command](args)
        sys.stdout.flush()  # a closed pipe shows here, not in the interpreter's last flush
        return code
    except BrokenPipeError:  # `host camera ... | head`: the reader left; not an error here
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 0
    except KeyboardInterrupt:  # Ctrl-C: every node is already stopped (LocalMesh's exit)
        print(f"\n{_prog()}: interrupted", file=sys.stderr)
        return 130


def _camera(args) -> int:
    from host.camera.lens import CameraError, describe, read_camera, with_f_number

    try:
        cam = read_camera(args.camera, args.film_size)
        if args.f_number is not None:
            cam = with_f_number(cam, args.f_number)
        d = describe(cam, args.focus, args.coc)
    except (CameraError, ValueError, OSError) as e:
        print(f"host: {e}", file=sys.stderr)
        return 2
    if args.json:
        print(json.dumps(_finite(d), indent=2, allow_nan=False))
        return 0
    fov = d["field_of_view_deg"]
    mm = 1000.0
    print(
        f"effective focal length  {d['effective_focal_length_m'] * mm:.2f} mm\n"
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
        f"{d['circle_of_confusion_m'] * mm:.3f} mm)"
    )
    return 0


def _cluster_file(args) -> int:
    try:
        text = statefulset_cluster(
            args.statefulset, args.service, args.rows, args.cols, args.port, args.namespace
        )
        if args.output:
            Path(args.output).write_text(text)
        else:
            sys.stdout.write(text)
    except (ValueError, OSError) as e:
        print(f"{_prog()}: {e}", file=sys.stderr)
        return 2
    return 0


def _finite(value):
    """JSON has no Infinity: infinite figures (focus at infinity) are written "infinity"."""
    if isinstance(value, dict):
        return {k: _finite(v) for k, v in value.items()}
    if isinstance(value, list):
        return [_finite(v) for v in value]
    if isinstance(value, float) and not math.isfinite(value):
        return "infinity" if value > 0 else "-infinity" if value < 0 else "nan"
    return value


def _render(args) -> int:
    def note(line: str) -> None:
        if not args.quiet:
            print(f"host: {line}", file=sys.stderr)

    try:
        scene = read_scene(args.scene, args.settings, note)
    except SceneError as e:
        print(f"host: {e}", file=sys.stderr)
        return 2
    except OSError as e:
        print(f"host: cannot read scene: {e}", file=sys.stderr)
        return 2
    live = None
    try:
        outputs = _outputs(args)
        image, engine, camera = _records(args)
        image, camera = _fit_aspect(image, camera, scene.view, args)
        live = _serve(args)
        img, stats = _run(scene, image, engine, camera, args, live and live.monitor)
    except (ValueError, OSError) as e:  # SpecError, CameraError and LiveError included
        return _failed(live, str(e), 2, args)
    except MeshError as e:
        return _failed(live, f"render failed: {e}", 1, args)
    except BaseException:  # Ctrl-C mid-render: the live view goes too
        if live is not None:
            live.stop()
        raise
    out, float_path, stats_path = outputs
    for path in (out, float_path):
        if path is not None:
            WRITERS[path.suffix.lower()](path, img)
    if stats_path:
        stats_path.write_text(json.dumps(stats, indent=2) + "\n")
    if live is not None:
        live.monitor.finish(img, stats)
    leaving = stats.get("camera", {}).get("rays_leaving_lens", 1.0)
    if leaving < 0.5:
        print(
            f"host: only {leaving:.0%} of the camera rays leave the camera (the rest are "
            "stopped by rims or diaphragms): a camera whose elements are not round about "
            "the axis is aimed at its film-most element; list its stop first (film side)",
            file=sys.stderr,
        )
    if not args.quiet and "mesh" in stats:
        r = {
            k: stats["rays"].get(k, 0)
            for k in (
                "eye_rays",
                "reflected_rays",
                "refracted_rays",
                "shadow_rays",
                "shadow_rays_blocked",
            )
        }
        print(
            f"{out}: mesh {stats['mesh']['rows']}x{stats['mesh']['cols']}  eye {r['eye_rays']}"
            f"  reflected {r['reflected_rays']}  refracted {r['refracted_rays']}  shadow "
            f"{r['shadow_rays']} (blocked {r['shadow_rays_blocked']})  passed "
            f"{stats['rays_passed']}  wall {stats['wall_seconds']:.2f} s  imbalance "
            f"{stats['imbalance']:.2f}",
            file=sys.stderr,
        )
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
    if live is not None:
        _linger(live, args)
    return 0


def _serve(args):
    """The live view's server, started (its URL printed), or None without --serve."""
    if args.serve is None:
        if args.serve_exit:
            raise ValueError("--serve-exit needs --serve [HOST:]PORT")
        return None
    from host.live.monitor import Monitor
    from host.live.server import LiveServer, parse_address

    host, port = parse_address(args.serve)
    live = LiveServer(Monitor(), host, port).start()
    print(f"host: live view at {live.url}", file=sys.stderr, flush=True)
    return live


def _failed(live, message: str, code: int, args) -> int:
    """Report a failed render; a live view shows it too, and stays as after a render."""
    print(f"host: {message}", file=sys.stderr)
    if live is not None:
        live.monitor.fail(message)
        _linger(live, args)
    return code


def _linger(live, args) -> None:
    """Keep the live view up until Ctrl-C, or with --serve-exit until every open page has
    the final state (at most 10 s); then stop it, leaving no thread or socket behind."""
    try:
        if args.serve_exit:
            live.wait_delivered(10.0)
        else:
            print(
                f"host: the live view stays at {live.url} until Ctrl-C", file=sys.stderr, flush=True
            )
            while live.thread.is_alive():
                live.thread.join(1.0)
    except KeyboardInterrupt:
        print("host: live view stopped", file=sys.stderr)
    finally:
        live.stop()


def _outputs(args) -> tuple[Path, Path | None, Path | None]:
    """The image, float image and statistics paths, checked before any work: a format this
    run can write, and a folder that exists and can be written (a render is never lost to a
    bad path or a missing library). A .png output gets a .pfm beside it unless --float says
    where; an .exr output is the float image itself."""
    out = Path(args.output or Path(args.scene).with_suffix(".png").name)
    float_path = Path(args.float_path) if args.float_path else None
    if float_path is None and out.suffix.lower() == ".png":
        float_path = out.with_suffix(".pfm")
    stats = Path(args.stats) if args.stats else None
    for path, suffixes, flag in (
        (out, (".png", ".exr"), "-o"),
        (float_path, (".pfm", ".exr"), "--float"),
    ):
        if path is not None and path.suffix.lower() not in suffixes:
            raise ValueError(
                f"{flag} {path}: writes {' or '.join(suffixes)} images, not "
                f"{path.suffix or 'a name without a suffix'!r}"
            )
        if path is not None and path.suffix.lower() == ".exr" and exr_missing():
            raise ValueError(f"{flag} {path}: {exr_missing()}")
    for path in (out, float_path, stats):
        if path is None:
            continue
        folder = path.parent if str(path.parent) else Path(".")
        if not folder.is_dir():
            raise ValueError(f"cannot write {path}: no folder {folder}")
        if not os.access(folder, os.W_OK) or (path.exists() and not os.access(path, os.W_OK)):
            raise ValueError(f"cannot write {path}: permission denied")
    return out, float_path, stats


def _records(args):
    """The render's records from the options (each checked by its record); options that do
    not apply to the chosen camera fail, or warn when they merely change nothing, by name."""
    image, engine = ImageSpec(**_given(args, ImageSpec)), EngineSpec(**_given(args, EngineSpec))
    sampling = _given(args, CameraSampling)
    if "threshold" in sampling and sampling.get("sampling") != "adaptive":
        raise ValueError("--threshold applies to --sampling adaptive only")
    if not args.camera:
        pinhole = _pinhole(args, image, sampling)
        return (
            (image, engine, None) if pinhole is None else (replace(image, spp=1), engine, pinhole)
        )
    from host.camera.lens import read_camera

    if image.spp != 1:
        raise ValueError(
            "--spp is for the pinhole; through a camera, rays per pixel are --lens-rays N"
        )
    sampled = CameraSampling(**sampling)
    _warn_unused(sampled, sampling)
    return (
        image,
        engine,
        CameraSetup(
            read_camera(args.camera, args.film_size), sampled, Focus(**_given(args, Focus))
        ),
    )


def _fit_aspect(image: ImageSpec, camera, view, args):
    """A film of another shape than the image would stretch the picture: the image takes the
    film's shape (its width kept) unless --width and --height both fix it, and then the film
    is cropped to the image's shape; either way one line says so."""
    if not isinstance(camera, CameraSetup):
        return image, camera
    w, h = image.sized(view).size
    cam = camera.camera
    film, picture = cam.film_width / cam.film_height, w / h
    if abs(film / picture - 1) < 0.5 / min(w, h):  # within half a pixel
        return image, camera
    mm = f"{cam.film_width * 1000:g} x {cam.film_height * 1000:g} mm film"
    fixed = image.spd or {"width", "height"} <= set(_given(args, ImageSpec))
    if not fixed:
        height = max(1, round(w / film))
        _warn(
            f"the {mm} is {film:.3g}:1 and the image {w}x{h}: rendering {w}x{height} so "
            "nothing is stretched (give --width and --height to keep a size; the film is "
            "then cropped)"
        )
        return replace(image, width=w, height=height), camera
    if film > picture:
        fw, fh = cam.film_height * picture, cam.film_height
    else:
        fw, fh = cam.film_width, cam.film_width / picture
    _warn(
        f"the {mm} is {film:.3g}:1 and the image {w}x{h} {picture:.3g}:1: cropping the film "
        f"to {fw * 1000:.3g} x {fh * 1000:.3g} mm so nothing is stretched"
    )
    return image, replace(camera, camera=replace(cam, film_width=fw, film_height=fh))


def _pinhole(args, image: ImageSpec, sampling: dict):
    """The scene's pinhole: plain jittered samples (the eye-ray kernel; None), or, for another
    --sampling, the pinhole set up as a camera (PinholeSetup; the image then takes its rays
    per pixel from it)."""
    flags = [
        FLAGS[f"{r.__name__}.{f}"]
        for r in CAMERA_ONLY
        for f in _given(args, r)
        if f not in PINHOLE_TOO
    ]
    flags += ["--film-size"] if args.film_size is not None else []
    if flags:
        raise ValueError(f"{', '.join(flags)}: camera options, which need --camera")
    how = sampling.get("sampling", "jittered")
    if how == "jittered":
        return None
    if image.spd:
        raise ValueError(f"--sampling {how}: the SPD rules fix the eye rays at pixel corners")
    if image.spp == 1 and how == "adaptive":
        _warn("--sampling adaptive with --spp 1 traces one ray per pixel; give --spp N")
    return PinholeSetup.of(how, image.spp, sampling.get("threshold"))


def _warn_unused(s: CameraSampling, given: dict) -> None:
    """Options that change nothing with this generation area and film area, by name."""
    if "rays" in given and s.per_pixel != s.rays:
        why = (
            f"generation {s.generation} traces its fixed {s.kind.points} points"
            if s.kind.points
            else f"generation {s.generation} traces one ray per pixel without --film-area"
        )
        _warn(f"--lens-rays {s.rays} changes nothing: {why}")
    if "sampling" in given and s.per_pixel == 1:
        _warn(f"--sampling {s.sampling} changes nothing: one ray per pixel")
    if "film_area_size" in given and s.film_area == "centre":
        _warn("--film-area-size changes nothing without --film-area ellipse|rectangle")


def _warn(text: str) -> None:
    print(f"host: warning: {text}", file=sys.stderr)


def _run(scene, image, engine, camera, args, watch=None):
    """Single node in this process, a local mesh of processes, or a running cluster;
    `watch`: the live view's monitor, or None."""
    if args.cluster:
        from protocols.handshake import read_secret

        rows, cols, addresses = read_cluster(args.cluster)
        plan = _plan(rows, cols, args)
        secret = read_secret(args.secret_file)
        tls = TlsFiles(args.tls_cert, args.tls_key, args.tls_ca).client()
        img, stats = _mesh(
            scene, image, engine, plan, camera, addresses, secret, args, tls, watch, args.wait
        )
        stats["plan"] = {"choice": f"cluster {rows}x{cols}", "why": f"--cluster {args.cluster}"}
        return img, stats
    if args.tls_cert or args.tls_key or args.tls_ca:
        raise ValueError(
            "--tls-cert, --tls-key and --tls-ca are for nodes of a --cluster (a "
            "local mesh talks over loopback with a secret of its own)"
        )
    rows, cols = parse_mesh(args.mesh)
    plan = _plan(rows, cols, args)
    if plan.nodes == 1:
        why = AUTO_WHY if args.mesh == "auto" else "asked for with --mesh 1x1"
        threads = engine.threads or os.cpu_count() or 1
        if not args.quiet:
            print(f"host: plan: one process, {threads} tracing threads ({why})", file=sys.stderr)
        img, stats = render(scene, image, engine, camera, progress=not args.quiet, watch=watch)
        stats["plan"] = {"choice": "one process", "threads": threads, "why": why}
        return img, stats
    secret = secrets.token_hex(32).encode()  # this render's own: other users cannot join
    with LocalMesh(plan.nodes, secret=secret) as addresses:
        img, stats = _mesh(scene, image, engine, plan, camera, addresses, secret, args, watch=watch)
    stats["plan"] = {
        "choice": f"local mesh {plan.rows}x{plan.cols}",
        "why": f"asked for with --mesh {args.mesh}",
    }
    return img, stats


def _plan(rows: int, cols: int, args) -> MeshPlan:
    """The mesh plan from the options, checked now (an asked-for mode with it)."""
    asked = {"mode": args.mode} if args.mode != "auto" else {}
    given = _given(args, MeshPlan)
    if _auto_overlap(args):  # the pre-pass chooses it (`render_on_mesh(overlaps=)`)
        del given["overlap"]
    return MeshPlan(rows, cols, **given, **asked)


def _auto_overlap(args) -> bool:
    """--overlap auto was given."""
    return getattr(args, "MeshPlan.overlap", None) == "auto"


def _mesh(
    scene, image, engine, plan, camera, addresses, secret, args, tls=None, watch=None, wait=5.0
):
    from tqdm import tqdm

    total = primary_rays(image.sized(scene.view), camera)
    shape = f"mesh {plan.rows}x{plan.cols}"
    bar = tqdm(
        total=total,
        unit=" rays",
        desc=f"{shape}: waiting for the nodes (connecting, "
        "building engines; a first run compiles kernels)",
        file=sys.stderr,
        disable=args.quiet,
        leave=False,
    )

    def ready():
        """Every node traces from now on: the rate and ETA count from here, without the
        nodes' build and kernel compile time."""
        bar.set_description(f"{shape} primary", refresh=False)
        bar.reset(total=total)

    try:
        return asyncio.run(
            render_on_mesh(
                scene,
                image,
                addresses,
                plan,
                engine,
                camera,
                secret=secret,
                progress=bar.update,
                on_node_loss=args.on_node_loss,
                tls=tls,
                mode=args.mode,
                node_memory=args.node_memory,
                overlaps=OVERLAPS if _auto_overlap(args) else (),
                notice=lambda text: bar.write(f"host: {text}", file=sys.stderr),
                watch=watch,
                ready=ready,
                wait=wait,
            )
        )
    finally:
        bar.close()


if __name__ == "__main__":
    sys.exit(main())
