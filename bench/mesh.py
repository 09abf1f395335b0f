"""Mesh benchmark: SPD scenes on local meshes of meshnode processes, against one node in this
process.

    python -m bench.mesh [--scenes DIR] [--only balls,tetra] [--meshes 2x2,3x3]
                         [--overlaps 2,24,100] [--node-threads 1] [--balance even]
                         [--modes object,image] [--tiles static] [--tile 32]
                         [--size 512 --spp 1] [--camera FILE --lens-rays 16
                         --sampling adaptive] [--min-trace 5] [--repeat 3] [--together 1]
                         [--json FILE] [--plots DIR]

Per mesh and overlap: wall seconds, the busiest node's tracing CPU seconds, speedup = one
node's CPU seconds / busiest node's (the best of each; "median": the median over the renders
of one node's CPU / the busiest node's in the mesh render that followed; "work": the same
in the engine's work units (`meshnode.mesh.stats.work_units`: tests, hierarchy and occupancy
map steps, segments and segments sent on, each weighted by its fitted cost), which no
machine noise moves; "batch": one node's tracing CPU over the busiest node's CPU for its
whole batches (routing each ray to the node that takes it on, and its deposits, around the
kernels: `NodeCore.trace`), in turns; and for wall time), parallel efficiency (sum of
node CPU / nodes x busiest), imbalance (Tmax - Tmin) / Tmax over node CPU seconds, setup
seconds (until every node is built and linked), rays passed between nodes, and bytes per link
(mean and max over directed links). Counts are checked against the single node's. Without
--size the SPD rules (512x512 from corner rays); with it, SIZE x SIZE at --spp samples, and
with `--min-trace S` at more samples for a scene that one node traces in less than S CPU
seconds (through `--camera`: at more lens rays per pixel, `--lens-rays` the first; the image
takes the film's shape, SIZE wide). Every row renders on one node (in this process) and on
the mesh in turns, `--repeat
N` times (the mesh's nodes keep running, so later renders reuse their engines), and compares
the best of each (least tracing CPU; least busiest-node CPU): this machine's speed moves by
up to 1.6x for minutes at a time, so both sides are measured over the same span. Each
core's speed also moves by up to 25% within seconds, each core on its own, so a reference
taken a few seconds from the mesh still lands on other spells: `--together N` then measures
one node and the mesh at once, N times (one node renders on a thread here while the mesh
renders again and again until one node is done, so both share the same spells and the same
load), and "at once" is the median of those windows' one-node CPU / busiest-node CPU.
`--overlaps 2,auto` compares a fixed overlap with the one the cost pre-pass chooses
(`--overlap auto`: the row shows `a:<chosen>`); `--node-threads 1,2` runs every row with
nodes tracing on that many threads, side by side;
`--balance even,cost` compares the image cuts likewise; `--tiles static,dynamic` the image
space tilings, `--tile 32,64` their tile sides (samples) and `--orders rows,centre` the
order dynamic tiles are dealt in. `--plots DIR` writes a
per-node load plot (PNG) for every row: each node's tracing CPU against the busiest's. The
machine has 2 cores, so meshes of 4 and more processes share them: wall time shows that;
CPU seconds show the division of work.
"""

import argparse
import asyncio
import statistics
import sys
import time
from pathlib import Path

if __package__ in (None, ""):
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench import add_scenes_option, finish  # noqa: E402 (after the path is set)

COUNTS = (
    "eye_rays",
    "eye_hits",
    "reflected_rays",
    "refracted_rays",
    "shadow_rays",
    "shadow_rays_blocked",
)


def single(scene, image, warm: bool = True, camera=None):
    """(wall seconds, stats) of one node in this process, one thread: the CPU-seconds
    reference, after a warm run; `camera`: a host.camera.setup.CameraSetup, or the pinhole."""
    from host.run.oneprocess import render
    from protocols.render import EngineSpec

    if warm:
        render(scene, image, EngineSpec(threads=1), camera)
    start = time.perf_counter()
    _, stats = render(scene, image, EngineSpec(threads=1), camera)
    return time.perf_counter() - start, stats


