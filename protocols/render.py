"""The records that describe one render, each setting in exactly one place.

    ImageSpec   what picture: size, SPD rules, samples per pixel, ray depth, seed
    EngineSpec  how each engine is built: grid storage, density, threads
    MeshPlan    how the work is spread: rows x cols nodes, box overlap, image cuts
    RenderSpec  image + engine + plan (+ camera): what the host sends every node in CONFIG

What the host planned from them, each node's image rectangles and box, is the Partition
(`protocols.partition`), sent beside them.

The command line builds them (its defaults are these fields' defaults), the host sends them,
the node reads them; `sample_grid` is the one place the SPD corner-sampling rule lives.
"""

import math
from dataclasses import dataclass, replace
from typing import ClassVar

from protocols.camera import CameraSpec
from protocols.spec import Spec, SpecError
from protocols.topology import Torus

SPD_SIZE = 512  # the SPD rules: 512x512 pixels from 513x513 corner rays ...
SPD_DEPTH = 5  # ... traced to depth 5 (also the default depth of every render)
MAX_SIDE = 32768  # pixels along an image side
MAX_SPP = 65536
MAX_DEPTH = 64
MAX_NODES = 1024  # nodes in one mesh
EVERYWHERE = ((1, 1, 1), b"\x80")  # Partition's occupancy map of one occupied voxel: skips nothing
STORAGES = ("auto", "csr", "hash")
STRUCTURES = ("auto", "grid", "bvh")  # the engine's structure (auto: chosen per node by content)
BALANCES = ("even", "cost", "objects")
MODES = ("object", "image")
TILINGS = ("none", "static", "dynamic")
ORDERS = ("rows", "centre")  # dynamic tiles: dealt row by row, or from the image's centre out
FORWARDS = ("owner", "nearest")  # under holds: a cell's rays to its owner, or its nearest holder


@dataclass(frozen=True)
class ImageSpec(Spec):
    """The picture. width/height None: the scene's resolution (`sized` fills them in). spd:
    the SPD rules (512x512 from 513x513 corner rays, four averaged per pixel, depth 5; a size
    given with them keeps corner sampling at that size); spp: rays (samples) per pixel for
    every camera: the pinhole's jittered samples (stratified when a square), or the rays of a
    camera or of the pinhole set up as one (of which CameraSampling.per_pixel says how many
    are traced); depth: maximum ray tree depth (eye ray = 1); seed: of every random choice
    (jitter, lens and film samples)."""

    width: int | None = None
    height: int | None = None
    spd: bool = False
    spp: int = 1
    depth: int = SPD_DEPTH
    seed: int = 0

    def check(self) -> None:
        self.want_int("width", 1, MAX_SIDE, optional=True)
        self.want_int("height", 1, MAX_SIDE, optional=True)
        self.want_bool("spd")
        self.want_int("spp", 1, MAX_SPP)
        self.want_int("depth", 1, MAX_DEPTH)
        self.want_int("seed", 0, 2**63 - 1)
        if self.spd and self.depth != SPD_DEPTH:
            self.fail("depth", f"the SPD rules fix it at {SPD_DEPTH}")

    def check_corners(self, camera: bool = False) -> None:
        """The SPD rules' eye rays are one a pixel corner: spp is 1, unless a camera makes
        the rays (then spp is its rays per pixel)."""
        if self.corners(camera) and self.spp != 1:
            self.fail("spp", "the SPD rules fix it at 1 (but for the rays through a --camera)")

    def sized(self, view) -> "ImageSpec":
        """This image with its size filled in from the scene's view (or the SPD rules)."""
        if self.spd:  # a size given with the SPD rules: corner sampling at that size
            return replace(self, width=self.width or SPD_SIZE, height=self.height or SPD_SIZE)
        return replace(self, width=self.width or view.width, height=self.height or view.height)

    @property
    def size(self) -> tuple[int, int]:
        if self.width is None or self.height is None:
            raise SpecError("ImageSpec: size unknown until sized() by the scene's view")
        return self.width, self.height

    def corners(self, camera: bool = False) -> bool:
        """Eye rays at pixel corners (the SPD rule), unless a camera makes the rays."""
        return self.spd and not camera

    def sample_grid(self, camera: bool = False) -> tuple[int, int]:
        """Columns and rows of primary sample positions: pixel corners under the SPD rules
        (one more each way), else pixels. Image cuts and node rectangles are on this grid."""
        w, h = self.size
        return (w + 1, h + 1) if self.corners(camera) else (w, h)


