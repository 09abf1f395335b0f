"""The argparse parser of `host` / `meshtrace`: its commands and their options. Render
options are bound to record fields (`host.cli.options`); nothing here acts on them.
"""

import argparse
import sys
from pathlib import Path

from host.camera.policy import LENS_SPP
from host.cli.options import (
    FILM_SIZE_HELP,
    camera_options,
    film_size,
    overlap,
    record_option,
    sampling_options,
    share,
)
from host.planning.holding import OVERLAPS
from host.planning.request import PLAN_MODES
from host.run.errors import NODE_LOSS
from host.scene.formats import FORMATS
from meshnode.transport.tls import add_tls_options
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
from protocols.units import memory_size


def _version() -> str:
    """The installed distribution's version, for --version."""
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("meshtrace")
    except PackageNotFoundError:
        return "unknown (not installed)"


class _Version(argparse.Action):
    """--version: the installed version, looked up only when asked for (reading the
    distribution's metadata took 7 ms of every command's start)."""

    def __init__(self, option_strings, dest=argparse.SUPPRESS, **kwargs):
        shown = "show program's version number and exit"  # argparse's own words
        super().__init__(option_strings, dest, nargs=0, help=shown)

    def __call__(self, parser, namespace, values, option_string=None):
        print(f"{parser.prog} {_version()}")
        parser.exit()


def prog() -> str:
    """`meshtrace` when run by that name (the same commands as `host`, which /usr/bin/host,
    the DNS lookup tool, shadows outside a virtual environment), else `host`."""
    return "meshtrace" if Path(sys.argv[0]).name == "meshtrace" else "host"


def _parser() -> argparse.ArgumentParser:
    """The command line: `render`, `cluster-file` and `camera`, each with its options."""
    p = argparse.ArgumentParser(
        prog=prog(), description="Meshtrace host: render scenes (NFF, OBJ, PLY, Open Inventor)."
    )
    p.add_argument("--version", action=_Version)
    sub = p.add_subparsers(dest="command", required=True)
    _render_parser(sub)
    _cluster_file_parser(sub)
    _camera_parser(sub)
    return p


def _render_parser(sub) -> None:
    """`render`: a scene with the options of each record of the render, in --help's order."""
    r = sub.add_parser("render", help="render a scene file")
    _file_options(r)
    _image_options(r)
    _engine_options(r)
    _placement_options(r)
    _plan_options(r)
    _tile_options(r)
    r.add_argument("--camera", help="render through a camera file (.toml) or lens table")
    sampling_options(r.add_argument_group("sampling (of --spp rays per pixel, any camera)"))
    camera_options(r.add_argument_group("camera (with --camera)"))


def _file_options(r) -> None:
    """What is read and written, and the live view."""
    formats = "; ".join(f"{ext} {what}" for ext, what in FORMATS.items())
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


def _image_options(r) -> None:
    """ImageSpec: the image and its rays."""
    record_option(
        r,
        "--spd",
        ImageSpec,
        "spd",
        "SPD rules: 512x512 from 513x513 corner rays, depth 5",
        action="store_true",
    )
    record_option(
        r,
        "--spp",
        ImageSpec,
        "spp",
        "rays (samples) per pixel, pinhole or --camera (placed by --sampling)",
        default_also=f"; {LENS_SPP} through --camera",
        type=int,
    )
    record_option(
        r, "--depth", ImageSpec, "depth", "maximum ray tree depth (eye ray = 1)", type=int
    )
    record_option(r, "--width", ImageSpec, "width", "image width (default: the scene's)", type=int)
    record_option(r, "--height", ImageSpec, "height", "image height", type=int)
    record_option(r, "--seed", ImageSpec, "seed", "seed of jitter, lens and film samples", type=int)


