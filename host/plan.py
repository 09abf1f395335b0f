"""A render planned for a mesh: the spec every node receives, the image cuts (even, or from
the simulated cost pre-pass), every node's rectangle and box, and which objects it holds.

Everything here happens in the host before any node is configured, so a plan that cannot
work (a bad camera, too many nodes for the image) fails before any connection is made.
"""

import time
from dataclasses import dataclass

import numpy as np

from host.balance import balanced_cuts
from host.camerasetup import CameraSetup
from host.partition import partition
from protocols.render import EngineSpec, ImageSpec, MeshPlan, Partition, RenderSpec
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
    xs = ys = None
    balance: dict = {"cuts": plan.balance}
    if plan.balance == "cost" and plan.nodes > 1:
        t0 = time.perf_counter()
        xs, ys, report = balanced_cuts(scene, spec)
        balance.update(report, seconds=time.perf_counter() - t0)
    part, keep = partition(scene, spec, xs, ys)
    return Planned(spec, part, keep, info, balance, time.perf_counter() - start)


def _probe_engine(scene: SceneData, image: ImageSpec, engine: EngineSpec):
    from host.autofocus import probe_engine

    width, height = image.size
    return probe_engine(scene, width, height, density=engine.density, storage=engine.storage,
                        max_depth=1)  # fmt: skip
