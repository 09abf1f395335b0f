"""Node kernel benchmark: what an image-space node's tracing costs with the mesh kernel (every
segment clipped to the node's box and checked against the occupancy map, for rays to pass on)
against the one-node kernel that `Engine.trace_node` uses when the node's box holds the whole
scene, on the same tiles of the same engine, taking turns; and what one mesh-kernel call
costs on a single ray (the fixed cost an object-space node pays per batch, many of which are a
few dozen passed rays) through the engine's bound entry point (`meshnode.engine.bound`) and
through numba's dispatcher.

    python -m bench.node_kernel [--scenes DIR] [--only balls,tetra] [--size 1024] [--spp 4]
                                [--tile 32] [--repeat 3] [--json FILE]

Each scene's engine is built as an image-space node builds it (its box the partition's scene
box); its eye rays are traced tile by tile (`--tile` pixels square, as the dynamic tiles deal
them), once with each kernel per round, `--repeat` rounds, on one thread pinned to one core
(`bench.timing`). The figures are tracing CPU seconds (thread time around each call) as
median (least-most) over the rounds, and mesh / one-node as the median of the rounds' paired
ratios (least-most). A call's microseconds (thread CPU), bound and dispatched, take turns the
same way. Both kernels must give the same colours and ray counts.
"""

import argparse
import sys
import time
from pathlib import Path

if __package__ in (None, ""):
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench import add_scenes_option, finish  # noqa: E402 (after the path is set)
from bench.timing import (  # noqa: E402
    Figure,
    Turns,
    interleaved,
    pin_one_core,
    pinned_text,
    turns,
)

COUNTS = ("eye_rays", "reflected_rays", "refracted_rays", "shadow_rays")


def tiles(view, image, side: int):
    """The image's eye-ray batches, one per tile of the partition's grid (`tile_grid`)."""
    from host.planning.rectangles import tile_grid
    from meshnode.engine.camera import eye_rays

    return [
        eye_rays(view, image, rows=(y0, y1), cols=(x0, x1))
        for x0, x1, y0, y1 in tile_grid(image.width, image.height, side)
    ]


def timed(trace, batches):
    """(tracing CPU seconds, colours, counts) of `trace` over every batch."""
    import numpy as np

    cpu, rgbs, counts = 0.0, [], {}
    for rays in batches:
        start = time.thread_time()
        rgb, done = trace(rays)[:2]
        cpu += time.thread_time() - start
        rgbs.append(rgb)
        for k in COUNTS:
            counts[k] = counts.get(k, 0) + done[k]
    return cpu, np.concatenate(rgbs), counts


def per_call(engine, trace, rays, repeat: int, calls: int = 2000) -> tuple[Figure, Figure]:
    """Thread CPU microseconds of one `trace(rays)` call (a single ray: the fixed cost a call
    pays) through `engine`'s bound entry point ("bound") and through numba's dispatcher
    ("dispatched"), `calls` calls a turn, the two taking turns `repeat` rounds."""
    from meshnode.engine.trace import trace_batch

    def each():
        for _ in range(calls):
            trace(rays)

    def dispatched():
        bound = engine._trace_batch
        engine._trace_batch = lambda key, *args: trace_batch(*args)
        try:
            each()
        finally:
            engine._trace_batch = bound

    times, _ = interleaved({"bound": each, "dispatched": dispatched}, repeat, time.thread_time)

    def micro(seconds: float) -> float:
        return 1e6 * seconds / calls

    return times.figure("bound").map(micro), times.figure("dispatched").map(micro)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="bench.node_kernel", description=__doc__.split("\n\n")[0])
    add_scenes_option(p)
    p.add_argument("--only", default="balls,gears,rings,tetra,teapot,mount_s1")
    p.add_argument("--size", type=int, default=1024)
    p.add_argument("--spp", type=int, default=4)
    p.add_argument("--tile", type=int, default=32, help="tile side in pixels")
    p.add_argument("--repeat", type=int, default=3)
    p.add_argument("--json", type=Path)
    args = p.parse_args(argv)
    import numpy as np

    from bench import read_scene
    from host.planning.cells import scene_box
    from meshnode.engine import Engine
    from protocols.render import ImageSpec

    core = pin_one_core()
    print(
        f"{args.size}x{args.size} at {args.spp} spp, {args.tile}-pixel tiles, one thread "
        f"{pinned_text(core)}, {args.repeat} rounds in turns: thread CPU, median (least-most); "
        f"mesh / one-node: the median of the rounds' paired ratios"
    )
    print(
        f"{'scene':>10} {'tiles':>6} {'mesh kernel s':>19} {'one-node kernel s':>19} "
        f"{'mesh / one-node':>16} {'call us bound':>19} {'dispatched':>19}"
    )
    rows, bad = [], []
    for name in args.only.split(","):
        scene = read_scene(args.scenes, name)
        box = scene_box(scene)
        engine = Engine(scene, box=box, scene_box=box)
        engine.warmup()
        image = ImageSpec(width=args.size, height=args.size, spp=args.spp)
        batches = tiles(scene.view, image, args.tile)

        mesh = engine.trace_passing  # an object-space node's kernel: spans, passing
        mesh(batches[0][:1])  # its entry point looked up (and loaded) before it is timed
        kernels = {"mesh": mesh, "one": engine.trace_node}
        times, last = Turns(), {}
        for _, label in turns(list(kernels), args.repeat):
            cpu, *last[label] = timed(kernels[label], batches)
            times.add(label, cpu)
        (m_rgb, m_counts), (o_rgb, o_counts) = last["mesh"], last["one"]
        if m_counts != o_counts or not np.allclose(m_rgb, o_rgb, rtol=0, atol=1e-12):
            bad.append(name)
        bound, typed = per_call(engine, mesh, batches[len(batches) // 2][:1], args.repeat)
        m, o, ratio = times.figure("mesh"), times.figure("one"), times.ratio("mesh", "one")
        rows.append(
            {
                "scene": name,
                "tiles": len(batches),
                "clock": "thread CPU seconds, in turns",
                **m.fields("mesh_kernel_cpu_seconds"),
                **o.fields("one_node_kernel_cpu_seconds"),
                **ratio.fields("ratio"),
                **bound.fields("call_us_bound"),
                **typed.fields("call_us_dispatched"),
                "counts": o_counts,
            }
        )
        print(
            f"{name:>10} {len(batches):>6} {m.text():>19} {o.text():>19} "
            f"{ratio.text('{:.2f}'):>16} {bound.text('{:.1f}'):>19} {typed.text('{:.1f}'):>19}"
        )
    return finish(
        rows,
        args.json,
        bad,
        "MISMATCH (colours or counts) between the kernels:\n",
        "both kernels gave the same colours and ray counts on every scene",
    )


if __name__ == "__main__":
    sys.exit(main())
