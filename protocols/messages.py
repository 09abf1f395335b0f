"""Message kinds of the mesh and the fields each must carry.

A message is a dict {"k": kind, field: value, ...}; `make` builds one and `parse` checks one
received from a peer, so handlers only ever see well-formed messages. Arrays are wire arrays of
the dtype the field names (see `framing`).
"""

from enum import IntEnum

import numpy as np

from protocols import dtypes
from protocols.errors import BadFrame, UnknownKind
from protocols.records import Parts
from protocols.scene import TABLE_DTYPES

# 17: Partition.inner_* (a second occupancy map where the small objects lie);
# 16: RAYS_SET (several RAYS for one link in one frame);
# 15: Partition.occ_fine (the occupied voxels' sub-voxels a walk tests);
# 14: RAYS.cell (the engine a ray is for: a copy its node holds), MeshPlan.forward;
# 13: MeshPlan.holds (a budget's copies, node by node);
# 12: CameraSampling.rays gone (CONFIG's camera takes its rays per pixel from ImageSpec.spp),
# CONFIG.scene (protocols.scene.SceneHeader) for CONFIG.view and CONFIG.background;
# 11: PROGRESS.setup (where a node's setup is: SETUP_STEPS); 10: termination waves (STATE down
# the tree, ECHO up), TILES_TRACED; 9: arrays after the map,
# MeshPlan.max_share, node_bytes (8: MeshPlan.shared; 7: TILES.owners; 6: MeshPlan.order;
# 5: OBJECTS name)
PROTOCOL_VERSION = 17
MAX_TILES_PER_MESSAGE = 1024
MAX_LINKS = 4  # a torus node's neighbours
# PROGRESS.setup: the step a node's setup is at (an index), so the live view can say what a
# node does before it traces (a first run compiles kernels for tens of seconds): objects
# arriving, engine building, kernels compiling (a first run) or loading from the disk cache,
# links to the neighbours opening, ready
SETUP_STEPS = ("objects", "engine", "compile", "load", "links", "ready")


class Kind(IntEnum):
    HELLO = 1  # handshake: protocol version, cluster id, who is speaking, a fresh nonce
    CONFIG = 2  # node configuration from the host: mesh shape, coordinates, boxes, settings
    OBJECTS = 3  # a batch of one primitive kind's records for the node's box (or, under
    # MeshPlan.copies, a linked neighbour's: `node` says whose)
    RAYS = 4  # a batch of rays (eye, reflected, refracted or shadow) entering a node's box
    PIXELS = 5  # deposits on their way to node 0 and the host (adaptive: to the pixel's owner)
    STATE = 6  # a termination wave's probe, parent to child down the tree: wave, state
    STATS = 7  # a node's statistics
    SHUTDOWN = 8  # stop and close every link
    ERROR = 9  # the sender hit an error; `reason` says what
    PROGRESS = 10  # a node to the host: primary rays traced since its last report, batches
    # traced in all, whether its engine is built and its links are up (a heartbeat every
    # second, so the host tells alive from working, and building from stuck); and for the
    # live view: its state, busy and elapsed milliseconds, rays traced in all, objects held,
    # each link's traffic so far, and its setup step (SETUP_STEPS)
    AUTH = 11  # handshake: proof of the cluster secret over both nonces (protocols.handshake)
    WELCOME = 12  # handshake: the listener accepted the dialler's proof
    TILES = 13  # host to node, dynamic image space: tiles to trace (partition rectangles)
    TILE_DONE = 14  # node to host: tiles whose every primary ray has started
    ABORT = 15  # host to node: give up this render (a node was lost); a new CONFIG may follow
    ABORTED = 16  # node to host: the render is given up, its links closed; after everything
    # the node sent for it, so the host knows what follows belongs to the next render
    STEAL = 17  # node to neighbour (MeshPlan.steal): I have run out, give me unstarted chunks
    GIVE = 18  # neighbour's answer: chunks [x0, x1, y0, y1] of its rectangle, maybe none
    ECHO = 19  # child to parent: its subtree's answer to a wave (meshnode.mesh.termination)
    TILES_TRACED = 20  # node to host, dynamic image space: tiles whose every deposit it has
    # sent (all before this message), with their ray counts: kept if another node is lost
    RAYS_SET = 21  # several RAYS over one link in one frame: `parts` (dest, cell, count) each,
    # their rays end to end in `rays` (most of a flush's RAYS are a few rays each)


