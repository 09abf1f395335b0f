"""Mesh benchmark: SPD scenes on local meshes of meshnode processes, against one node in this
process.

    python -m bench.mesh [--scenes DIR] [--only balls,tetra] [--meshes 2x2,3x3]
                         [--overlaps 2,24,100] [--node-threads 1] [--balance even]
                         [--max-share 0.5,0.25]
                         [--modes object,image] [--tiles static] [--tile 32]
                         [--size 512 --spp 1] [--camera FILE --sampling adaptive]
                         [--min-trace 5] [--repeat 3] [--together 1]
                         [--nodes-on-cpu CPU] [--json FILE] [--plots DIR]

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
seconds (through `--camera`: at more lens rays per pixel, `--spp` the first; the image
takes the film's shape, SIZE wide). Every row renders on one node (in this process) and on
the mesh in turns, `--repeat
N` times (the mesh's nodes keep running, so later renders reuse their engines), and compares
the best of each (least tracing CPU; least busiest-node CPU): this machine's speed moves by
up to 1.6x for minutes at a time, so both sides are measured over the same span. Each
core's speed also moves by up to 25% within seconds, each core on its own, so a reference
taken a few seconds from the mesh still lands on other spells: `--together N` then measures
one node and the mesh at once, N times (one node renders in a process of its own while the mesh
renders again and again until one node is done, so both share the same spells and the same
load), and "at once" is the median of those windows' one-node CPU / busiest-node CPU.
`--overlaps 2,auto` compares a fixed overlap with the one the cost pre-pass chooses
(`--overlap auto`: the row shows `a:<chosen>`); `--node-threads 1,2` runs every row with
nodes tracing on that many threads, side by side;
`--balance even,cost,objects` compares the cuts likewise; `--max-share` gives object space
a memory budget per mesh (`MeshPlan.max_share`: the plan gives up what breaks it), and the
rows show it ("budget") beside the share the fullest node held ("held"), the speedup on the
busiest node's whole process CPU for the frame against one process's ("frame": in turns;
"frame@once": at once, one node rendering in a process of its own) and rays passed per ray
traced, with a line taking the frame speedup apart (`mesh_rows.frame_parts`);
`--tiles static,dynamic` the image space tilings, `--tile 32,64` their tile sides (samples)
and `--orders rows,centre` the order dynamic tiles are dealt in. `--plots DIR` writes a
per-node load plot (PNG) for every row: each node's tracing CPU against the busiest's. The
machine has 2 cores, so meshes of 4 and more processes share them: wall time shows that;
CPU seconds show the division of work. `--nodes-on-cpu 0` runs every node on CPU 0, one run
queue sharing it evenly (spread over two, an odd count of busy processes leaves those on the
fuller queue less, and dynamic tiles, dealt by arrival, give the others more work).
"""

import argparse
import sys
from pathlib import Path

if __package__ in (None, ""):
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench import add_scenes_option, finish, per_mesh  # noqa: E402 (after the path is set)
from bench.mesh_reference import camera_setup, sized  # noqa: E402
from bench.mesh_rows import COUNTS, figures, plot_row, print_header, print_row  # noqa: E402
from bench.mesh_runs import on_mesh  # noqa: E402


def parser() -> argparse.ArgumentParser:
    """Command line options."""
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
    p.add_argument(
        "--balance", default="even", help="cuts to compare: even,cost,objects (MeshPlan.balance)"
    )
    p.add_argument(
        "--max-share",
        default="1",
        help="object space's budget: the share of the objects a node may hold, one for every "
        "mesh or one per mesh of --meshes (e.g. 0.5,0.25,0.15)",
    )
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
    p.add_argument(
        "--budget-copies",
        default="hottest",
        help="object space under --max-share: the budget's room filled with copies of the "
        "hottest cells (each copied cell's own work shared over its holders; 'owners': each "
        "block's eye rays made where its rectangle's node hands them) or left empty, to "
        "compare: hottest,owners,none",
    )
    p.add_argument("--size", type=int, help="image SIZE x SIZE (default: the SPD rules)")
    p.add_argument(
        "--spp", type=int, help="rays per pixel with --size (default 1; 16 through --camera)"
    )
    p.add_argument(
        "--camera",
        type=Path,
        help="with --size: render through this camera file "
        "(.toml) or lens table, focused on the image centre",
    )
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
    p.add_argument(
        "--nodes-on-cpu",
        type=int,
        metavar="CPU",
        help="run every node on this one CPU (taskset), so each gets an even share of it",
    )
    p.add_argument("--json", type=Path)
    p.add_argument("--plots", type=Path, help="folder for per-node load plots (PNG)")
    return p