def sized(scene, image, min_trace: float, camera=None):
    """(image, camera, single-node run) with the samples per pixel (through a camera: its
    lens rays) raised, in one step from a first measurement, until one node traces at least
    `min_trace` CPU seconds: the issue's work size for scenes that one node traces quickly
    (per-render costs then weigh as on a long render)."""
    import dataclasses
    import math

    run = single(scene, image, camera=camera)
    cpu = run[1]["trace_cpu_seconds"]
    if not min_trace or cpu >= min_trace:
        return image, camera, run
    scale = min_trace * SIZE_MARGIN / cpu
    if camera is None:
        image = dataclasses.replace(image, spp=math.ceil(image.spp * scale))
    else:
        rays = math.ceil(camera.sampling.rays * scale)
        camera = dataclasses.replace(
            camera, sampling=dataclasses.replace(camera.sampling, rays=rays)
        )
    return image, camera, single(scene, image, camera=camera)


def camera_setup(path: Path, rays: int, sampling: str, width: int):
    """(CameraSetup, its image: `width` wide, the film's shape) for `--camera`, focused on
    the image centre (a probe pass)."""
    from host.camera.lens import read_camera
    from host.camera.setup import CameraSetup, Focus
    from protocols.camera import CameraSampling
    from protocols.render import ImageSpec

    camera = read_camera(path)
    height = max(1, round(width * camera.film_height / camera.film_width))
    setup = CameraSetup(
        camera, CameraSampling(rays=rays, sampling=sampling), Focus(distance="auto")
    )
    return setup, ImageSpec(width=width, height=height)


# Samples are raised for min_trace * SIZE_MARGIN seconds: one node's later runs in the rows
# (best of --repeat, caches warm) traced 10-20% less than the sizing run (session 10: balls
# and tetra 4.1-4.8 s at --min-trace 5 with a margin of 1.1).
SIZE_MARGIN = 1.3


def on_mesh(
    scene,
    image,
    rows,
    cols,
    overlap,
    threads=1,
    balance="even",
    mode="object",
    tiles="static",
    steal=False,
    repeat=1,
    tile=32,
    copies=False,
    together=0,
    order="rows",
    camera=None,
):
    """(wall seconds, stats, one node's run) of the render on a local mesh: of `repeat`
    renders on the same running nodes, the one whose busiest node traced least; its
    `setup_seconds` are the first render's (engines built), `setup_reused_seconds` its own
    (engines kept). One node renders in this process before each mesh render, taking turns
    with it, and the best of those runs is the row's reference: this machine's speed moves
    by up to 1.6x for minutes at a time, so the two sides are measured over the same span.
    Then `together` times both at once (`at_once`): the stats' `together` holds each
    window's one-node CPU seconds and its mesh renders' mean busiest-node CPU seconds."""
    from host.planning.balance import OVERLAPS
    from host.run.localmesh import LocalMesh
    from host.run.meshclient import render_on_mesh
    from protocols.render import MeshPlan

    auto = overlap == "auto"  # the pre-pass chooses (`--overlap auto`)
    plan = MeshPlan(
        rows,
        cols,
        OVERLAPS[0] if auto else overlap,
        balance,
        mode,
        tiles,
        tile=tile,
        steal=steal,
        copies=copies,
        order=order,
    )
    runs, singles, windows = [], [], []

    def mesh_render():
        start = time.perf_counter()
        _, stats = asyncio.run(
            render_on_mesh(
                scene, image, addresses, plan, camera=camera, overlaps=OVERLAPS if auto else ()
            )
        )
        if stats["lost_nodes"]:  # re-planned on fewer nodes: not the row's mesh
            raise RuntimeError(f"{rows}x{cols}: nodes lost {stats['lost_nodes']}")
        return start, time.perf_counter(), stats

    with LocalMesh(rows * cols, threads=threads, once=False) as addresses:
        for _ in range(repeat):
            singles.append(single(scene, image, warm=False, camera=camera))
            start, end, stats = mesh_render()
            runs.append((end - start, stats))
        for _ in range(together):
            windows.append(
                at_once(lambda: single(scene, image, warm=False, camera=camera), mesh_render)
            )
    wall, best = min(runs, key=lambda r: r[1]["busiest_node_cpu_seconds"])
    best["together"] = windows
    best["setup_reused_seconds"] = best["setup_seconds"]
    best["setup_seconds"] = runs[0][1]["setup_seconds"]
    best["paired_speedups"] = [
        one[1]["trace_cpu_seconds"] / run[1]["busiest_node_cpu_seconds"]
        for one, run in zip(singles, runs, strict=True)
    ]
    return wall, best, min(singles, key=lambda r: r[1]["trace_cpu_seconds"])


