"""Primary rays through this project's engine and through Embree, side by side, one thread.

    python -m bench.embree [--scenes DIR] [--only tetra,teapot,gears] [--size 512]
                           [--levels 9] [--repeat 3]

Embree comes from the `embreex` package and polygon triangulation from `mapbox-earcut`
(`pip install -e ".[bench]"`; benchmark dependencies, not runtime ones). For each scene its
triangles and polygons (spheres and cones left out of both) are traced with the same eye
rays (the scene's view, SIZE x SIZE pixel centres) by `Engine.first_hits` (float64, one
thread) and by Embree (float32 `rtcIntersect1` per ray in embreex's loop, one thread). Ours
traces the surfaces as `host render` does, polygons native ("native" rows); Embree takes
triangles only, so polygons are cut into triangles by ear clipping (exact for concave ones:
gears' outlines), and ours is also timed on those same triangles ("triangles" rows). Plus a
generated recursive tetrahedron of 4 x 4^LEVELS triangles (9: 1,048,576).

Timed as `bench.timing` says: the process pinned to one core, CPU seconds of the process
(never the wall), ours and Embree taking turns `--repeat` rounds per row (ours, Embree, ours,
Embree ...). Printed per scene and structure: triangles, build CPU seconds both ways (one
build each), million rays per second both ways (median over the rounds, least-most in
brackets), ours / Embree (the median of the rounds' paired ratios, each round's two sides
sharing a spell of the machine, with their spread), and the first-hit agreement: hit/miss
disagreements and percentiles of the relative difference of t where both hit.

Each row is followed by its shadow rays ("shadow" in the triangles column): from every
primary hit point where both sides hit, one ray towards each scene light that lies on the
side of the surface the eye sees (Embree's geometric normal; the renderer casts no shadow
ray towards a light behind the surface, which blocks it), ending at the light. Neither side
skips the surface a ray leaves (Embree has no such rule): both get the same rays, their
origins moved off the surface towards the light by 1e-4 of the scene's scale (far above
float32 round-off of the points and triangles Embree is given) and t_max shortened by as
much. The generated tetrahedron has no lights: it gets one fixed light above it, (0, 0, 5)
(its triangles lie in [-1, 1]^3). Ours answers with `Engine.occluded` (stops at the first
object found, one thread), Embree with `rtcOccluded1` per ray (embreex's OCCLUDED query),
timed in turns as the primary rays; printed: both rates, ours / Embree, the occluded
disagreements (in the hit/miss column), how many shadow rays and the share blocked.
"""

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

if __package__ in (None, ""):
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench import add_scenes_option  # noqa: E402 (after the path is set)
from bench.timing import interleaved, pin_one_core, pinned_text  # noqa: E402


def triangles_of(scene) -> np.ndarray:
    """(N, 3, 3) triangles: the scene's triangles and its polygons cut by ear clipping in
    their plane (mapbox-earcut), which keeps concave outlines exact."""
    import mapbox_earcut

    tris = [scene.triangles["v"].reshape(-1, 3, 3)]
    verts = scene.vertices
    for start, count in zip(scene.polygons["start"], scene.polygons["count"], strict=True):
        p = verts[start : start + count]
        normal = np.cross(p - p.mean(axis=0), np.roll(p, -1, axis=0) - p.mean(axis=0)).sum(0)
        keep = [a for a in range(3) if a != int(np.argmax(np.abs(normal)))]
        ring = np.array([count], np.uint32)
        index = mapbox_earcut.triangulate_float64(np.ascontiguousarray(p[:, keep]), ring)
        tris.append(p[index.reshape(-1, 3)])
    return np.concatenate(tris) if tris else np.zeros((0, 3, 3))


def surfaces_of(scene):
    """The scene's triangles and polygons alone (no spheres or cones, which Embree is not
    given): what ours traces in the "native" rows. First hits read no materials."""
    from dataclasses import replace

    from protocols import dtypes

    return replace(scene, spheres=np.zeros(0, dtypes.SPHERE), cones=np.zeros(0, dtypes.CONE))