# field -> type (a Python type, a tuple of them, or a NumPy dtype for wire arrays)
_NUM = (int, float)
FIELDS = {
    # render: the render a node's link to a neighbour belongs to (empty from a host);
    # memory: bytes the listening node can give a render (the host plans with it; 0 unknown)
    Kind.HELLO: {
        "version": int,
        "cluster": str,
        "role": str,
        "node": int,
        "nonce": bytes,
        "render": bytes,
        "memory": int,
    },
    # render: protocols.render.RenderSpec, partition: protocols.partition.Partition, scene:
    # protocols.scene.SceneHeader (wire forms);
    # render_id: this render's random id (a new one for every try at a frame)
    Kind.CONFIG: {
        "node": int,
        "neighbours": dict,
        "render": dict,
        "partition": dict,
        "scene": dict,
        "render_id": bytes,
    },
    Kind.OBJECTS: {"table": str, "records": None, "node": int, "last": bool},
    Kind.RAYS: {"rays": dtypes.RAY, "dest": int, "cell": int},
    Kind.RAYS_SET: {"rays": dtypes.RAY, "parts": np.dtype("<i8")},
    Kind.PIXELS: {"deposits": dtypes.DEPOSIT, "dest": int},
    Kind.STATE: {"wave": int, "state": int},
    Kind.ECHO: {"wave": int, "dirty": bool, "sent": int, "received": int},
    Kind.STATS: {"node": int, "stats": dict},
    Kind.SHUTDOWN: {},
    Kind.ERROR: {"reason": str},
    Kind.PROGRESS: {
        "node": int,
        "rays": int,
        "work": int,
        "ready": bool,
        "state": int,
        "busy_ms": int,
        "elapsed_ms": int,
        "traced": int,
        "objects": int,
        "links": dtypes.LINK_TRAFFIC,
        "setup": int,
    },
    Kind.AUTH: {"proof": bytes},
    Kind.WELCOME: {},
    # owners: every tile's node, with `last` under adaptive sampling (else empty)
    Kind.TILES: {"tiles": list, "last": bool, "owners": np.dtype("<i8")},
    Kind.TILE_DONE: {"node": int, "tiles": list},
    Kind.TILES_TRACED: {"node": int, "tiles": list, "counts": dict},
    Kind.ABORT: {"reason": str},
    Kind.ABORTED: {},
    Kind.STEAL: {"node": int},
    Kind.GIVE: {"chunks": list},
}
OBJECT_TABLES = TABLE_DTYPES  # OBJECTS.table: each scene table's records


def _check(kind: Kind, name: str, value, want) -> None:
    if want is None:
        return
    if isinstance(want, np.dtype):  # an array, or a sender's Parts of arrays sent as one
        if not isinstance(value, (np.ndarray, Parts)) or value.dtype != want:
            got = getattr(value, "dtype", type(value).__name__)
            raise BadFrame(f"{kind.name}.{name} must be an array of {want}, got {got}")
        return
    if want is float:
        want = _NUM
    if isinstance(value, bool) and want is int:
        raise BadFrame(f"{kind.name}.{name} must be int, got bool")
    if not isinstance(value, want):
        raise BadFrame(
            f"{kind.name}.{name} must be {getattr(want, '__name__', want)}, "
            f"got {type(value).__name__}"
        )