def main(argv=None) -> int:
    """Every scene on every mesh and variant, each row printed as it finishes; exit 1 when a
    mesh's ray counts differ from the single node's."""
    p = parser()
    args = p.parse_args(argv)
    from protocols.render import ImageSpec

    if (args.min_trace or args.camera) and not args.size:
        p.error("--min-trace and --camera need --size")
    base = (
        ImageSpec(width=args.size, height=args.size, spp=args.spp or 1)
        if args.size
        else ImageSpec(spd=True)
    )
    lens = None
    if args.camera:
        from host.camera.policy import LENS_SPP

        lens, base = camera_setup(args.camera, args.spp or LENS_SPP, args.sampling, args.size)
    if args.plots:
        args.plots.mkdir(parents=True, exist_ok=True)

    meshes = [tuple(int(v) for v in m.split("x")) for m in args.meshes.split(",")]
    overlaps = [o if o == "auto" else float(o) for o in args.overlaps.split(",")]
    results = []
    bad = []
    for name in args.only.split(","):
        bench_scene(args, name, base, lens, meshes, overlaps, results, bad)
    return finish(
        results,
        args.json,
        bad,
        "COUNT MISMATCH:\n",
        "ray counts equal the single node's on every mesh and overlap",
    )


def bench_scene(args, name: str, base, lens, meshes, overlaps, results: list, bad: list) -> None:
    """One scene: one node sized and measured here, then every row of `row_plan` on every
    mesh; rows go to `results`, count mismatches to `bad`."""
    from bench import read_scene
    from host.planning.budget import BudgetError

    scene = read_scene(args.scenes, name)
    image, camera, (wall1, s1) = sized(scene, base, args.min_trace, lens)
    ref = {k: s1["rays"][k] for k in COUNTS}
    print_header(name, image, camera, wall1, s1["trace_cpu_seconds"])
    runs = row_plan(args, overlaps)
    shares = per_mesh(args.max_share, meshes)
    for (rows, cols), share in zip(meshes, shares, strict=True):
        for mode, overlap, thr, cut, (steal, copy, budget) in runs:
            try:
                got, cut, side, order = run_row(
                    args,
                    scene,
                    image,
                    camera,
                    (rows, cols),
                    mode,
                    overlap,
                    thr,
                    cut,
                    steal,
                    copy,
                    share if mode == "object" else 1.0,
                    budget,
                )
            except BudgetError as e:  # a budget this scene cannot be divided within
                print(f"{rows}x{cols:<3} refused: {e}")
                results.append({"scene": name, "mesh": f"{rows}x{cols}", "refused": str(e)})
                continue
            key = {
                "scene": name,
                "mesh": f"{rows}x{cols}",
                "mode": mode,
                "overlap": overlap,
                "node_threads": thr,
                "cuts": cut,
                "steal": steal,
                "copies": copy,
                "budget_copies": budget,
                "tile": side,
                "order": order,
            }
            row = figures(key, got, image, camera)
            if row["counts"] != ref:
                bad.append(
                    f"{name} {rows}x{cols} {mode} {cut} {overlap}%: {row['counts']} != {ref}"
                )
            results.append(row)
            print_row(row)
            if args.plots:
                plot_row(args.plots, row, got[1])


def row_plan(args, overlaps) -> list[tuple]:
    """(mode, overlap, node threads, cuts, (steal, copies)) of every row on one mesh: object
    space at every overlap, cut and lever; image space per tiling, tile side and order (its
    `cuts` is then that triple)."""
    threads = [int(t) for t in args.node_threads.split(",")]
    cuts = args.balance.split(",")
    steals = [s == "on" for s in args.steal.split(",")]
    copies = [s == "on" for s in args.copies.split(",")]
    budgets = args.budget_copies.split(",")
    levers = [(st, cp, b) for st in steals for cp in copies for b in budgets]
    return [
        (m, o, t, c, lv)
        for m in args.modes.split(",")
        for t in threads
        for o, c, lv in (
            [(o, c, lv) for o in overlaps for c in cuts for lv in levers]
            if m == "object"
            else [
                (0.0, (t, int(side), order), (False, False, "none"))
                for t in args.tiles.split(",")
                for side in args.tile.split(",")
                for order in args.orders.split(",")
            ]
        )
    ]


def run_row(
    args, scene, image, camera, mesh, mode, overlap, thr, cut, steal, copy, share=1.0, budget="none"
):
    """(what `on_mesh` returned, the row's cuts label, tile side, order) of one row: image
    space renders its tiling (overlap and cuts do not apply), object space its cuts."""
    rows, cols = mesh
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
            nodes_cpu=args.nodes_on_cpu,
        )
        cut += "" if side == 32 and len(args.tile.split(",")) == 1 else f"/{side}"
        cut += "" if len(args.orders.split(",")) == 1 else f"/{order}"
        return got, cut, side, order
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
        max_share=share,
        budget_copies=budget in ("hottest", "owners"),
        share_claims=budget == "hottest",
        nodes_cpu=args.nodes_on_cpu,
    )
    cut += ("+steal" if steal else "") + ("+copies" if copy else "")
    if share < 1 and budget in ("hottest", "owners"):
        cut += "+budget copies" + (" (owners' claims)" if budget == "owners" else "")
    return got, cut, None, None


if __name__ == "__main__":
    sys.exit(main())