def flat_scene(view, tris: np.ndarray):
    """A scene of flat triangles only (one grey material, one light)."""
    from protocols import dtypes
    from protocols.scene import SceneData

    scene = SceneData(view=view)
    scene.materials = np.array([((0.8, 0.8, 0.8), 0.8, 0.0, 1.0, 0.0, 1.0)], dtypes.MATERIAL)
    scene.lights = np.array([((1e3, 1e3, 1e3), (1, 1, 1))], dtypes.LIGHT)
    t = np.zeros(len(tris), dtypes.TRIANGLE)
    t["gid"] = np.arange(len(tris))
    t["v"] = tris
    scene.triangles = t
    return scene


def ours(scene, structure: str) -> dict:
    """Our engine with `structure`, its build CPU seconds, and the structure it chose."""
    from meshnode.engine import Engine

    start = time.process_time()
    engine = Engine(scene, structure=structure)
    build = time.process_time() - start
    return {"engine": engine, "build_s": build, "chosen": engine.structure}


def compare(
    name: str,
    view,
    tris: np.ndarray,
    size: int,
    repeat: int,
    structures: list[str],
    lights: np.ndarray,
    native=None,
) -> list[dict]:
    """One row per structure (and per surface form: `native`, the scene's own polygons, if
    given, then Embree's triangles) of ours against Embree on identical rays, the two taking
    turns `repeat` rounds: primary rays, then shadow rays from their hits towards `lights`
    ((L, 3) positions)."""
    from embreex import rtcore_scene
    from embreex.mesh_construction import TriangleMesh

    from meshnode.engine.camera import eye_rays
    from protocols.render import ImageSpec

    rays = eye_rays(view, ImageSpec(width=size, height=size))
    # Both sides get contiguous arrays made before timing (Embree its float32 copies).
    o = np.ascontiguousarray(rays["o"])
    d = np.ascontiguousarray(rays["d"] / np.linalg.norm(rays["d"], axis=1)[:, None])
    o32, d32 = o.astype(np.float32), d.astype(np.float32)
    start = time.process_time()
    embree = rtcore_scene.EmbreeScene()
    TriangleMesh(embree, tris.astype(np.float32))
    embree.run(o32[:1], d32[:1], output=1)  # commits (builds) the scene
    embree_build = time.process_time() - start

    def per_second(seconds: float) -> float:
        return len(o) / seconds

    rows = []
    forms = ([("native", native)] if native is not None else []) + [
        ("triangles", flat_scene(view, tris))
    ]
    for (form, scene), structure in ((f, s) for f in forms for s in structures):
        run = ours(scene, structure)
        engine = run["engine"]
        engine.first_hits(o[:1], d[:1])  # kernels loaded before timing
        times, last = interleaved(
            {
                "ours": lambda engine=engine: engine.first_hits(o, d),
                "embree": lambda: embree.run(o32, d32, output=1),
            },
            repeat,
        )
        shadow = shadow_rays(o, d, last["ours"][0], last["embree"], lights, tris)
        so, sd, st = shadow["ours"]
        so32, sd32, st32 = shadow["embree"]
        n_shadow = len(so)
        engine.occluded(so[:1], sd[:1], st[:1])  # kernel loaded (or compiled) before timing
        shadow_times, shadow_last = interleaved(
            {
                "ours": lambda engine=engine, so=so, sd=sd, st=st: engine.occluded(so, sd, st),
                "embree": lambda so32=so32, sd32=sd32, st32=st32: embree.run(
                    so32, sd32, dists=st32, query="OCCLUDED"
                ),
            },
            repeat,
        )
        del engine, run["engine"]  # one engine alive at a time: the biggest scenes are large

        def shadow_per_second(seconds: float, n_shadow=n_shadow) -> float:
            return n_shadow / seconds

        blocked_ours = shadow_last["ours"]
        blocked_embree = np.asarray(shadow_last["embree"]) != -1  # geomID stays -1 if clear
        row = {
            "scene": name,
            "form": form,
            "structure": structure,
            "chosen": run["chosen"],
            "triangles": len(tris),
            "rays": len(o),
            "clock": "process CPU seconds, in turns",
            "ours_build_s": run["build_s"],
            "embree_build_s": embree_build,
            **times.figure("ours").fields("ours_seconds"),
            **times.figure("embree").fields("embree_seconds"),
            **times.figure("ours").map(per_second).fields("ours_rays_per_s"),
            **times.figure("embree").map(per_second).fields("embree_rays_per_s"),
            # ours rays/s over Embree's: Embree's seconds over ours, paired by round
            **times.ratio("embree", "ours").fields("ratio"),
            **agreement(last["ours"][0], last["embree"]),
            "shadow_rays": n_shadow,
            "shadow_offset": shadow["offset"],
            **shadow_times.figure("ours").fields("shadow_ours_seconds"),
            **shadow_times.figure("embree").fields("shadow_embree_seconds"),
            **shadow_times.figure("ours").map(shadow_per_second).fields("shadow_ours_rays_per_s"),
            **shadow_times.figure("embree")
            .map(shadow_per_second)
            .fields("shadow_embree_rays_per_s"),
            **shadow_times.ratio("embree", "ours").fields("shadow_ratio"),
            "shadow_mismatches": int((blocked_ours != blocked_embree).sum()),
            "shadow_blocked": int(blocked_ours.sum()),
        }
        print_row(row, run["chosen"])
        print_shadow_row(row, run["chosen"])
        rows.append(row)
    return rows