def _engine_options(r) -> None:
    """EngineSpec: how each engine stores and traces the scene."""
    record_option(
        r,
        "--storage",
        EngineSpec,
        "storage",
        "grid storage (auto: the smaller in memory)",
        choices=STORAGES,
    )
    record_option(
        r,
        "--structure",
        EngineSpec,
        "structure",
        "the engine's structure: uniform grid or "
        "bounding volume hierarchy (auto: chosen per node by its objects)",
        choices=STRUCTURES,
    )
    record_option(
        r,
        "--density",
        EngineSpec,
        "density",
        "grid density: voxels per object to start "
        "from, refined until a voxel holds about 4/DENSITY objects",
        type=float,
    )
    record_option(
        r,
        "--threads",
        EngineSpec,
        "threads",
        "tracing threads (0: one per core; on a mesh, at most this many per node)",
        type=int,
    )


def _placement_options(r) -> None:
    """Where the render runs: this process, a local mesh or a cluster's running nodes."""
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


def _plan_options(r) -> None:
    """MeshPlan's cuts and the choice of image or object space."""
    record_option(
        r,
        "--overlap",
        MeshPlan,
        "overlap",
        "grow each node's box by PERCENT of its size; "
        f"auto: the simulated pre-pass picks of {', '.join(f'{o:g}' for o in OVERLAPS)} the "
        "fastest whose largest node fits the nodes' memory",
        type=overlap,
    )
    record_option(
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
        type=memory_size,
        help="the memory each node gives its engines (e.g. 512M, 8G), instead of what the "
        "nodes report: --mode auto picks image space when the whole scene's engine takes a "
        "quarter of it at most; in object space no node's engines may exceed it",
    )
    record_option(
        r,
        "--max-share",
        MeshPlan,
        "max_share",
        "object space: no node may hold more than this share of the scene's objects (its "
        "copies counted, e.g. 0.25); the plan gives up what breaks it, or fails before any "
        "work naming the smallest share it reached",
        type=share,
    )
    r.add_argument(
        "--budget-copies",
        choices=("hottest", "none"),
        default="hottest",
        help="object space under --max-share or --node-memory: hottest (default) fills "
        "each node's room with copies of the cells where the cost pre-pass finds the most "
        "work, kept where it finds they lighten the busiest node; none: no copies",
    )


def _tile_options(r) -> None:
    """MeshPlan's tiles, chunks and copies: how work is dealt and shared on a mesh."""
    record_option(
        r,
        "--tiles",
        MeshPlan,
        "tiles",
        "image space: none (a band of rows a node), "
        "static (tiles dealt round-robin) or dynamic (dealt by the host as nodes finish)",
        choices=TILINGS,
    )
    record_option(
        r,
        "--tile",
        MeshPlan,
        "tile",
        "image-space tile side, or object-space chunk side with --steal, pixels",
        type=int,
    )
    record_option(
        r, "--buffer", MeshPlan, "buffer", "dynamic tiles each node holds ahead", type=int
    )
    record_option(
        r,
        "--order",
        MeshPlan,
        "order",
        "dynamic tiles dealt row by row, or from the "
        "image's centre outward (the border last: even ends where it is background)",
        choices=ORDERS,
    )
    record_option(
        r,
        "--steal",
        MeshPlan,
        "steal",
        "object space: nodes trace their rectangles in "
        "--tile chunks spiralling out from the centre, and one that runs out takes "
        "unstarted chunks from a busy neighbour's outer end",
        action="store_true",
    )
    record_option(
        r,
        "--copies",
        MeshPlan,
        "copies",
        "object space: each node also holds its linked "
        "neighbours' objects and traces the rays they would take on (with --steal, a stolen "
        "chunk's work moves too; with --balance cost, also the cells the pre-pass shares)",
        action="store_true",
    )


def _cluster_file_parser(sub) -> None:
    """`cluster-file`: the cluster file of a Kubernetes StatefulSet."""
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


def _camera_parser(sub) -> None:
    """`camera`: a camera file's figures."""
    c = sub.add_parser("camera", help="what a photographer asks of a camera or lens table")
    c.add_argument("camera", help="camera file (.toml, SI units) or lens table (mm)")
    c.add_argument("--focus", type=float, help="focus distance in metres (default: the file's)")
    c.add_argument("--coc", type=float, help="largest circle of confusion, m (default: d/1500)")
    c.add_argument("--f-number", type=float, help="stop the lens to this f-number")
    c.add_argument("--film-size", type=film_size, help=FILM_SIZE_HELP)
    c.add_argument("--json", action="store_true", help="print JSON")