def make(kind: Kind, **fields) -> dict:
    """A message of `kind`; every field of the kind must be given, no other."""
    spec = FIELDS[kind]
    if set(fields) != set(spec):
        raise TypeError(f"{kind.name} needs fields {sorted(spec)}, got {sorted(fields)}")
    for name, value in fields.items():
        _check(kind, name, value, spec[name])
    return {"k": int(kind), **fields}


def parse(message: dict) -> tuple[Kind, dict]:
    """Kind and fields of a received message, checked against FIELDS."""
    raw = message.get("k")
    try:
        kind = Kind(raw)
    except (ValueError, TypeError):
        raise UnknownKind(f"unknown message kind {raw!r}") from None
    fields = {k: v for k, v in message.items() if k != "k"}
    spec = FIELDS[kind]
    missing = set(spec) - set(fields)
    extra = set(fields) - set(spec)
    if missing or extra:
        raise BadFrame(
            f"{kind.name}: missing {sorted(missing)}, unexpected {sorted(map(repr, extra))}"
        )  # keys of any type: sort their reprs
    for name, value in fields.items():
        _check(kind, name, value, spec[name])
    if kind is Kind.GIVE:
        chunks = fields["chunks"]
        if len(chunks) > MAX_TILES_PER_MESSAGE or not all(
            isinstance(c, list)
            and len(c) == 4
            and all(isinstance(v, int) and not isinstance(v, bool) and v >= 0 for v in c)
            and c[0] < c[1]
            and c[2] < c[3]
            for c in chunks
        ):
            raise BadFrame(
                f"GIVE.chunks must be at most {MAX_TILES_PER_MESSAGE} rectangles "
                "[x0, x1, y0, y1] of non-negative integers, x0 < x1, y0 < y1"
            )
    if kind in (Kind.TILES, Kind.TILE_DONE, Kind.TILES_TRACED):
        tiles = fields["tiles"]
        if len(tiles) > MAX_TILES_PER_MESSAGE or not all(
            isinstance(t, int) and not isinstance(t, bool) and t >= 0 for t in tiles
        ):
            raise BadFrame(
                f"{kind.name}.tiles must be at most {MAX_TILES_PER_MESSAGE} tile indices"
            )
    if kind is Kind.PROGRESS:
        _check_progress(fields)
    if kind is Kind.TILES_TRACED:
        _check_counts(fields["counts"])
    if kind is Kind.OBJECTS:
        want = OBJECT_TABLES.get(fields["table"])
        if want is None:
            raise BadFrame(f"OBJECTS: unknown table {fields['table']!r}")
        _check(kind, "records", fields["records"], want)
    return kind, fields


def _check_progress(f: dict) -> None:
    """Counters never negative, a setup step of SETUP_STEPS, at most a torus node's links (the
    host checks node numbers and states against its mesh)."""
    counts = ("node", "rays", "work", "state", "busy_ms", "elapsed_ms", "traced", "objects")
    bad = [name for name in counts if f[name] < 0]
    if not 0 <= f["setup"] < len(SETUP_STEPS):
        bad.append("setup")
    links = f["links"]
    if len(links) > MAX_LINKS or (
        len(links)
        and (links["peer"].min() < 0 or links["rays"].min() < 0 or links["bytes"].min() < 0)
    ):
        bad.append("links")
    if bad:
        raise BadFrame(f"PROGRESS: {', '.join(bad)} out of range")


MAX_COUNTERS = 64  # ray counters in a TILES_TRACED (a node's STATS has about 20)


def _check_counts(counts: dict) -> None:
    """Counters a host adds into the render's statistics: named, whole and not negative."""
    if len(counts) > MAX_COUNTERS or not all(
        isinstance(k, str)
        and len(k) <= 64
        and isinstance(v, int)
        and not isinstance(v, bool)
        and 0 <= v < 2**62
        for k, v in counts.items()
    ):
        raise BadFrame(
            f"TILES_TRACED.counts must be at most {MAX_COUNTERS} named counters, "
            "each a whole number from 0"
        )
