"""A row of the `bench.mesh` table: the figures of one mesh render against one node's (kept
for JSON), the printed line and the per-node load plot, apart from the runs that measure them."""

import statistics
from pathlib import Path

from meshnode.engine.counters import RAY_COUNTS
from meshnode.mesh.stats import RAY_KINDS

COUNTS = RAY_COUNTS


def work(rays: dict) -> int:
    """Work in the engine's own units, as the simulated mesh counts it
    (`meshnode.mesh.stats.work_units`): the same on any machine, at any load."""
    from meshnode.mesh.stats import work_units

    return work_units(rays)


def link_bytes(stats):
    """(mean, max) bytes sent over one directed link: the traffic a mesh costs."""
    sizes = [link["bytes_out"] for n in stats["nodes"] for link in n["links"].values()]
    return (sum(sizes) / len(sizes), max(sizes)) if sizes else (0, 0)


def figures(key: dict, got: tuple, image, camera) -> dict:
    """The row's figures (`key`: scene, mesh, mode, overlap, node_threads, cuts, steal, copies,
    tile, order) from `got`, what `on_mesh` returned: speedups of every kind, balance, setup,
    traffic and the counts the single node's are checked against."""
    wall, st, (wall1, s1) = got
    cpu1 = s1["trace_cpu_seconds"]
    work1 = work(
        {
            **s1["rays"],
            "intersection_tests": s1["intersection_tests"],
            "voxel_steps": s1["voxel_steps"],
        }
    )
    node_work = [work(n["rays"]) for n in st["nodes"]]
    work_busiest = max(node_work)
    busiest = st["busiest_node_cpu_seconds"]
    together = (
        statistics.median(
            w["one_node_cpu_seconds"] / w["busiest_cpu_seconds"] for w in st["together"]
        )
        if st["together"]
        else float("nan")
    )
    frame_together = (
        statistics.median(
            w["one_node_frame_cpu_seconds"] / w["busiest_frame_cpu_seconds"] for w in st["together"]
        )
        if st["together"]
        else float("nan")
    )
    traced = sum(st["rays"][k] for k in RAY_KINDS)
    mean, top = link_bytes(st)
    prepass = (st.get("balance") or {}).get("prepass") or {}
    row = {
        "scene": key["scene"],
        "mesh": key["mesh"],
        "mode": key["mode"],
        "overlap": key["overlap"],
        "overlap_used": st["mesh"]["overlap"],  # the pre-pass's choice under "auto"
        "node_threads": key["node_threads"],
        "cuts": key["cuts"],
        "steal": key["steal"],
        "copies": key["copies"],
        "shared": list(st["mesh"].get("shared", ())),
        "objects_held_max_share": st["objects_held_max_share"],
        "tile": key["tile"],
        "order": key["order"],
        "wall_seconds": wall,
        "busiest_cpu_seconds": busiest,
        "speedup": cpu1 / busiest,
        "wall_speedup": wall1 / wall,
        "batch_speedup": cpu1 / max(st["busiest_node_batch_cpu_seconds"], 1e-9),
        "node_batch_cpu_seconds": [n["batch_cpu_seconds"] for n in st["nodes"]],
        "together": st["together"],
        "together_speedup": together,
        "paired_speedups": st["paired_speedups"],
        "work_speedup": work1 / work_busiest,
        # on whole processes' CPU for the frame (kernels, routing, framing, event loop): one
        # process's frame CPU over the busiest node's, in turns and at once (`together`: one
        # node in a process of its own, `bench.one_process`)
        "frame_speedup": s1["frame_cpu_seconds"] / max(st["busiest_node_frame_cpu_seconds"], 1e-9),
        "frame_together_speedup": frame_together,
        "busiest_frame_cpu_seconds": st["busiest_node_frame_cpu_seconds"],
        "passes_per_ray": st["rays_passed"] / max(traced, 1),
        "max_share": st["mesh"].get("max_share", 1.0),
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
        # what the work and frame speedups' busiest node is the busiest of
        "node_work_units": node_work,
        "node_frame_cpu_seconds": [n.get("frame_cpu_seconds", 0.0) for n in st["nodes"]],
        "node_loop_cpu_seconds": [n.get("loop_cpu_seconds", 0.0) for n in st["nodes"]],
        "one_frame_cpu_seconds": s1["frame_cpu_seconds"],
        "work_summed_over_one": sum(node_work) / max(work1, 1),
        "sky_tiles": st.get("sky_tiles", {}),
        "balance": st.get("balance"),
        # the cost pre-pass's CPU against one node's measured tracing, and what it skipped
        "prepass_share": prepass.get("cpu_seconds", 0.0) / max(cpu1, 1e-9),
        "prepass_charged_share": prepass.get("charged_cpu_seconds", 0.0) / max(cpu1, 1e-9),
        "prepass_skipped": [s["stage"] for s in prepass.get("skipped", ())],
        "counts": {k: st["rays"][k] for k in COUNTS},
        "image": image.to_wire(),
        "camera": None if camera is None else camera.sampling.to_wire(),
    }
    row["frame_parts"] = frame_parts(row)  # the frame speedup's parts: overhead and balance
    return row


