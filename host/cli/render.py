"""`host render`: the scene read, the render's records made from the options, the run
placed (one process, a local mesh or a cluster), the images and statistics written, and a
summary. Wiring only: the camera policy is `host.camera.policy`, the output paths
`host.run.outputs`. A mesh's modules (asyncio, the links, the planner's simulator, the
progress bar) are imported only when a mesh renders: a one-process render starts without them.
"""

import json
import os
import re
import sys
from typing import TYPE_CHECKING

from host.camera.policy import fit_aspect, lens_camera, pinhole
from host.camera.setup import Focus
from host.cli.options import FLAGS, given_fields
from host.planning.budget import check_divisible
from host.planning.holding import OVERLAPS
from host.planning.request import Auto, Request
from host.run.cluster import parse_mesh, read_cluster
from host.run.errors import MeshError
from host.run.oneprocess import render
from host.run.outputs import output_paths, write_images
from host.run.summary import summary_line
from host.scene.formats import SceneError, read_scene
from protocols.camera import CameraSampling
from protocols.render import EngineSpec, ImageSpec, MeshPlan

if TYPE_CHECKING:
    from host.run.connections import Nodes

CAMERA_ONLY = (CameraSampling, Focus)
PINHOLE_TOO = ("sampling", "threshold")  # CameraSampling fields the pinhole takes as well
AUTO_WHY = (
    "on one machine, threads in one process beat a local mesh of processes: no rays or "
    "pixels cross process boundaries; --mesh ROWSxCOLS starts a local mesh"
)


def command(args) -> int:
    """Render the scene as the options say; 2 for a bad scene or option, 1 for a failed mesh."""

    def note(line: str) -> None:
        if not args.quiet:
            print(f"host: {line}", file=sys.stderr)

    try:
        _check_inputs(args)
        scene = read_scene(args.scene, args.settings, note)
    except (ValueError, SceneError) as e:  # a bad option's file, or the scene file:line
        print(f"host: {e}", file=sys.stderr)
        return 2
    except OSError as e:
        print(f"host: cannot read scene: {e}", file=sys.stderr)
        return 2
    live = None
    try:
        outputs = output_paths(args.scene, args.output, args.float_path, args.stats)
        image, engine, camera = _records(args)
        size_given = {"width", "height"} <= set(given_fields(args, ImageSpec))
        image, camera = fit_aspect(image, camera, scene.view, size_given, _warn)
        live = _serve(args)
        img, stats = _run(scene, image, engine, camera, args, live and live.monitor)
    except (ValueError, OSError) as e:  # SpecError, CameraError and LiveError included
        return _failed(live, in_user_terms(str(e)), 2, args)
    except MeshError as e:
        return _failed(live, f"render failed: {e}", 1, args)
    except BaseException:  # Ctrl-C mid-render: the live view goes too
        if live is not None:
            live.stop()
        raise
    out, float_path, stats_path = outputs
    write_images(img, out, float_path)
    if stats_path:
        stats_path.write_text(json.dumps(stats, indent=2) + "\n")
    if live is not None:
        live.monitor.finish(img, stats)
    _report(out, stats, args.quiet)
    if live is not None:
        _linger(live, args)
    return 0


def _report(out, stats: dict, quiet: bool) -> None:
    """A camera that stops most of its rays, always; then, unless quiet, one summary of
    the rays and times."""
    leaving = stats.get("camera", {}).get("rays_leaving_lens", 1.0)
    if leaving < 0.5:
        print(
            f"host: only {leaving:.0%} of the camera rays leave the camera (the rest are "
            "stopped by rims or diaphragms): a camera whose elements are not round about "
            "the axis is aimed at its film-most element; list its stop first (film side)",
            file=sys.stderr,
        )
    if not quiet:
        print(summary_line(out, stats), file=sys.stderr)


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


# Files an option names, each read during the render: checked before any work.
INPUT_FILES = {
    "camera": "--camera",
    "cluster": "--cluster",
    "settings": "--settings",
    "secret_file": "--secret-file",
    "tls_cert": "--tls-cert",
    "tls_key": "--tls-key",
    "tls_ca": "--tls-ca",
}


def _check_inputs(args) -> None:
    """Every file an option names exists (one line naming the option, not an errno), and
    options that contradict each other are refused by name."""
    for name, flag in INPUT_FILES.items():
        path = getattr(args, name, None)
        if path and not os.path.isfile(path):
            what = "a folder, not a file" if os.path.isdir(path) else "no such file"
            raise ValueError(f"{flag} {path}: {what}")
    if args.cluster and args.mesh != "auto":
        raise ValueError(
            f"--mesh {args.mesh} and --cluster: choose one (the cluster file gives the mesh)"
        )


def in_user_terms(message: str) -> str:
    """`message` with every record field it names ("ImageSpec.spp") as the option that
    sets it ("--spp"): users type options, not records."""
    for field, flag in sorted(FLAGS.items(), key=lambda kv: -len(kv[0])):
        message = re.sub(
            rf"\b{re.escape(field)}\b( = )?",
            lambda m, flag=flag: flag + (" " if m.group(1) else ""),
            message,
            flags=re.IGNORECASE,
        )
    return message


