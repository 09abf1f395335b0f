"""One render asked for, the same record whether one process or a mesh renders it.

    Request  the scene and the records that describe its picture (image, engine, camera),
             the mesh plan, and the choices left to the host until it knows the nodes
    Auto     those choices: the mode, the memory to plan for, the overlaps to choose among

The one-process render reads the scene, image, engine and camera; a mesh render reads it all.
Where the nodes are and how to reach them is the run's, not the render's
(`host.run.connections.Nodes`).
"""

from dataclasses import dataclass, field, replace

from host.camera.setup import CameraSetup
from protocols.render import MODES, EngineSpec, ImageSpec, MeshPlan, RenderSpec
from protocols.scene import SceneData

PLAN_MODES = ("auto", *MODES)  # what a user may ask for; nodes only ever run MODES


@dataclass(frozen=True)
class Auto:
    """What `--mode auto`, `--node-memory` and `--overlap auto` leave to the host: `mode`
    ("auto", or a mode of `protocols.render.MODES`; None keeps the plan's), `node_memory`
    (bytes to plan each node for, instead of what the nodes report) and `overlaps` (object
    space: overlaps for the cost pre-pass to choose among; empty keeps the plan's) and
    `budget_copies` (under a memory budget, fill each node's room with copies of the
    hottest cells where the pre-pass finds they pay: `host.planning.replicas`) and
    `share_claims` (with those copies, each copied cell's own work shared over its holders:
    `host.planning.holder_shares`) and `steal_claims` (with those copies, holders take each
    other's unstarted claimed chunks at run time: `meshnode.mesh.claimfeed`)."""

    mode: str | None = None
    node_memory: int | None = None
    overlaps: tuple[float, ...] = ()
    budget_copies: bool = True
    share_claims: bool = True
    steal_claims: bool = True

    def __post_init__(self):
        if self.mode is not None and self.mode not in PLAN_MODES:
            raise ValueError(f"mode {self.mode!r}: want auto or one of {MODES}")
        if self.node_memory is not None and self.node_memory <= 0:
            raise ValueError(f"node memory {self.node_memory}: want a positive number of bytes")
        object.__setattr__(self, "overlaps", tuple(float(o) for o in self.overlaps))


@dataclass(frozen=True)
class Request:
    """A render: `scene`, what picture (`image`), how each engine is built (`engine`), the
    camera (None: the pinhole of the scene's view), how a mesh spreads the work (`plan`) and
    what the host chooses once it knows the nodes (`auto`)."""

    scene: SceneData
    image: ImageSpec = field(default_factory=ImageSpec)
    engine: EngineSpec = field(default_factory=EngineSpec)
    camera: CameraSetup | None = None
    plan: MeshPlan = field(default_factory=MeshPlan)
    auto: Auto = field(default_factory=Auto)

    @property
    def sized(self) -> ImageSpec:
        """The image with its size filled in from the scene's view (or the SPD rules)."""
        return self.image.sized(self.scene.view)

    def spec(self) -> RenderSpec:
        """The records every node is sent, before the camera is focused (checked now): a
        camera's rays start from pixels, so its image samples pixels under the SPD rules too."""
        image = self.sized
        if self.camera is not None:
            image = replace(image, spd=False)
        return RenderSpec(image, self.engine, self.plan)

    def on(self, plan: MeshPlan) -> "Request":
        """This render planned otherwise (a mode chosen, a mesh shrunk after a lost node)."""
        return replace(self, plan=plan)
