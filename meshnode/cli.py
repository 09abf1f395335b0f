"""`meshnode` command line. `warmup` compiles the engine's and the camera's kernels into the
disk cache, so a node (or a container image) starts tracing without paying numba's compile
time."""

import argparse
import sys
import time

import numpy as np

from meshnode.scheduler import INCOMING_HIGH
from meshnode.tls import NO_TLS, TlsFiles, add_tls_options
from protocols import dtypes
from protocols.scene import SceneData, View


def _all_kinds_scene() -> SceneData:
    """A tiny scene with every primitive kind, a light and a transmitter."""
    scene = SceneData(view=View((0, 0, -5), (0, 0, 0), (0, 1, 0), 45.0))
    scene.materials = np.array(
        [((1, 1, 1), 0.8, 0.2, 10, 0, 1), ((1, 1, 1), 0.1, 0.1, 10, 0.9, 1.5)], dtypes.MATERIAL
    )
    scene.lights = np.array([((0, 5, -5), (1, 1, 1))], dtypes.LIGHT)
    scene.spheres = np.array([(0, 1, (0, 0, 0), 1.0)], dtypes.SPHERE)
    v = np.array([(2, 0, 0), (3, 0, 0), (2, 1, 0)], float)
    scene.triangles = np.array([(1, 0, v, np.tile((0, 0, -1.0), (3, 1)), 1)], dtypes.TRIANGLE)
    scene.polygons = np.array([(2, 0, 0, 4)], dtypes.POLYGON)
    scene.vertices = np.array([(-3, -1, 1), (3, -1, 1), (3, 1, 1), (-3, 1, 1)], float)
    scene.cones = np.array([(3, 0, (-2, 0, 0), 0.5, (-2, 1, 0), 0.2)], dtypes.CONE)
    return scene


def warmup() -> float:
    """Compile (or load) the all-kinds variant; returns the seconds it took."""
    from meshnode.engine import Engine

    start = time.perf_counter()
    Engine(_all_kinds_scene()).warmup()
    _camera_warmup()
    return time.perf_counter() - start


def _camera_warmup() -> None:
    """Compile the camera-ray kernels (elements, sampling, records) on a one-pixel batch."""
    from meshnode.engine.lenscamera import camera_rays
    from protocols.camera import CameraSpec

    lens = np.zeros(1, dtypes.ELEMENT)
    lens["kind"], lens["focal"], lens["ax"], lens["ay"] = dtypes.THIN_LENS, 0.05, 0.01, 0.01
    spec = CameraSpec(lens, 0.036, 0.024, -0.051)
    camera_rays(spec, View((0, 0, 0), (0, 0, 1), (0, 1, 0), 45.0), 1, 1, np.zeros(1, int))


def parse(argv=None) -> argparse.Namespace:
    p = argparse.ArgumentParser(prog="meshnode", description="Meshtrace mesh node.")
    sub = p.add_subparsers(dest="command", required=True)
    sub.add_parser("warmup", help="compile the tracing kernels into the disk cache")
    s = sub.add_parser("serve", help="serve as a mesh node")
    s.add_argument("--listen", default="127.0.0.1:7700",
                   help="HOST:PORT (default 127.0.0.1:7700; port 0: any free); another "
                        "address than loopback needs a cluster secret")  # fmt: skip
    s.add_argument("--secret-file", help="the cluster secret (default: $MESHTRACE_SECRET); "
                   "every host and node of the cluster must prove it holds the same one")
    s.add_argument("--insecure", action="store_true",
                   help="listen beyond loopback without a secret: anyone who reaches the port "
                        "can use the node")  # fmt: skip
    add_tls_options(s, "this node's")
    s.add_argument("--cluster", default="meshtrace", help="cluster id peers must match")
    s.add_argument("--once", action="store_true", help="exit after one render")
    s.add_argument("--threads", type=int, default=0,
                   help="tracing threads (default 0: one per core)")
    s.add_argument("--incoming-high", type=int, default=INCOMING_HIGH,
                   help="queued incoming rays at which the node stops reading from its "
                        f"neighbours (default {INCOMING_HIGH}, about 100 MB)")  # fmt: skip
    return p.parse_args(argv)


def main(argv=None) -> int:
    args = parse(argv)
    if args.command == "warmup":
        print(f"kernels ready in {warmup():.2f} s", file=sys.stderr)
        return 0
    try:
        secret = serving_secret(args)
        tls = TlsFiles(args.tls_cert, args.tls_key, args.tls_ca)
        if tls.ca is not None and tls.cert is None:
            raise ValueError("--tls-ca needs --tls-cert and --tls-key: a node listening with "
                             "TLS needs its own certificate")  # fmt: skip
        tls.server()
    except (ValueError, OSError) as e:
        print(f"meshnode: {e}", file=sys.stderr)
        return 2
    return serve(args.listen, args.cluster, args.once, args.threads, args.incoming_high,
                 secret=secret, tls=tls)  # fmt: skip


def serving_secret(args) -> bytes | None:
    """The cluster secret, and the rule that only loopback may go without one."""
    import ipaddress

    from protocols.handshake import read_secret

    secret = read_secret(args.secret_file)
    host = args.listen.rsplit(":", 1)[0].strip("[]")
    try:
        loopback = ipaddress.ip_address(host).is_loopback
    except ValueError:
        loopback = host == "localhost"
    if secret is None and not loopback and not args.insecure:
        raise ValueError(f"--listen {args.listen} reaches beyond this machine: give a cluster "
                         "secret (MESHTRACE_SECRET or --secret-file), or --insecure")
    return secret


def serve(listen: str, cluster: str, once: bool, threads: int = 0,
          incoming_high: int = INCOMING_HIGH, service_class=None,
          secret: bytes | None = None, tls: TlsFiles = NO_TLS) -> int:  # fmt: skip
    """Run the node service (uvloop when installed) until stopped."""
    import asyncio
    import logging
    import os

    from meshnode.service import NodeService

    service_class = service_class or NodeService

    logging.basicConfig(level=logging.INFO, format="meshnode %(levelname)s %(message)s")
    host, port = listen.rsplit(":", 1)

    async def main():
        service = service_class(host, int(port), cluster, once, threads or os.cpu_count() or 1,
                                incoming_high, secret, tls)  # fmt: skip
        try:
            bound = await service.start()
        except OSError as e:
            print(f"meshnode: cannot listen on {listen}: {e.strerror or e}", file=sys.stderr)
            return 2
        print(f"listening {host}:{bound}", flush=True)
        await service.run()

    try:
        import uvloop

        runner = uvloop.run
    except ImportError:
        runner = asyncio.run
    try:
        return runner(main()) or 0
    except KeyboardInterrupt:
        return 130


if __name__ == "__main__":
    sys.exit(main())