def at_once(one_node, mesh_render) -> dict:
    """One node and the mesh measured over the same seconds: one node renders on a thread of
    this process while the mesh renders again and again, until one node is done; the mesh
    renders that ended by then (at least the first) give the mean busiest-node CPU seconds.
    This machine's cores change speed by up to 25% within seconds, each on its own, so one
    node measured before or after the mesh can land on a fast spell and the mesh on a slow
    one; at once, both share the same spells of both cores and the same load (every core
    busy, the tracing threads time-shared)."""
    from concurrent.futures import ThreadPoolExecutor

    with ThreadPoolExecutor(1) as pool:
        ref = pool.submit(lambda: (one_node(), time.perf_counter()))
        renders = [mesh_render()]
        while not ref.done():
            renders.append(mesh_render())
        (_, stats), ended = ref.result()
    inside = [r for r in renders if r[1] <= ended] or renders[:1]
    busiest = [r[2]["busiest_node_cpu_seconds"] for r in inside]
    return {
        "one_node_cpu_seconds": stats["trace_cpu_seconds"],
        "busiest_cpu_seconds": statistics.fmean(busiest),
        "mesh_renders": len(inside),
    }


def work(rays: dict) -> int:
    """Work in the engine's own units, as the simulated mesh counts it
    (`meshnode.mesh.stats.work_units`): the same on any machine, at any load."""
    from meshnode.mesh.stats import work_units

    return work_units(rays)


def load_plot(path: Path, title: str, stats: dict) -> None:
    """Each node's tracing CPU seconds as a bar against the busiest node's (PNG, Pillow)."""
    from PIL import Image, ImageDraw

    busy = [n["busy_cpu_seconds"] for n in stats["nodes"]]
    top = max(max(busy), 1e-9)
    w, row = 480, 18
    img = Image.new("RGB", (w, 30 + row * len(busy)), "white")
    d = ImageDraw.Draw(img)
    d.text((6, 6), title, fill="black")
    for i, b in enumerate(busy):
        y = 26 + i * row
        d.rectangle([70, y, 70 + (w - 150) * b / top, y + row - 5], fill=(70, 120, 200))
        d.rectangle([70, y, w - 80, y + row - 5], outline=(160, 160, 160))
        d.text((6, y), f"node {i}", fill="black")
        d.text((w - 74, y), f"{b:.2f} s", fill="black")
    img.save(path)


