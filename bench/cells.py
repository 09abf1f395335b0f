"""The object-space plan under a memory budget, simulated: how evenly `--balance objects` cells
and the budget's copies share the work, with the first guess of where the work lies taken
from the eye rays (`host.planning.seenwork`) or from the objects alone, side by side.

    python -m bench.cells [--scenes DIR] [--only teapot,balls,rings,gears,tetra]
                          [--meshes 3x3] [--max-share 0.25] [--size 256] [--spp 64]
                          [--simulate-spp 4] [--guess seen,objects] [--json FILE]

For each scene, mesh and guess the host plans the render (`plan_render`: cells, copies,
growth), then the simulated mesh traces it at `--simulate-spp` (the work units of
`meshnode.mesh.stats.work_units`, which no machine noise moves; the same ray counts as one
node's). Printed: the pre-pass's simulated busiest node by round, the rounds it afforded,
the plan's busiest node at the simulated spp in M units and over the mean, rays passed per
ray, and the host's CPU for the cells' pre-pass and for the copies'. `--spp` is the render
planned (the rounds the pre-pass affords follow its size); the simulation runs the same plan
at fewer samples.
"""

import argparse
import sys
import time
from dataclasses import replace
from pathlib import Path

if __package__ in (None, ""):
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import numpy as np  # noqa: E402

from bench import add_scenes_option, finish  # noqa: E402

GUESSES = {"seen": None, "objects": 0.0}  # seenwork.SEEN as each guess sets it (None: as is)


def parse_args(argv=None) -> argparse.Namespace:
    p = argparse.ArgumentParser(prog="bench.cells", description=__doc__.split("\n\n")[0])
    add_scenes_option(p)
    p.add_argument("--only", default="teapot,balls,rings,gears,tetra")
    p.add_argument("--meshes", default="3x3")
    p.add_argument("--max-share", type=float, default=0.25)
    p.add_argument("--size", type=int, default=256)
    p.add_argument("--spp", type=int, default=64, help="samples a pixel of the render planned")
    p.add_argument("--simulate-spp", type=int, default=4, help="... and of its simulation")
    p.add_argument("--guess", default="seen,objects", help="first guesses to compare")
    p.add_argument("--json", type=Path)
    return p.parse_args(argv)


def row(scene, name: str, mesh: str, guess: str, args) -> dict:
    """Plan `scene` on `mesh` under the budget with `guess`, simulate it; the figures."""
    from host.planning import seenwork
    from host.planning.plan import plan_render
    from host.planning.request import Auto, Request
    from host.scene.subset import subset
    from meshnode.mesh.simulator import simulate
    from protocols.render import EngineSpec, ImageSpec, MeshPlan

    rows, cols = (int(v) for v in mesh.split("x"))
    plan = MeshPlan(rows, cols, balance="objects", max_share=args.max_share)
    image = ImageSpec(width=args.size, height=args.size, spp=args.spp)
    request = Request(scene, image, EngineSpec(threads=1), plan=plan, auto=Auto(budget_copies=True))
    kept = seenwork.SEEN
    if GUESSES[guess] is not None:
        seenwork.SEEN = GUESSES[guess]
    try:
        began = time.process_time()
        planned = plan_render(request)
        plan_cpu = time.process_time() - began
    finally:
        seenwork.SEEN = kept
    spec, part = planned.spec, planned.partition
    scenes = [subset(scene, planned.holders[n]) for n in range(part.nodes)]
    out = simulate(scenes, replace(spec, image=replace(spec.image, spp=args.simulate_spp)), part)
    cost = np.array([r.cost for r in out.nodes], float)
    traced = sum(r.counts.get("ray_segments", 0) for r in out.nodes)
    balance = planned.balance
    budget = balance.get("budget", {})  # none without --max-share under 1
    held = [planned.holders[spec.plan.held(n)].any(axis=0).mean() for n in range(part.nodes)]
    return {
        "scene": name,
        "mesh": mesh,
        "guess": guess,
        "by_round": [round(b) for b in balance.get("simulated_busiest_by_round", [])],
        "rounds": balance.get("rounds"),
        "busiest_units": float(cost.max()),
        "busiest_over_mean": float(cost.max() / cost.mean()),
        "passes_per_segment": sum(r.rays_sent for r in out.nodes) / max(traced, 1),
        "cells_prepass_cpu": balance.get("prepass_cpu_seconds", 0.0),
        "copies_prepass_cpu": budget.get("copies", {}).get("prepass_cpu_seconds", 0.0),
        "plan_cpu": plan_cpu,
        "fullest_share": float(max(held)),
    }


def main(argv=None) -> int:
    from bench import read_scene

    args = parse_args(argv)
    guesses = args.guess.split(",")
    unknown = set(guesses) - set(GUESSES)
    if unknown:
        raise SystemExit(f"bench.cells: unknown --guess {sorted(unknown)}: from {sorted(GUESSES)}")
    out = []
    print(
        f"{'scene':8s} {'mesh':4s} {'guess':8s} {'rounds':>6s} {'busiest M':>9s} {'/mean':>6s}"
        f" {'pass/seg':>8s} {'cells s':>7s} {'copies s':>8s} {'held':>5s}  by round (k units)"
    )
    for name in args.only.split(","):
        scene = read_scene(args.scenes, name)
        for mesh in args.meshes.split(","):
            for guess in guesses:
                r = row(scene, name, mesh, guess, args)
                out.append(r)
                print(
                    f"{name:8s} {mesh:4s} {guess:8s} {r['rounds']:>6} "
                    f"{r['busiest_units'] / 1e6:9.2f} {r['busiest_over_mean']:6.2f} "
                    f"{r['passes_per_segment']:8.3f} {r['cells_prepass_cpu']:7.2f} "
                    f"{r['copies_prepass_cpu']:8.2f} {r['fullest_share']:5.0%}  "
                    f"{[round(b / 1e3) for b in r['by_round']]}",
                    flush=True,
                )
            first = [r for r in out if (r["scene"], r["mesh"]) == (name, mesh)]
            if len(first) > 1:
                base = first[-1]["busiest_units"]
                ratios = ", ".join(
                    f"{r['guess']} {r['busiest_units'] / base:.2f}" for r in first[:-1]
                )
                print(f"{'':8s} busiest node against {first[-1]['guess']}: {ratios}")
    return finish(out, args.json, [], "", "simulated: the same work units on any machine")


if __name__ == "__main__":
    sys.exit(main())
