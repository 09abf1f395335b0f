"""A node's configuration for one render: the CONFIG message read and checked, and the
objects the host downloads after it.

Everything the host sends is checked before the node acts on it: the render's records check
their own fields, and the message's node index, neighbour addresses and view must fit the
plan; the objects may not exceed MAX_OBJECT_BYTES. SpecError or BadFrame names what is
wrong; the service sends that back to the host.
"""

import numpy as np

from meshnode.mesh.stats import available_memory
from protocols.errors import BadFrame
from protocols.handshake import RENDER_ID_BYTES
from protocols.messages import OBJECT_TABLES
from protocols.partition import Partition
from protocols.render import RenderSpec
from protocols.scene import MAX_COORDINATE, OBJECT_KINDS, SceneData, SceneHeader
from protocols.spec import SpecError
from protocols.topology import Torus

MAX_OBJECT_BYTES = 4 << 30  # object records one render may download to a node, at most ...
OBJECT_SHARE = 0.5  # ... and at most this share of the node's free memory when it starts
KEEP_ENGINES = 2 << 30  # bytes of engines a node keeps between renders (`meshnode serve`)


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
        if len(f["render_id"]) != RENDER_ID_BYTES:
            raise BadFrame(f"CONFIG.render_id must be {RENDER_ID_BYTES} bytes")
        self.render_id = f["render_id"]
        self.neighbours = f["neighbours"]
        for m in self.torus.links(self.node):
            if not isinstance(self.neighbours.get(str(m)), str):
                raise BadFrame(f"CONFIG.neighbours has no address for node {m}")
        try:
            self.scene = SceneHeader.from_wire(f["scene"])
        except ValueError as e:
            raise BadFrame(f"CONFIG.{e}") from None

    @property
    def copies(self) -> list[int]:
        """The neighbours whose engines this node also holds (MeshPlan.copies)."""
        return self.render.plan.held(self.node)[1:]


class Objects:
    """The node's objects as they arrive, table by table, bounded in bytes; keyed by whose
    they are: this node's, or under MeshPlan.copies a linked neighbour's (`nodes`)."""

    def __init__(self, nodes=(), share: float = OBJECT_SHARE):
        self.nodes, self.share = frozenset(nodes), share
        free = available_memory()
        self.most = min(MAX_OBJECT_BYTES, int(share * free)) if free else MAX_OBJECT_BYTES
        self.tables: dict[tuple[int, str], list] = {}
        self.seen: set[int] = set()
        self.bytes = 0

    def add(self, node: int, table: str, records: np.ndarray) -> None:
        if node not in self.nodes:
            whose = ", ".join(map(str, sorted(self.nodes)))
            raise BadFrame(f"OBJECTS.node = {node}: this render downloads objects of {whose}")
        self.bytes += records.nbytes
        if self.bytes > self.most:
            raise BadFrame(
                f"OBJECTS: more than {self.most >> 20} MiB of objects ({self.share:.0%} of "
                f"this node's free memory, at most {MAX_OBJECT_BYTES >> 30} GiB)"
            )
        self.seen.add(node)
        self.tables.setdefault((node, table), []).append(np.array(records))

    def scene(self, node: int, header: SceneHeader) -> SceneData:
        """Node `node`'s objects as a scene, checked first: every number finite, every
        material and polygon vertex index in range (a bad index would read outside an array
        in a kernel, a NaN could keep a ray walking forever)."""
        if node not in self.seen:
            raise BadFrame(f"OBJECTS: none came for node {node}")
        tables = {
            name: np.concatenate(self.tables[node, name])
            if (node, name) in self.tables
            else np.zeros(0, OBJECT_TABLES[name])
            for name in OBJECT_TABLES
        }
        _check_objects(tables)
        return SceneData.from_tables(header, tables)


def _check_objects(tables: dict) -> None:
    """BadFrame naming the table unless the objects are safe to build an engine from."""
    for name, records in tables.items():
        fields = records.dtype.names or (None,)
        for f in fields:
            column = records if f is None else records[f]
            if column.dtype.kind != "f" or not column.size:
                continue
            if not np.all(np.isfinite(column)):
                raise BadFrame(f"OBJECTS {name}: {f or 'values'} must be finite")
            worst = float(np.abs(column).max())
            if worst > MAX_COORDINATE:  # the scene readers' bound, whoever sent the objects
                raise BadFrame(
                    f"OBJECTS {name}: {f or 'values'} = {worst:.3g} is beyond "
                    f"+-{MAX_COORDINATE:g}, as the scene readers refuse it"
                )
    if len(tables["vertices"]) % 3:
        raise BadFrame("OBJECTS vertices: a whole number of (x, y, z) points")
    n_mat, n_vert = len(tables["materials"]), len(tables["vertices"]) // 3
    for name in OBJECT_KINDS:
        mat = tables[name]["mat"]
        if len(mat) and (mat.min() < 0 or mat.max() >= n_mat):
            raise BadFrame(f"OBJECTS {name}: material index outside the {n_mat} materials")
    p = tables["polygons"]
    if len(p) and (
        p["start"].min() < 0
        or p["count"].min() < 3
        or (p["start"].astype(np.int64) + p["count"]).max() > n_vert
    ):
        raise BadFrame(f"OBJECTS polygons: vertex ranges outside the {n_vert} vertices")