@dataclass(frozen=True)
class EngineSpec(Spec):
    """How every engine is built: structure (grid or bvh; auto: chosen per node by its
    objects), grid storage (auto: the smaller in memory), density (voxels
    per object to start from, refined until a voxel holds about 4/density objects), tracing
    threads (0: one per core; on a mesh, at most this many per node), brute (test every
    object against every ray: the reference the grid must agree with)."""

    storage: str = "auto"
    structure: str = "auto"
    density: float = 1.0
    threads: int = 0
    brute: bool = False

    def check(self) -> None:
        self.want_choice("storage", STORAGES)
        self.want_choice("structure", STRUCTURES)
        self.want_number("density", 0.0, 1e6, open_lo=True)
        self.want_int("threads", 0, 4096)
        self.want_bool("brute")


@dataclass(frozen=True)
class MeshPlan(Spec):
    """How the work is spread over a rows x cols torus of nodes.

    mode "object" (DESIGN.md 5): each node holds the objects of its box of space, grown by
    `overlap` percent of its size, and traces the rays that pass through it; the image is cut
    evenly or where a simulated pre-pass says the nodes' work is even (balance "cost").
    mode "image" (DESIGN.md 6): every node holds the whole scene and traces whole pixel tiles,
    no rays passed; `tiles` "none" gives each node one band of rows, "static" deals near-square
    tiles of `tile` pixels round-robin, "dynamic" deals `buffer` tiles to each node at first
    and one more whenever a node reports one finished (a node never waits on the network),
    in `order`: "rows" row by row, or "centre" from the image's centre outward (the last
    dealt, which decide how evenly the nodes finish, are then the border's: cheapest where
    the border is background; measured on 4x4 it evened the work units, not the CPU).
    `steal` (object space): a node traces its rectangle in chunks spiralling out from the
    centre, and one that has run out takes unstarted chunks from the outer end of a busy
    neighbour's spiral and makes their eye rays itself; under adaptive sampling in both
    passes (pass 2's chunks are the refined pixels' row runs), the owner keeping the books;
    with copies and the eye's claims, the chunks are tiles of a node's claimed samples, taken
    only by a holder of every cell they start in (`meshnode.mesh.claimfeed`).
    `copies` (object space): each node also holds a copy of every linked neighbour's engine
    (the same objects in the same box, so the same segments) and traces there the rays that
    neighbour would take on, instead of passing them: stolen chunks then move their work,
    not only their eye rays, at the price of holding up to five boxes' objects. `shared`
    (with copies): cells whose engines every node holds besides (the cost pre-pass picks the
    cells most of the work is traced in, within the nodes' memory): any node then makes and
    traces the tiles whose eye rays those cells take on, so the work gathered in one cell
    spreads over the whole mesh, not only over that cell's four neighbours. `holds` (with
    copies; one tuple a node, empty: every node's links and the shared cells): the cells
    whose engines each node holds besides its own, as a memory budget's copies are chosen
    (`host.planning.replicas`: the hottest cells onto the nodes with room, within the budget).
    balance "objects" (object space): cells cut in three axes so each holds about 1/N of the
    objects, whatever the view (`host.planning.objectcells`). `max_share` and `node_bytes`
    are a memory budget (object space): no node holds more than `max_share` of the scene's
    objects, its copies counted, nor engines over `node_bytes` bytes (0: no bound); the
    host plans within them and every node checks its own engines against `node_bytes`.
    `forward` (with holds): a ray entering a cell whose engine its node does not hold goes
    to the cell's owner ("owner"), or to whichever of the cell's holders is fewest hops away
    ("nearest", the owner on a tie): a copy then takes on the rays of the nodes around it,
    not only its holder's own, as R2E2 hands rays to a node holding what they need (the
    budget's copies choose by the simulated mesh, `host.planning.replicas`).
    `claim_shares` (with holds; one tuple a cell, empty: none): the shares of a cell's eye
    rays each of its holders (`holders`, in that order) makes and traces, where a copy
    should take on a part of the cell's own work and not only the rays passed to it
    (`meshnode.mesh.claims`; the host weighs them, `host.planning.holder_shares`)."""

    rows: int = 1
    cols: int = 1
    overlap: float = 1.0
    balance: str = "even"
    mode: str = "object"
    tiles: str = "static"
    tile: int = 32
    buffer: int = 2
    order: str = "rows"
    steal: bool = False
    copies: bool = False
    shared: tuple = ()
    holds: tuple = ()
    max_share: float = 1.0
    node_bytes: int = 0
    forward: str = "owner"
    claim_shares: tuple = ()

    def check(self) -> None:
        self.want_int("rows", 1, MAX_NODES)
        self.want_int("cols", 1, MAX_NODES)
        if self.rows * self.cols > MAX_NODES:
            self.fail("cols", f"a mesh has at most {MAX_NODES} nodes ({self.rows} rows)")
        self.want_number("overlap", 0.0, 1000.0)
        self.want_choice("balance", BALANCES)
        self.want_choice("mode", MODES)
        self.want_choice("tiles", TILINGS)
        self.want_int("tile", 1, MAX_SIDE)
        self.want_int("buffer", 1, 1024)
        self.want_choice("order", ORDERS)
        if not isinstance(self.steal, bool):
            self.fail("steal", "must be true or false")
        if self.steal and self.mode != "object":
            self.fail("steal", "stealing is object space's lever (image space deals tiles)")
        self.want_bool("copies")
        if self.copies and self.mode != "object":
            self.fail("copies", "neighbours' copies are object space's (image space holds all)")
        self._check_shared()
        self._check_holds()
        self.want_choice("forward", FORWARDS)
        self._check_claim_shares()
        self.want_number("max_share", 0.0, 1.0, open_lo=True)
        self.want_int("node_bytes", 0, 1 << 60)
        if self.mode == "image" and (self.max_share < 1 or self.node_bytes):
            self.fail("max_share", "a memory budget is object space's (image space holds all)")
        if self.mode == "image" and self.balance != "even":
            self.fail("balance", "image-space tiles need no cost cuts (balance 'even')")

    @property
    def nodes(self) -> int:
        return self.rows * self.cols

    def _check_shared(self) -> None:
        shared = self.shared
        if not isinstance(shared, tuple) or not all(
            isinstance(c, int) and not isinstance(c, bool) for c in shared
        ):
            self.fail("shared", "must be a list of node numbers (a tuple in Python)")
        if shared and not self.copies:
            self.fail("shared", "shared cells are copies too: they need 'copies'")
        if any(not 0 <= c < self.nodes for c in shared) or len(set(shared)) < len(shared):
            self.fail("shared", f"must name distinct nodes from 0 to {self.nodes - 1}")

    def _check_holds(self) -> None:
        holds = self.holds
        if holds == ():
            return
        if not isinstance(holds, tuple) or len(holds) != self.nodes:
            self.fail("holds", f"must list {self.nodes} tuples, one a node")
        if not self.copies or self.shared:
            self.fail("holds", "a node's copies need 'copies' and replace 'shared'")
        for n, cells in enumerate(holds):
            if (
                not isinstance(cells, tuple)
                or not all(isinstance(c, int) and not isinstance(c, bool) for c in cells)
                or any(not 0 <= c < self.nodes or c == n for c in cells)
                or len(set(cells)) < len(cells)
            ):
                self.fail(
                    "holds",
                    f"node {n}'s must name distinct other nodes from 0 to {self.nodes - 1}",
                )

    def _check_claim_shares(self) -> None:
        """Every cell's shares, if any, one a holder: finite, at least 0, some above."""
        shares = self.claim_shares
        if shares == ():
            return
        if not isinstance(shares, tuple) or len(shares) != self.nodes or not self.holds:
            self.fail("claim_shares", f"must list {self.nodes} tuples, one a cell, with holds")
        holders = self.holders_table()
        for c, got in enumerate(shares):
            if got == ():
                continue
            if (
                not isinstance(got, tuple)
                or len(got) != len(holders[c])
                or not all(
                    isinstance(w, int | float) and not isinstance(w, bool) and 0 <= w < math.inf
                    for w in got
                )
                or not sum(got) > 0
            ):
                self.fail(
                    "claim_shares",
                    f"cell {c}'s must be {len(holders[c])} finite shares, one for each of its "
                    "holders, at least 0 and not all 0",
                )

    def holders_table(self) -> list[list[int]]:
        """`holders` of every cell at once (under holds: one pass over them)."""
        if not self.holds:
            return [self.holders(c) for c in range(self.nodes)]
        out = [[c] for c in range(self.nodes)]
        for n, cells in enumerate(self.holds):
            for c in cells:
                out[c].append(n)
        return out

    @classmethod
    def decode(cls, values: dict) -> dict:
        if isinstance(values.get("shared"), list):  # msgpack gives a list
            values = {**values, "shared": tuple(values["shared"])}
        holds = values.get("holds")
        if isinstance(holds, list) and all(isinstance(h, list) for h in holds):
            values = {**values, "holds": tuple(tuple(h) for h in holds)}
        shares = values.get("claim_shares")
        if isinstance(shares, list) and all(isinstance(h, list) for h in shares):
            values = {**values, "claim_shares": tuple(tuple(h) for h in shares)}
        return values

    def held(self, node: int) -> list[int]:
        """The nodes whose engines `node` holds: itself, and under `copies` the cells of
        `holds`, or without them its links and the shared cells."""
        if not self.copies:
            return [node]
        if self.holds:
            return [node, *self.holds[node]]
        links = Torus(self.rows, self.cols).links(node)
        return list(dict.fromkeys([node, *links, *self.shared]))

    def holders(self, node: int) -> list[int]:
        """The nodes that hold `node`'s engine: itself first, then the others in order."""
        return [node, *(n for n in range(self.nodes) if n != node and node in self.held(n))]

    def takers(self, node: int) -> list[int]:
        """For each cell, the node `node` hands a ray entering it to (`forward`): itself
        where it holds the cell's engine, else the owner, or under holds and "nearest" the
        holder fewest hops away (the owner, then the lowest number, on a tie)."""
        held = set(self.held(node))
        if not self.holds or self.forward == "owner":
            return [node if c in held else c for c in range(self.nodes)]
        holders = self.holders_table()
        torus = Torus(self.rows, self.cols)
        return [
            node if c in held else min(holders[c], key=lambda h: torus.distance(node, h))
            for c in range(self.nodes)
        ]

    @property
    def dynamic(self) -> bool:
        """Tiles dealt while the frame is traced, by the host."""
        return self.mode == "image" and self.tiles == "dynamic"