def _records(args):
    """The render's records from the options (each checked by its record); options that do
    not apply to the chosen camera fail, or warn when they merely change nothing, by name."""
    image, engine = given_fields(args, ImageSpec), EngineSpec(**given_fields(args, EngineSpec))
    sampling = given_fields(args, CameraSampling)
    if "threshold" in sampling and sampling.get("sampling") != "adaptive":
        raise ValueError("--threshold applies to --sampling adaptive only")
    if not args.camera:
        _no_camera_options(args)
        image, camera = pinhole(ImageSpec(**image), sampling, _warn)
        return image, engine, camera
    focus = given_fields(args, Focus)
    image, camera = lens_camera(image, sampling, focus, args.camera, args.film_size, _warn)
    return image, engine, camera


def _no_camera_options(args) -> None:
    """Options of a camera, given without --camera, fail by name (the pinhole takes only
    --sampling and --threshold of them)."""
    flags = [
        FLAGS[f"{r.__name__}.{f}"]
        for r in CAMERA_ONLY
        for f in given_fields(args, r)
        if f not in PINHOLE_TOO
    ]
    flags += ["--film-size"] if args.film_size is not None else []
    if flags:
        raise ValueError(f"{', '.join(flags)}: camera options, which need --camera")


def _warn(text: str) -> None:
    """A warning: the render goes on."""
    print(f"host: warning: {text}", file=sys.stderr)


def _run(scene, image, engine, camera, args, watch=None):
    """Single node in this process, a local mesh of processes, or a running cluster;
    `watch`: the live view's monitor, or None."""
    if args.cluster:
        from host.run.connections import Nodes
        from meshnode.transport.tls import TlsFiles
        from protocols.handshake import read_secret

        rows, cols, addresses = read_cluster(args.cluster)
        request = _request(scene, image, engine, camera, rows, cols, args)
        secret = read_secret(args.secret_file)
        tls = TlsFiles(args.tls_cert, args.tls_key, args.tls_ca).client()
        nodes = Nodes(addresses, secret=secret, tls=tls, wait=args.wait)
        img, stats = _mesh(request, nodes, args, watch)
        stats["plan"] = {"choice": f"cluster {rows}x{cols}", "why": f"--cluster {args.cluster}"}
        return img, stats
    if args.tls_cert or args.tls_key or args.tls_ca:
        raise ValueError(
            "--tls-cert, --tls-key and --tls-ca are for nodes of a --cluster (a "
            "local mesh talks over loopback with a secret of its own)"
        )
    request = _request(scene, image, engine, camera, *parse_mesh(args.mesh), args)
    plan = request.plan
    if plan.nodes == 1:
        why = AUTO_WHY if args.mesh == "auto" else "asked for with --mesh 1x1"
        threads = engine.threads or os.cpu_count() or 1
        if not args.quiet:
            print(f"host: plan: one process, {threads} tracing threads ({why})", file=sys.stderr)
        img, stats = render(request, progress=not args.quiet, watch=watch)
        stats["plan"] = {"choice": "one process", "threads": threads, "why": why}
        return img, stats
    import secrets

    from host.run.connections import Nodes
    from host.run.localmesh import LocalMesh

    secret = secrets.token_hex(32).encode()  # this render's own: other users cannot join
    with LocalMesh(plan.nodes, secret=secret) as addresses:
        img, stats = _mesh(request, Nodes(addresses, secret=secret), args, watch)
    stats["plan"] = {
        "choice": f"local mesh {plan.rows}x{plan.cols}",
        "why": f"asked for with --mesh {args.mesh}",
    }
    return img, stats


def _request(scene, image, engine, camera, rows: int, cols: int, args) -> Request:
    """The render asked for on a rows x cols mesh, its plan checked now and a budget it
    cannot meet refused before any node starts."""
    auto = Auto(
        mode=args.mode,
        node_memory=args.node_memory,
        overlaps=OVERLAPS if _auto_overlap(args) else (),
        budget_copies=args.budget_copies == "hottest",
    )
    request = Request(scene, image, engine, camera, _plan(rows, cols, args), auto)
    check_divisible(scene, request.spec())
    return request


def _plan(rows: int, cols: int, args) -> MeshPlan:
    """The mesh plan from the options, checked now (an asked-for mode with it)."""
    asked = {"mode": args.mode} if args.mode != "auto" else {}
    given = given_fields(args, MeshPlan)
    if _auto_overlap(args):  # the pre-pass chooses it (`render_on_mesh(overlaps=)`)
        del given["overlap"]
    return MeshPlan(rows, cols, **given, **asked)


def _auto_overlap(args) -> bool:
    """--overlap auto was given."""
    return getattr(args, "MeshPlan.overlap", None) == "auto"


def _mesh(request: Request, nodes: "Nodes", args, watch=None):
    """The render on the mesh at `nodes`, with a progress bar of its primary rays."""
    import asyncio

    from tqdm import tqdm

    from host.run.meshclient import primary_rays, render_on_mesh

    total = primary_rays(request.sized, request.camera)
    plan = request.plan
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
                request,
                nodes,
                progress=bar.update,
                on_node_loss=args.on_node_loss,
                notice=lambda text: bar.write(f"host: {text}", file=sys.stderr),
                watch=watch,
                ready=ready,
            )
        )
    finally:
        bar.close()
