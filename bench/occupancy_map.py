"""What the occupancy map's marking buys an object-space mesh, on the same cells: the plan made
once (`host render`'s, under a memory budget), then its mesh simulated in this process with
the map marked where the objects' bounds reach (how the host marked it before session 45,
rasterised here), where their surfaces reach (`meshnode.engine.voxelize.touched_map`,
session 45) and, as the host marks it now, with each occupied voxel's 4x4x4 sub-voxels a
walk tests before it stops there (`Partition.occ_fine`, session 46; and where the host makes
one, the inner map, session 51: the first two maps go without it). Counts, not time: the
same cells, nodes and rays, so what changes is only which segments the map ends or passes on.

    python -m bench.occupancy_map [--scenes DIR] [--only balls,rings,teapot,tetra,mount]
                                  [--meshes 2x2,3x3,4x4] [--max-share 0.5,0.25,0.15]
                                  [--size 256] [--spp 8] [--json FILE]

Printed per scene and mesh, for each map: its occupied share, rays passed per eye ray, the
nodes' summed work units and the busiest node's; and their ratios to the bounds map's. The
mesh's hits, escapes and shadow rays are checked equal under all three maps.
"""

import argparse
import dataclasses
import sys
from pathlib import Path

import numpy as np

if __package__ in (None, ""):
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench import add_scenes_option, finish, per_mesh  # noqa: E402 (after the path is set)

SAME = ("eye_hits", "escaped", "shadow_rays", "shadow_rays_blocked", "reflected_rays")


def bounds_bits(scene, part) -> bytes:
    """The partition's map as it was marked before session 45 (`bounds_map`), packed."""
    box = np.asarray(part.scene_lo, float), np.asarray(part.scene_hi, float)
    return np.packbits(bounds_map(scene, *box, part.occ_res).ravel()).tobytes()


def bounds_map(scene, lo, hi, res) -> np.ndarray:
    """(z, y, x) bool: the map over lo..hi of `res` voxels as the host marked it before
    session 45: every voxel some object's bounds, padded by a millionth of the box's extent,
    reach."""
    from host.scene.derived import scene_tables

    res = np.asarray(res, np.int64)
    cell, tb = (hi - lo) / res, scene_tables(scene)
    pad = 1e-6 * float((hi - lo).max())
    first = np.clip(np.floor((tb.lo - pad - lo) / cell), 0, res - 1).astype(np.int64)
    last = np.clip(np.floor((tb.hi + pad - lo) / cell), 0, res - 1).astype(np.int64)
    full = np.zeros(tuple(res[::-1]), bool)
    for (x0, y0, z0), (x1, y1, z1) in zip(first, last, strict=True):  # once per object
        full[z0 : z1 + 1, y0 : y1 + 1, x0 : x1 + 1] = True
    return full


def simulated(scene, planned, part) -> dict:
    """The mesh of `planned` simulated on partition `part`: its counts and work."""
    from host.scene.subset import subset
    from meshnode.mesh.simulator import simulate

    outcome = simulate([subset(scene, k) for k in planned.holders], planned.spec, part)
    units = np.array([n.cost for n in outcome.nodes], float)
    bits = np.unpackbits(np.frombuffer(part.occ_bits, np.uint8), count=int(np.prod(part.occ_res)))
    return {
        "occupied": float(bits.mean()),
        "passed": sum(n.rays_sent for n in outcome.nodes),
        "units": float(units.sum()),
        "busiest": float(units.max()),
        "counts": outcome.totals(),
    }


def _row(runs: dict, key: str, scale: float = 1.0, form: str = ".3f") -> str:
    """`key` under each map, and the last two maps' ratios to the first's."""
    values = [r[key] * scale for r in runs.values()]
    ratios = "/".join(f"{v / values[0] if values[0] else 1.0:.2f}" for v in values[1:])
    return " -> ".join(f"{v:{form}}" for v in values) + f" ({ratios})"


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="bench.occupancy_map", description=__doc__.split("\n\n")[0])
    add_scenes_option(p)
    p.add_argument("--only", default="balls,rings,teapot,tetra,mount")
    p.add_argument("--meshes", default="2x2,3x3,4x4")
    p.add_argument("--max-share", default="0.5,0.25,0.15", help="one, or one per mesh")
    p.add_argument("--size", type=int, default=256)
    p.add_argument("--spp", type=int, default=8)
    p.add_argument("--json", type=Path)
    args = p.parse_args(argv)
    from bench import read_scene
    from host.planning.plan import plan_render
    from host.planning.request import Auto, Request
    from protocols.render import EngineSpec, ImageSpec, MeshPlan

    meshes = args.meshes.split(",")
    shares = per_mesh(args.max_share, meshes)
    image = ImageSpec(width=args.size, height=args.size, spp=args.spp)
    eye = args.size * args.size * args.spp
    print(
        f"{args.size}x{args.size} at {args.spp} spp; the same cells under each map: bounds -> "
        "surfaces -> sub-voxels (ratios to the bounds map's)"
    )
    print(f"{'scene':>9} {'mesh':>4} occupied; passes a ray; summed units; busiest units")
    rows, bad = [], []
    for name in args.only.split(","):
        for mesh, share in zip(meshes, shares, strict=True):
            scene = read_scene(args.scenes, name)
            rr, cc = (int(v) for v in mesh.lower().split("x"))
            plan = MeshPlan(rr, cc, 1.0, "objects", "object", max_share=share)
            request = Request(scene, image, EngineSpec(), plan=plan, auto=Auto(budget_copies=True))
            planned = plan_render(request)
            part = planned.partition
            alone = dataclasses.replace(  # the maps of sessions 45 and 46 had no inner map
                part, inner_lo=(), inner_hi=(), inner_res=(), inner_bits=b"", inner_fine=b""
            )
            maps = {
                "bounds": dataclasses.replace(
                    alone, occ_bits=bounds_bits(scene, part), occ_fine=b""
                ),
                "surfaces": dataclasses.replace(alone, occ_fine=b""),
                "sub-voxels": part,
            }
            runs = {k: simulated(scene, planned, m) for k, m in maps.items()}
            first = runs["bounds"]["counts"]
            if any(r["counts"][k] != first[k] for r in runs.values() for k in SAME):
                bad.append(
                    f"{name} {mesh}: {[[r['counts'][k] for k in SAME] for r in runs.values()]}"
                )
            cells = (
                _row(runs, "occupied"),
                _row(runs, "passed", 1 / eye),
                _row(runs, "units", 1e-6, ".1f"),
                _row(runs, "busiest", 1e-6, ".2f"),
            )
            print(f"{name:>9} {mesh:>4} " + " ".join(cells))
            rows.append(
                {
                    "scene": name,
                    "mesh": mesh,
                    "max_share": share,
                    **{
                        f"{k.replace('-', '_')}_{f}": v
                        for k, r in runs.items()
                        for f, v in r.items()
                        if f != "counts"
                    },
                    "eye_rays": eye,
                }
            )
    return finish(
        rows,
        args.json,
        bad,
        "MISMATCH (ray counts) between the maps:\n",
        "the mesh counted the same hits, escapes and shadow rays under all three maps",
    )


if __name__ == "__main__":
    sys.exit(main())