def shadow_rays(o, d, t_ours, hits, lights, tris) -> dict:
    """The shadow rays from the primary hits where both sides hit (ours' hit points),
    light by light: to each light on the side of the surface the eye sees, from the point
    moved off the surface towards the light, ending at the light. {"ours": (origins,
    directions, t_max) float64, "embree": the same as float32, "offset": the move}."""
    both = np.isfinite(t_ours) & (hits["geomID"] >= 0)
    p = o[both] + t_ours[both, None] * d[both]
    ng = hits["Ng"][both].astype(float)
    eye_side = np.sign(np.einsum("ij,ij->i", ng, -d[both]))
    scale = max(float(np.ptp(tris.reshape(-1, 3), axis=0).max()), float(np.abs(tris).max()))
    offset = 1e-4 * scale
    origins, directions, ends = [], [], []
    for light in np.asarray(lights, float).reshape(-1, 3):
        to = light - p
        dist = np.linalg.norm(to, axis=1)
        to /= dist[:, None]
        seen = np.sign(np.einsum("ij,ij->i", ng, to)) == eye_side
        seen &= dist > 2 * offset
        origins.append(p[seen] + offset * to[seen])
        directions.append(to[seen])
        ends.append(dist[seen] - offset)
    so, sd, st = (np.ascontiguousarray(np.concatenate(a)) for a in (origins, directions, ends))
    f32 = tuple(np.ascontiguousarray(a, dtype=np.float32) for a in (so, sd, st))
    return {"ours": (so, sd, st), "embree": (f32[0], f32[1], f32[2]), "offset": offset}


def agreement(t_ours: np.ndarray, hits) -> dict:
    """Hit/miss disagreements with Embree's hits, and the 50th, 99th and 100th percentiles of
    the relative difference of t where both hit."""
    t_emb = np.where(hits["geomID"] >= 0, hits["tfar"].astype(float), np.inf)
    ours_hit, emb_hit = np.isfinite(t_ours), np.isfinite(t_emb)
    both = ours_hit & emb_hit
    rel = np.abs(t_ours[both] - t_emb[both]) / np.maximum(t_ours[both], 1e-30)
    pct = np.percentile(rel, [50, 99, 100]) if both.any() else np.zeros(3)
    return {"mismatches": int((ours_hit != emb_hit).sum()), "rel_t_p50_p99_max": pct.tolist()}


HEADER = (
    f"{'scene':>16} {'ours on':>9} {'structure':>9} {'triangles':>10} {'build s':>8} "
    f"{'embree':>7} {'ours M rays/s':>19} {'embree M rays/s':>19} {'ours/embree':>17} "
    f"{'hit/miss':>8} {'t rel p50':>9} {'p99':>9} {'max':>9}"
)


