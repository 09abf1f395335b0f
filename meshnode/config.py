"""A node's configuration for one render: the CONFIG message read and checked, and the
objects the host downloads after it.

Everything the host sends is checked before the node acts on it: the render's records check
their own fields, and the message's node index, neighbour addresses and view must fit the
plan; the objects may not exceed MAX_OBJECT_BYTES. SpecError or BadFrame names what is
wrong; the service sends that back to the host.
"""

import numpy as np

from protocols.errors import BadFrame
from protocols.messages import OBJECT_TABLES
from protocols.render import Partition, RenderSpec
from protocols.scene import SceneData, View
from protocols.spec import SpecError
from protocols.topology import Torus

MAX_OBJECT_BYTES = 4 << 30  # object records one render may download to a node


class Config:
    """A CONFIG message read and checked: SpecError or BadFrame name what is wrong."""

    def __init__(self, f: dict):
        self.render = RenderSpec.from_wire(f["render"])
        self.partition = Partition.from_wire(f["partition"])
        plan = self.render.plan
        self.torus = Torus(plan.rows, plan.cols)
        if self.partition.nodes != plan.nodes:
            raise SpecError(f"Partition has {self.partition.nodes} nodes, the plan {plan.nodes}")
        if not 0 <= f["node"] < plan.nodes:
            raise BadFrame(f"CONFIG.node = {f['node']}: must be from 0 to {plan.nodes - 1}")
        self.node = f["node"]
        self.neighbours = f["neighbours"]
        for m in self.torus.links(self.node):
            if not isinstance(self.neighbours.get(str(m)), str):
                raise BadFrame(f"CONFIG.neighbours has no address for node {m}")
        try:
            view = View(**{k: tuple(v) if isinstance(v, list) else v for k, v in f["view"].items()})
        except (TypeError, ValueError) as e:
            raise BadFrame(f"CONFIG.view: {e}") from None
        self.view, self.background = view, tuple(f["background"])


class Objects:
    """The node's objects as they arrive, table by table, bounded in bytes."""

    def __init__(self):
        self.tables: dict[str, list] = {}
        self.bytes = 0

    def add(self, table: str, records: np.ndarray) -> None:
        self.bytes += records.nbytes
        if self.bytes > MAX_OBJECT_BYTES:
            raise BadFrame(f"OBJECTS: more than {MAX_OBJECT_BYTES >> 20} MiB of objects")
        self.tables.setdefault(table, []).append(np.array(records))

    def scene(self, view: View, background) -> SceneData:
        def table(name):
            parts = self.tables.get(name)
            return np.concatenate(parts) if parts else np.zeros(0, OBJECT_TABLES[name])

        return SceneData(
            view=view, background=background, lights=table("lights"),
            materials=table("materials"), spheres=table("spheres"),
            triangles=table("triangles"), polygons=table("polygons"),
            vertices=table("vertices").reshape(-1, 3), cones=table("cones"),
        )  # fmt: skip