def frame_parts(row: dict) -> dict:
    """Where the frame speedup goes: it is N / (summed x balance), with `summed` the nodes'
    frame CPU added up over one process's frame CPU (the work the mesh adds: kernels tracing
    more, routing, the event loop) and `balance` the busiest node's over the mean node's.
    `summed` is split into the nodes' kernels, their routing around the kernels in whole
    batches, and the rest of their process (the event loop, framing, the sky's deposits),
    each over one process's frame (`event_loop`: of that rest, the event loop's thread);
    `work` is the kernels' summed work units over one's, and `even` the speedup were the
    nodes evenly loaded (N / summed)."""
    one = max(row["one_frame_cpu_seconds"], 1e-9)
    frames, batches = row["node_frame_cpu_seconds"], row["node_batch_cpu_seconds"]
    kernels = row["node_cpu_seconds"]
    summed = sum(frames) / one
    n = len(frames)
    return {
        "summed": summed,
        "balance": max(frames) / max(sum(frames) / n, 1e-9),
        "even": n / max(summed, 1e-9),
        "kernels": sum(kernels) / one,
        "routing": (sum(batches) - sum(kernels)) / one,
        "outside_batches": (sum(frames) - sum(batches)) / one,
        "event_loop": sum(row.get("node_loop_cpu_seconds", [])) / one,
        "one_kernels": row["single_cpu_seconds"] / one,
        "work": row["work_summed_over_one"],
    }


def print_header(name: str, image, camera, wall1: float, cpu1: float) -> None:
    """The scene's line (its image, sampling and one node's figures) and the column names."""
    rate = (
        f"{image.spp} spp"
        if camera is None
        else f"{image.spp} {camera.sampling.sampling} lens rays"
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
        f"{'bytes/link mean':>15} {'max':>11} {'held':>4} {'budget':>6} {'frame':>5} "
        f"{'frame@once':>10} {'pass/ray':>8} shared"
    )


def shown_overlap(row: dict) -> str:
    """The overlap as printed: the pre-pass's choice as `a:<chosen>` under "auto"."""
    overlap = row["overlap"]
    return f"a:{row['overlap_used']:g}" if overlap == "auto" else f"{overlap:g}"


def print_row(row: dict) -> None:
    """The row's line of the table, under `print_header`'s columns."""
    rows, cols = row["mesh"].split("x")
    print(
        f"{rows}x{cols:<3} {row['mode']:>6} {shown_overlap(row):>7} {row['node_threads']:>3} "
        f"{row['cuts']:>18} {row['wall_seconds']:>7.2f} "
        f"{row['single_cpu_seconds']:>14.3f} {row['busiest_cpu_seconds']:>13.3f} "
        f"{row['speedup']:>7.2f} "
        f"{statistics.median(row['paired_speedups']):>6.2f} {row['together_speedup']:>7.2f} "
        f"{row['batch_speedup']:>5.2f} "
        f"{row['work_speedup']:>5.2f} "
        f"{row['wall_speedup']:>5.2f} {row['parallel_efficiency']:>5.2f} "
        f"{row['imbalance']:>9.2f} {row['setup_seconds']:>7.2f} "
        f"{row['rays_passed']:>11} {row['bytes_per_link_mean']:>15,.0f} "
        f"{row['bytes_per_link_max']:>11,} "
        f"{row['objects_held_max_share']:>4.0%} {row['max_share']:>6.0%} "
        f"{row['frame_speedup']:>5.2f} {row['frame_together_speedup']:>10.2f} "
        f"{row['passes_per_ray']:>8.3f} "
        f"{','.join(map(str, row['shared'])) or '-'}"
    )
    if row["mode"] == "object":
        f = row["frame_parts"]
        print(
            f"      frame: the nodes' summed {f['summed']:.2f} of one process's (kernels "
            f"{f['kernels']:.2f}, their work units {f['work']:.2f} of one's; routing "
            f"{f['routing']:.2f}; outside batches {f['outside_batches']:.2f}, the event loop's "
            f"thread {f['event_loop']:.2f}; one process's "
            f"kernels {f['one_kernels']:.2f}), busiest / mean {f['balance']:.2f}: "
            f"{len(row['node_frame_cpu_seconds'])} / ({f['summed']:.2f} x {f['balance']:.2f}); "
            f"evenly loaded {f['even']:.2f}"
        )
    if row["prepass_share"]:
        skipped = ", ".join(dict.fromkeys(row["prepass_skipped"])) or "nothing"
        print(
            f"      pre-pass: {row['prepass_share']:.1%} of one node's tracing CPU "
            f"({row.get('prepass_charged_share', 0.0):.1%} charged); skipped: {skipped}"
        )


def plot_row(folder: Path, row: dict, stats: dict) -> None:
    """The row's per-node load plot in `folder`, named after the row."""
    tag = (
        f"{row['scene']}-{row['mesh']}-{row['mode']}-{row['cuts']}-{shown_overlap(row)}"
        f"-t{row['node_threads']}"
    )
    load_plot(
        folder / f"{tag}.png",
        f"{tag}: speedup {row['speedup']:.2f}, efficiency {stats['parallel_efficiency']:.2f}",
        stats,
    )


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
