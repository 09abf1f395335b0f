"""The mesh simulated in this process for tests: `meshnode.mesh.simulator` (every node's NodeCore
driven by its own Scheduler, messages queued instead of sent, a seeded random order and
optional delays on one link), with the host's partition and framebuffer around it.

It checks the distributed algorithm itself (partition, clipping, ray passing, routing, colour
deposits, counts, termination) against the single-node image; the asyncio service runs the
same NodeCore and the same Scheduler.
"""

from host.planning.partition import partition
from host.run.framebuffer import Framebuffer
from host.scene.subset import subset
from meshnode.mesh.scheduler import PASSED_MIN
from meshnode.mesh.simulator import simulate
from protocols.render import ImageSpec, MeshPlan, RenderSpec


def render_mesh(
    scene,
    rows,
    cols,
    overlap,
    width,
    height,
    corners=False,
    spp=1,
    depth=5,
    seed=0,
    delay=None,
    camera=None,
    batch=512,
    cuts=None,
    cells=None,
    passed_min=PASSED_MIN,
    clock="rounds",
    latency=10,
    outcome=None,
    loads=None,
    **plan,
):
    """Image, summed counters, per-node records and rounds of a rows x cols mesh render.

    `delay` = (src, dst, rounds): messages on that link arrive that many rounds late; `cuts`:
    (xs, ys) as `host.planning.rectangles.rectangles` takes them (default even); `cells`: (los,
    his) of the nodes' cells (default: cut to match the rectangles); `passed_min`: the nodes'
    Scheduler's; `clock`: the simulator's ("rounds" or "work", a message's `latency` in work
    units); `outcome`: a list the simulator's Outcome is appended to; `loads`: the nodes'
    estimated CPU seconds the partition deals the sky's tiles against; `plan`: more MeshPlan
    fields (mode, tiles, tile)."""
    image = ImageSpec(width=width, height=height, spd=corners, spp=spp, depth=depth, seed=seed)
    spec = RenderSpec(
        image.sized(scene.view), plan=MeshPlan(rows, cols, overlap, **plan), camera=camera
    )
    part, keep = partition(scene, spec, *(cuts or (None, None)), cells, loads=loads)
    scenes = [subset(scene, keep[n]) for n in range(part.nodes)]
    out = simulate(scenes, spec, part, seed, delay, batch, passed_min, clock=clock, latency=latency)
    if outcome is not None:
        outcome.append(out)
    w, h = spec.image.size
    fb = Framebuffer(w, h, spec.corners, spec.ids_per_cell)
    for d in out.deposits:
        fb.add(d["pixel"], d["rgb"])
    return fb.image(), out.totals(), out.nodes, out.rounds
