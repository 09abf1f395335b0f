"""One process's frame with the eye rays that meet nothing made and traced, against not made
(`meshnode.engine.sky`: their cells take the background), in turns on one thread.

    python -m bench.sky [--scenes DIR] [--only tetra,jacks,balls] [--size 256] [--spp 100]
                        [--turns 3] [--json FILE]

Printed per scene: the share of eye rays that meet nothing, the frame's CPU seconds (the
whole process: making rays, tracing, adding deposits) each way in every turn, the median
of each, and their ratio; the sky's own CPU (the map and its view, made once a render
before the frame) beside them. Every turn's image and ray counts must be the same to the bit
both ways (exit 1 where not).
"""

import argparse
import statistics
import sys
from pathlib import Path

if __package__ in (None, ""):
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench import add_scenes_option, finish, read_scene  # noqa: E402 (after the path is set)

KEPT = ("eye_rays", "eye_hits", "escaped", "shadow_rays", "reflected_rays", "refracted_rays")


def frame(scene, image, looked: bool):
    """(image, stats) of one single-thread render, the sky looked for or not."""
    from host.planning.request import Request
    from host.run.oneprocess import render
    from meshnode.engine import sky
    from protocols.render import EngineSpec

    sky.SKY_MIN_RAYS = 0 if looked else 1 << 62
    return render(Request(scene, image, EngineSpec(threads=1)))


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    add_scenes_option(p)
    p.add_argument("--only", default="tetra,jacks,shells,teapot,balls")
    p.add_argument("--size", type=int, default=256)
    p.add_argument("--spp", type=int, default=100)
    p.add_argument("--turns", type=int, default=3)
    p.add_argument("--json", type=Path)
    a = p.parse_args(argv)
    from protocols.render import ImageSpec

    rows, bad = [], []
    image = ImageSpec(width=a.size, height=a.size, spp=a.spp)
    print(f"{a.size}x{a.size} at {a.spp} spp, one thread; frame CPU seconds, traced / sky")
    for name in a.only.split(","):
        scene = read_scene(a.scenes, name)
        frame(scene, image, True)  # compiled and loaded before any turn is timed
        times: dict[bool, list] = {False: [], True: []}
        for _ in range(a.turns):
            ref, ref_stats = frame(scene, image, False)
            img, stats = frame(scene, image, True)
            times[False].append(ref_stats["frame_cpu_seconds"])
            times[True].append(stats["frame_cpu_seconds"])
            same = {k: stats["rays"][k] for k in KEPT} == {k: ref_stats["rays"][k] for k in KEPT}
            if not (same and (img == ref).all()):
                bad.append(f"{name}: the image or the ray counts differ with the sky")
        traced, skipped = (statistics.median(times[k]) for k in (False, True))
        row = {
            "scene": name,
            "sky": stats["sky"]["eye_rays"],
            "sky_cpu_seconds": stats["sky"]["cpu_seconds"],
            "traced_frame_cpu_seconds": times[False],
            "sky_frame_cpu_seconds": times[True],
            "ratio": skipped / traced,
        }
        rows.append(row)
        print(
            f"{name:8s} traced {' '.join(f'{t:.3f}' for t in times[False])}  "
            f"sky {' '.join(f'{t:.3f}' for t in times[True])}  "
            f"median ratio {row['ratio']:.3f}  (sky's own {row['sky_cpu_seconds']:.3f} s: "
            f"{row['sky']})"
        )
    return finish(rows, a.json, bad, "EXACTNESS FAILED:\n", "images and counts equal both ways")


if __name__ == "__main__":
    sys.exit(main())