def print_row(row: dict, chosen: str) -> None:
    """One row of the table: medians with their spread (least-most) in brackets."""

    def spread(key: str, scale: float = 1.0) -> str:
        lo, mid, hi = (row[f"{key}_low"], row[key], row[f"{key}_high"])
        return f"{mid / scale:.2f} ({lo / scale:.2f}-{hi / scale:.2f})"

    label = f"auto={chosen}" if row["structure"] == "auto" else row["structure"]
    pct = row["rel_t_p50_p99_max"]
    print(
        f"{row['scene']:>16} {row['form']:>9} {label:>9} {row['triangles']:>10,} "
        f"{row['ours_build_s']:>8.2f} {row['embree_build_s']:>7.2f} "
        f"{spread('ours_rays_per_s', 1e6):>19} {spread('embree_rays_per_s', 1e6):>19} "
        f"{spread('ratio'):>17} {row['mismatches']:>8} "
        f"{pct[0]:>9.1e} {pct[1]:>9.1e} {pct[2]:>9.1e}",
        flush=True,
    )


def print_shadow_row(row: dict, chosen: str) -> None:
    """The row's shadow rays: rates, ours / Embree, occluded disagreements, rays, blocked."""

    def spread(key: str, scale: float = 1.0) -> str:
        lo, mid, hi = (row[f"{key}_low"], row[key], row[f"{key}_high"])
        return f"{mid / scale:.2f} ({lo / scale:.2f}-{hi / scale:.2f})"

    label = f"auto={chosen}" if row["structure"] == "auto" else row["structure"]
    n = row["shadow_rays"]
    blocked = row["shadow_blocked"] / n if n else 0.0
    print(
        f"{row['scene']:>16} {row['form']:>9} {label:>9} {'shadow':>10} {'':>8} {'':>7} "
        f"{spread('shadow_ours_rays_per_s', 1e6):>19} "
        f"{spread('shadow_embree_rays_per_s', 1e6):>19} {spread('shadow_ratio'):>17} "
        f"{row['shadow_mismatches']:>8} {n:>9,} rays, {blocked:.0%} blocked",
        flush=True,
    )


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="bench.embree", description=__doc__.split("\n\n")[0])
    add_scenes_option(p)
    p.add_argument("--only", default="tetra,teapot,gears")
    p.add_argument("--size", type=int, default=512)
    p.add_argument("--levels", type=int, default=9, help="generated tetrahedron's recursion")
    p.add_argument("--repeat", type=int, default=3, help="rounds of turns per row (3)")
    p.add_argument(
        "--structures",
        default="grid,bvh,auto",
        help="our engine's structures to time, side by side (default grid,bvh,auto)",
    )
    p.add_argument("--json", type=Path, help="write the rows to this JSON file")
    args = p.parse_args(argv)
    core = pin_one_core()  # before Embree's and numba's threads start: they inherit it
    try:
        import embreex  # noqa: F401
    except ImportError:
        print("bench.embree: needs embreex (pip install embreex)", file=sys.stderr)
        return 2
    import numba

    from bench import read_scene
    from bench.generate import tetra_triangles
    from protocols.scene import View

    numba.set_num_threads(1)
    print(
        f"one thread, {pinned_text(core)}; process CPU seconds, ours and Embree in turns, "
        f"{args.repeat} rounds a row: medians (least-most); ours/embree is the median of the "
        f"rounds' paired ratios; build: one each"
    )
    print(HEADER)
    structures = args.structures.split(",")
    rows = []
    for name in args.only.split(",") if args.only else []:
        scene = read_scene(args.scenes, name)
        rows += compare(
            name,
            scene.view,
            triangles_of(scene),
            args.size,
            args.repeat,
            structures,
            scene.lights["pos"],
            native=surfaces_of(scene),
        )
    if args.levels > 0:
        view = View((2.1, 1.3, 1.7), (0, 0, 0), (0, 0, 1), 45.0)
        tris = tetra_triangles(args.levels + 1)  # SPD size factor levels + 1: 4 x 4^levels
        above = np.array([[0.0, 0.0, 5.0]])  # a fixed light: the generated mesh has none
        rows += compare(
            f"tetra L{args.levels}", view, tris, args.size, args.repeat, structures, above
        )
    if args.json:
        args.json.write_text(json.dumps(rows, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