def link_bytes(stats):
    sizes = [link["bytes_out"] for n in stats["nodes"] for link in n["links"].values()]
    return (sum(sizes) / len(sizes), max(sizes)) if sizes else (0, 0)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="bench.mesh", description=__doc__.split("\n\n")[0])
    add_scenes_option(p)
    p.add_argument("--only", default="balls,tetra")
    p.add_argument("--meshes", default="2x2,3x3")
    p.add_argument(
        "--overlaps",
        default="2,24,100",
        help="object space overlaps (percent; auto: the pre-pass chooses)",
    )
    p.add_argument("--node-threads", default="1", help="tracing threads per node to compare")
    p.add_argument("--balance", default="even", help="image cuts to compare: even,cost")
    p.add_argument(
        "--modes",
        default="object",
        help="object,image: object space (every overlap and cut) and image space "
        "(static tiles; overlap and cuts do not apply)",
    )
    p.add_argument(
        "--tiles", default="static", help="image space tilings to compare: static,dynamic"
    )
    p.add_argument("--tile", default="32", help="image space tile sides (samples) to compare")
    p.add_argument(
        "--orders", default="rows", help="dynamic tiles' dealing orders to compare: rows,centre"
    )
    p.add_argument(
        "--steal", default="off", help="object space without and with stealing to compare: off,on"
    )
    p.add_argument(
        "--copies",
        default="off",
        help="object space without and with the neighbours' copies: off,on",
    )
    p.add_argument("--size", type=int, help="image SIZE x SIZE (default: the SPD rules)")
    p.add_argument("--spp", type=int, default=1, help="samples per pixel with --size")
    p.add_argument(
        "--camera",
        type=Path,
        help="with --size: render through this camera file "
        "(.toml) or lens table, focused on the image centre",
    )
    p.add_argument("--lens-rays", type=int, default=16, help="rays per pixel with --camera")
    p.add_argument("--sampling", default="adaptive", help="how --camera places a pixel's rays")
    p.add_argument(
        "--min-trace",
        type=float,
        default=0.0,
        help="with --size: raise a scene's samples per pixel until one node "
        "traces at least this many CPU seconds",
    )
    p.add_argument(
        "--repeat",
        type=int,
        default=1,
        help="best of N renders (least busiest-node CPU) for one node and each row",
    )
    p.add_argument(
        "--together",
        type=int,
        default=1,
        help="windows in which one node and the mesh are measured at once",
    )
    p.add_argument("--json", type=Path)
    p.add_argument("--plots", type=Path, help="folder for per-node load plots (PNG)")
    args = p.parse_args(argv)
    from host.scene.nff import read_nff
    from protocols.render import ImageSpec

    if (args.min_trace or args.camera) and not args.size:
        p.error("--min-trace and --camera need --size")
    base = (
        ImageSpec(width=args.size, height=args.size, spp=args.spp)
        if args.size
        else ImageSpec(spd=True)
    )
    lens = None
    if args.camera:
        lens, base = camera_setup(args.camera, args.lens_rays, args.sampling, args.size)
    if args.plots:
        args.plots.mkdir(parents=True, exist_ok=True)

    meshes = [tuple(int(v) for v in m.split("x")) for m in args.meshes.split(",")]
    overlaps = [o if o == "auto" else float(o) for o in args.overlaps.split(",")]
    results = []
    bad = []
    for name in args.only.split(","):
        scene = read_nff(args.scenes / f"{name}.nff")
        image, camera, (wall1, s1) = sized(scene, base, args.min_trace, lens)
        cpu1 = s1["trace_cpu_seconds"]
        ref = {k: s1["rays"][k] for k in COUNTS}
        rate = (
            f"{image.spp} spp"
            if camera is None
            else f"{camera.sampling.rays} {camera.sampling.sampling} lens rays"
        )
        print(
            f"\n== {name}: {image.width}x{image.height} at {rate}, 1x1 in process  "
            f"wall {wall1:.2f} s  tracing CPU {cpu1:.3f} s (each row: one node again, "
            "taking turns with the mesh)"
        )
        print(
            f"{'mesh':>5} {'mode':>6} {'overlap':>7} {'thr':>3} {'cuts':>18} {'wall s':>7} "
            f"{'one node CPU s':>14} {'busiest CPU s':>13} {'speedup':>7} {'median':>6} "
            f"{'at once':>7} {'batch':>5} "
            f"{'work':>5} {'wall':>5} "
            f"{'effic':>5} {'imbalance':>9} {'setup s':>7} {'rays passed':>11} "
            f"{'bytes/link mean':>15} {'max':>11} {'held':>4} shared"
        )
        threads = [int(t) for t in args.node_threads.split(",")]
        cuts = args.balance.split(",")
        steals = [s == "on" for s in args.steal.split(",")]
        copies = [s == "on" for s in args.copies.split(",")]
        levers = [(st, cp) for st in steals for cp in copies]
        runs = [
            (m, o, t, c, lv)
            for m in args.modes.split(",")
            for t in threads
            for o, c, lv in (
                [(o, c, lv) for o in overlaps for c in cuts for lv in levers]
                if m == "object"
                else [
                    (0.0, (t, int(side), order), (False, False))
                    for t in args.tiles.split(",")
                    for side in args.tile.split(",")
                    for order in args.orders.split(",")
                ]
            )
        ]
        for rows, cols in meshes:
            for mode, overlap, thr, cut, (steal, copy) in runs:
                side = order = None
                if mode == "image":  # `cut` names the tiling, tile side and order here
                    cut, side, order = cut
                    got = on_mesh(
                        scene,
                        image,
                        rows,
                        cols,
                        0.0,
                        thr,
                        "even",
                        mode,
                        cut,
                        repeat=args.repeat,
                        tile=side,
                        together=args.together,
                        order=order,
                        camera=camera,
                    )
                    cut += "" if side == 32 and len(args.tile.split(",")) == 1 else f"/{side}"
                    cut += "" if len(args.orders.split(",")) == 1 else f"/{order}"

                else:
                    got = on_mesh(
                        scene,
                        image,
                        rows,
                        cols,
                        overlap,
                        thr,
                        cut,
                        mode,
                        steal=steal,
                        repeat=args.repeat,
                        copies=copy,
                        together=args.together,
                        camera=camera,
                    )
                    cut += ("+steal" if steal else "") + ("+copies" if copy else "")
                wall, st, (wall1, s1) = got
                cpu1 = s1["trace_cpu_seconds"]
                work1 = work(
                    {
                        **s1["rays"],
                        "intersection_tests": s1["intersection_tests"],
                        "voxel_steps": s1["voxel_steps"],
                    }
                )
                work_busiest = max(work(n["rays"]) for n in st["nodes"])
                counts = {k: st["rays"][k] for k in COUNTS}
                if counts != ref:
                    bad.append(f"{name} {rows}x{cols} {mode} {cut} {overlap}%: {counts} != {ref}")
                busiest = st["busiest_node_cpu_seconds"]
                batch = cpu1 / max(st["busiest_node_batch_cpu_seconds"], 1e-9)
                together = (
                    statistics.median(
                        w["one_node_cpu_seconds"] / w["busiest_cpu_seconds"] for w in st["together"]
                    )
                    if st["together"]
                    else float("nan")
                )
                mean, top = link_bytes(st)
                used = st["mesh"]["overlap"]  # the pre-pass's choice under "auto"
                shown = f"a:{used:g}" if overlap == "auto" else f"{overlap:g}"
                row = {
                    "scene": name,
                    "mesh": f"{rows}x{cols}",
                    "mode": mode,
                    "overlap": overlap,
                    "overlap_used": used,
                    "node_threads": thr,
                    "cuts": cut,
                    "steal": steal,
                    "copies": copy,
                    "shared": list(st["mesh"].get("shared", ())),
                    "objects_held_max_share": st["objects_held_max_share"],
                    "tile": side,
                    "order": order,
                    "wall_seconds": wall,
                    "busiest_cpu_seconds": busiest,
                    "speedup": cpu1 / busiest,
                    "wall_speedup": wall1 / wall,
                    "batch_speedup": batch,
                    "node_batch_cpu_seconds": [n["batch_cpu_seconds"] for n in st["nodes"]],
                    "together": st["together"],
                    "together_speedup": together,
                    "paired_speedups": st["paired_speedups"],
                    "work_speedup": work1 / work_busiest,
                    "parallel_efficiency": st["parallel_efficiency"],
                    "setup_seconds": st["setup_seconds"],
                    "imbalance": st["imbalance"],
                    "setup_reused_seconds": st["setup_reused_seconds"],
                    "rays_passed": st["rays_passed"],
                    "bytes_per_link_mean": mean,
                    "bytes_per_link_max": top,
                    "single_cpu_seconds": cpu1,
                    "node_cpu_seconds": [n["busy_cpu_seconds"] for n in st["nodes"]],
                    "node_batches": [n["batches"] for n in st["nodes"]],
                    "balance": st.get("balance"),
                    "counts": counts,
                    "image": image.to_wire(),
                    "camera": None if camera is None else camera.sampling.to_wire(),
                }
                results.append(row)
                print(
                    f"{rows}x{cols:<3} {mode:>6} {shown:>7} {thr:>3} {cut:>18} {wall:>7.2f} "
                    f"{cpu1:>14.3f} {busiest:>13.3f} {row['speedup']:>7.2f} "
                    f"{statistics.median(st['paired_speedups']):>6.2f} {together:>7.2f} "
                    f"{batch:>5.2f} "
                    f"{row['work_speedup']:>5.2f} "
                    f"{row['wall_speedup']:>5.2f} {st['parallel_efficiency']:>5.2f} "
                    f"{st['imbalance']:>9.2f} {st['setup_seconds']:>7.2f} "
                    f"{st['rays_passed']:>11} {mean:>15,.0f} {top:>11,} "
                    f"{st['objects_held_max_share']:>4.0%} "
                    f"{','.join(map(str, row['shared'])) or '-'}"
                )
                if args.plots:
                    tag = f"{name}-{rows}x{cols}-{mode}-{cut}-{shown}-t{thr}"
                    load_plot(
                        args.plots / f"{tag}.png",
                        f"{tag}: speedup "
                        f"{row['speedup']:.2f}, efficiency "
                        f"{st['parallel_efficiency']:.2f}",
                        st,
                    )
    return finish(
        results,
        args.json,
        bad,
        "COUNT MISMATCH:\n",
        "ray counts equal the single node's on every mesh and overlap",
    )


if __name__ == "__main__":
    sys.exit(main())
