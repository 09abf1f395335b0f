"""A render planned for a mesh: the spec every node receives, the image cuts (even, or from
the simulated cost pre-pass), every node's rectangle and box, and which objects it holds.

Everything here happens in the host before any node is configured, so a plan that cannot
work (a bad camera, too many nodes for the image) fails before any connection is made.
"""

import time
from dataclasses import dataclass, replace

import numpy as np

from host.balance import balanced_cuts
from host.camerasetup import CameraSetup
from host.partition import partition
from protocols.render import MODES, EngineSpec, ImageSpec, MeshPlan, Partition, RenderSpec
from protocols.scene import SceneData


@dataclass
class Planned:
    spec: RenderSpec
    partition: Partition
    holders: np.ndarray  # (nodes, objects) bool
    camera: dict | None  # what the statistics say of the camera
    balance: dict  # how the cuts were chosen
    seconds: float  # planning time (autofocus probe and cost pre-pass included)


def plan_render(scene: SceneData, image: ImageSpec, engine: EngineSpec, plan: MeshPlan,
                camera: CameraSetup | None = None) -> Planned:  # fmt: skip
    start = time.perf_counter()
    image = image.sized(scene.view)
    camera_spec = info = None
    if camera is not None:  # autofocus probes the scene here, before any node is configured
        camera_spec, info = camera.spec(scene, image, lambda: _probe_engine(scene, image,
                                                                           engine))  # fmt: skip
    spec = RenderSpec(image, engine, plan, camera_spec)
    xs = ys = cells = None
    occupancy = True
    balance: dict = {"cuts": plan.balance}
    if plan.balance == "cost" and plan.nodes > 1:
        t0 = time.perf_counter()
        xs, ys, report, cells, occupancy = balanced_cuts(scene, spec)
        balance.update(report, seconds=time.perf_counter() - t0)
    part, keep = partition(scene, spec, xs, ys, cells, occupancy)
    return Planned(spec, part, keep, info, balance, time.perf_counter() - start)


def _probe_engine(scene: SceneData, image: ImageSpec, engine: EngineSpec):
    from host.autofocus import probe_engine

    width, height = image.size
    return probe_engine(scene, width, height, density=engine.density, storage=engine.storage,
                        structure=engine.structure, max_depth=1)  # fmt: skip


PLAN_MODES = ("auto", *MODES)  # what a user may ask for; nodes only ever run MODES
ENGINE_BYTES_PER_RECORD_BYTE = 8  # tables and grid of a whole-scene engine (balls: 1.4 MB of
# grid and 0.6 MB of tables over 0.3 MB of records; gears, tetra and teapot alike or less)
FITS = 0.25  # image space when a whole-scene engine takes at most this share of a node


def engine_bytes(scene: SceneData) -> int:
    """A whole-scene engine's memory, estimated from the object records it is built from."""
    tables = (scene.spheres, scene.triangles, scene.polygons, scene.vertices, scene.cones,
              scene.materials, scene.lights)  # fmt: skip
    return ENGINE_BYTES_PER_RECORD_BYTE * sum(t.nbytes for t in tables)


def choose_mode(plan: MeshPlan, scene: SceneData, memories: list[int], asked: str = "auto",
                override: int | None = None) -> tuple[MeshPlan, str]:  # fmt: skip
    """The mode the nodes run, and why: what was asked, or (auto) image space when the
    whole scene's engine fits comfortably in the smallest node's memory (each node reports
    its memory at the handshake; `override` replaces the reports), object space when not or
    when the image cuts are cost-balanced (an object-space lever)."""
    if asked != "auto":
        return replace(plan, mode=asked), f"asked for with --mode {asked}"
    need = engine_bytes(scene)
    known = [m for m in memories if m > 0]
    memory = override if override is not None else min(known) if known else 0
    size = f"the whole scene's engine (about {_size(need)})"
    if plan.balance != "even":
        return replace(plan, mode="object"), f"--balance {plan.balance} cuts object space"
    if plan.steal:
        return replace(plan, mode="object"), "--steal is object space's lever"
    if memory == 0:
        return replace(plan, mode="object"), "the nodes did not report their memory"
    where = "--node-memory" if override is not None else "the smallest node's free memory"
    if need <= FITS * memory:
        return replace(plan, mode="image"), (f"{size} fits in {where} ({_size(memory)}) "
                                             "many times over: no rays cross the network")
    return replace(plan, mode="object"), (f"{size} would take over {FITS:.0%} of {where} "
                                          f"({_size(memory)}): each node holds its box")


def _size(n: int) -> str:
    for unit, scale in (("GiB", 1 << 30), ("MiB", 1 << 20), ("KiB", 1 << 10)):
        if n >= scale:
            return f"{n / scale:.1f} {unit}"
    return f"{n} bytes"