@dataclass(frozen=True)
class RenderSpec(Spec):
    """One render as every node receives it: the image (sized), engine choices, mesh plan,
    and the camera (None: the NFF pinhole)."""

    image: ImageSpec
    engine: EngineSpec = EngineSpec()
    plan: MeshPlan = MeshPlan()
    camera: CameraSpec | None = None

    NESTED: ClassVar[dict] = {
        "image": ImageSpec,
        "engine": EngineSpec,
        "plan": MeshPlan,
        "camera": CameraSpec,
    }

    def check(self) -> None:
        for name, record in self.NESTED.items():
            value = getattr(self, name)
            if not isinstance(value, record) and not (name == "camera" and value is None):
                self.fail(name, f"must be a {record.__name__}")
        if self.image.width is None or self.image.height is None:
            self.fail("image", "a render needs a sized image (ImageSpec.sized)")
        self.image.check_corners(self.camera is not None)

    @property
    def adaptive(self) -> bool:
        """Adaptive sampling through the camera: nodes keep their pixels' books."""
        return self.camera is not None and self.camera.adaptive(self.image.spp)

    @property
    def steals(self) -> bool:
        """Whether nodes take unstarted chunks from their neighbours: object space's lever
        (MeshPlan.steal), and adaptive sampling's second pass under dynamic tiles, whose
        books stay with the node that traced a tile's first pass while how much a tile
        refines is known only then."""
        return self.plan.steal or (self.plan.dynamic and self.adaptive)

    @property
    def sample_grid(self) -> tuple[int, int]:
        return self.image.sample_grid(self.camera is not None)

    @property
    def corners(self) -> bool:
        return self.image.corners(self.camera is not None)

    @property
    def rays_per_pixel(self) -> int:
        """Primary rays asked for a pixel: ImageSpec.spp, through any camera (what is traced
        may differ: CameraSampling.per_pixel's fixed points or one ray, adaptive sampling's
        fewer)."""
        return self.image.spp

    @property
    def ids_per_cell(self) -> int:
        """Deposit ids per framebuffer cell: a pixel's `spp` pinhole samples (ids pixel * spp
        + s); one under the SPD corners (a cell is a corner) and through a camera (its rays
        carry their pixel)."""
        return 1 if self.corners or self.camera is not None else self.image.spp
