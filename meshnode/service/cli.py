"""`meshnode` command line. `warmup` compiles every kernel variant the engine can choose into
the disk cache, so a node (or a container image) starts tracing without paying numba's compile
time."""

import argparse
import sys

from meshnode.engine.variants import KERNELS
from meshnode.mesh.scheduler import INCOMING_HIGH
from meshnode.service.config import KEEP_ENGINES, OBJECT_SHARE
from meshnode.transport.tls import NO_TLS, TlsFiles, add_tls_options
from protocols.units import memory_size


def parser() -> argparse.ArgumentParser:
    """Every `meshnode` command and its options (also walked by the help test)."""
    p = argparse.ArgumentParser(prog="meshnode", description="Meshtrace mesh node.")
    sub = p.add_subparsers(dest="command", required=True)
    w = sub.add_parser(
        "warmup",
        help="compile every tracing kernel variant into the disk "
        "cache (a first run: many minutes; later: seconds)",
    )
    w.add_argument(
        "--common",
        action="store_true",
        help="only the variants with every primitive kind, lights and refraction (one "
        "per structure)",
    )
    w.add_argument(
        "--variant",
        action="append",
        type=_variant,
        metavar="NAME",
        help="only this variant, as a render's statistics name it (e.g. "
        "triangles/flat/shadows/no-refraction/bvh; the grid's storage, csr, hash or "
        "brute-force, names the grid's; repeatable): no common kernels and no structure "
        "build (a first render compiles its tracing kernel so, beside itself)",
    )
    w.add_argument(
        "--kernels",
        type=_kernels,
        default=KERNELS,
        metavar="K,K",
        help=f"with --variant: which of its kernels, of {', '.join(KERNELS)} (default all)",
    )
    s = sub.add_parser("serve", help="serve as a mesh node")
    s.add_argument(
        "--listen",
        default="127.0.0.1:7700",
        help="HOST:PORT (default 127.0.0.1:7700; port 0: any free); another "
        "address than loopback needs a cluster secret",
    )
    s.add_argument(
        "--secret-file",
        help="the cluster secret (default: $MESHTRACE_SECRET); "
        "every host and node of the cluster must prove it holds the same one",
    )
    s.add_argument(
        "--insecure",
        action="store_true",
        help="listen beyond loopback without a secret: anyone who reaches the port "
        "can use the node",
    )
    add_tls_options(s, "this node's")
    s.add_argument("--cluster", default="meshtrace", help="cluster id peers must match")
    s.add_argument("--once", action="store_true", help="exit after one render")
    s.add_argument(
        "--threads", type=int, default=0, help="tracing threads (default 0: one per core)"
    )
    s.add_argument(
        "--object-share",
        type=_share,
        default=OBJECT_SHARE,
        help="the share of this node's free memory a render's objects may take, at most "
        f"4 GiB (default {OBJECT_SHARE:g})",
    )
    s.add_argument(
        "--keep-engines",
        type=memory_size,
        default=KEEP_ENGINES,
        metavar="SIZE",
        help="engines kept between renders for the next render of the same scene, at most "
        f"this many bytes (e.g. 512M; default {KEEP_ENGINES >> 30}G); the rest of a render's "
        "memory goes back to the system when it ends",
    )
    s.add_argument(
        "--incoming-high",
        type=int,
        default=INCOMING_HIGH,
        help="queued incoming rays at which the node stops reading from its "
        f"neighbours (default {INCOMING_HIGH}, about 100 MB)",
    )
    return p


def parse(argv=None) -> argparse.Namespace:
    return parser().parse_args(argv)


def main(argv=None) -> int:
    args = parse(argv)
    if args.command == "warmup":
        return _warmup(args.common, args.variant, args.kernels)
    try:
        secret = serving_secret(args)
        tls = TlsFiles(args.tls_cert, args.tls_key, args.tls_ca)
        if tls.ca is not None and tls.cert is None:
            raise ValueError(
                "--tls-ca needs --tls-cert and --tls-key: a node listening with "
                "TLS needs its own certificate"
            )
        tls.server()
    except (ValueError, OSError) as e:
        print(f"meshnode: {e}", file=sys.stderr)
        return 2
    return serve(
        args.listen,
        args.cluster,
        args.once,
        args.threads,
        args.incoming_high,
        secret=secret,
        tls=tls,
        object_share=args.object_share,
        keep_engines=args.keep_engines,
    )


def _share(text: str) -> float:
    """A share above 0 and at most 1."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number") from None
    if not 0 < value <= 1:
        raise argparse.ArgumentTypeError(f"{text!r}: a share must be above 0 and at most 1")
    return value


def _variant(name: str):
    from meshnode.engine.variants import Variant

    try:
        return Variant.parse(name)
    except ValueError as e:
        raise argparse.ArgumentTypeError(str(e)) from None


def _kernels(text: str) -> tuple[str, ...]:
    names = tuple(k.strip() for k in text.split(",") if k.strip())
    unknown = sorted(set(names) - set(KERNELS))
    if not names or unknown:
        raise argparse.ArgumentTypeError(f"{text!r}: want some of {', '.join(KERNELS)}")
    return names


def _warmup(common: bool, variants=None, kernels=KERNELS) -> int:
    from meshnode.engine.variants import all_variants
    from meshnode.service.warmup import EVERY_KIND, warmup

    def report(i, n, name):
        print(f"meshnode: kernels {i + 1}/{n}: {name}", file=sys.stderr, flush=True)

    if variants:
        seconds = warmup(variants, report, common=False, kernels=kernels, builds=False)
        print(f"kernels ready in {seconds:.2f} s", file=sys.stderr)
        return 0
    seconds = warmup(EVERY_KIND if common else all_variants(), report)
    print(f"kernels ready in {seconds:.2f} s", file=sys.stderr)
    return 0


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
        raise ValueError(
            f"--listen {args.listen} reaches beyond this machine: give a cluster "
            "secret (MESHTRACE_SECRET or --secret-file), or --insecure"
        )
    return secret


def serve(
    listen: str,
    cluster: str,
    once: bool,
    threads: int = 0,
    incoming_high: int = INCOMING_HIGH,
    service_class=None,
    secret: bytes | None = None,
    tls: TlsFiles = NO_TLS,
    object_share: float = OBJECT_SHARE,
    keep_engines: int = KEEP_ENGINES,
) -> int:
    """Run the node service (uvloop when installed) until stopped."""
    import asyncio
    import logging
    import os

    from meshnode.service.server import NodeService

    service_class = service_class or NodeService

    logging.basicConfig(level=logging.INFO, format="meshnode %(levelname)s %(message)s")
    host, port = listen.rsplit(":", 1)

    async def main():
        service = service_class(
            host,
            int(port),
            cluster,
            once,
            threads or os.cpu_count() or 1,
            incoming_high,
            secret,
            tls,
            object_share=object_share,
            keep_engines=keep_engines,
        )
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
