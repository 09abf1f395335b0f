"""The engines a node built, kept across renders: building a grid or hierarchy for millions
of objects costs seconds, and a user re-rendering the same scene on a running cluster (another
size, sampling or camera) should not pay it again."""

import hashlib
from collections import Counter
from collections.abc import Callable

import numpy as np

from meshnode.engine import Engine
from meshnode.engine.loading import cpu_less_loads
from meshnode.engine.mapbounds import map_key, per_map_seconds
from protocols.render import EngineSpec
from protocols.scene import SCENE_TABLES, SceneData


class EngineCache:
    """The engines this node built for its last render, kept for the next render of the same
    objects in the same box with the same engine settings (a user re-rendering a scene at
    another size, sampling or camera on a running cluster pays no build). At most `keep`
    engines (one, or one per box held under MeshPlan.copies), least recently used dropped
    first: bounded memory; and after a render (`trim`) at most `keep_bytes` of them.
    `least`: engines kept at least whatever a render asks (a plan's simulated meshes share
    one cache: `host.planning.prepass.planning`)."""

    def __init__(self, keep_bytes: int | None = None, least: int = 1, same_scenes: bool = False):
        self.engines: dict[bytes, Engine] = {}  # oldest use first
        self.keep_bytes = keep_bytes  # kept between renders at most (None: no bound)
        self.least = least
        self.seen: dict[tuple, tuple] = {}  # `sightlines`, oldest first
        self.built = 0  # engines built, not reused: what a simulated mesh's cells cost anew
        self.build_seconds = 0.0  # ... and their CPU
        self.built_objects: Counter = Counter()  # ... and their objects by kind
        self.sights = 0  # `sightlines` made, not reused
        self.sight_seconds = 0.0  # ... and their CPU
        # `same_scenes`: the caller hands the same scene objects again and never changes
        # them (a plan's simulations: `host.planning.prepass.held_scenes`), so each scene's
        # objects are digested once, by identity (`_scene_digest`): tetra_s8 3x3's
        # simulations hashed them 11 ms of 60 ms each
        self.digests: dict[int, tuple[SceneData, bytes]] | None = {} if same_scenes else None
        # ... and each map's bytes digested once, by identity (`_digest`): a 3x3 simulation
        # digested the same map and sub-voxels nine times, 2.6 ms of balls' 19
        self.blobs: dict[int, tuple[bytes, bytes]] | None = {} if same_scenes else None

    def trim(self) -> None:
        """After a render: the oldest engines go until the rest fit `keep_bytes` (their
        memory comes back; the next render of their scene builds again)."""
        if self.keep_bytes is None:
            return
        while self.engines and sum(e.nbytes() for e in self.engines.values()) > self.keep_bytes:
            del self.engines[next(iter(self.engines))]

    def get(
        self, scene: SceneData, keep: int = 1, spec: EngineSpec = EngineSpec(), **placement
    ) -> tuple[Engine, bool]:
        """(engine, whether it was reused) for `scene` built as `spec` says, at `placement`
        (Engine.from_spec's keywords)."""
        # The primary rays an engine is told to expect choose its structure, not what it
        # traces: a kept engine serves a render of any size or sampling (in the structure
        # chosen for the render it was built for).
        built_from = {k: v for k, v in placement.items() if k != "eye_rays_expected"}
        key = _engine_key(self._scene_digest(scene), {"spec": spec, **built_from}, self.blobs)
        engine = self.engines.pop(key, None)
        reused = engine is not None
        if engine is None:
            while len(self.engines) >= max(1, keep, self.least):  # old memory goes first
                del self.engines[next(iter(self.engines))]
            began, once = cpu_less_loads(), per_map_seconds()
            engine = Engine.from_spec(scene, spec, **placement)
            self.built += 1  # its CPU, kernels loaded from the disk cache meanwhile left out,
            # and the map's tables made once for every engine on it (`mapbounds.per_map`)
            self.build_seconds += cpu_less_loads() - began - (per_map_seconds() - once)
            self.built_objects.update(scene.records_by_kind)
        self.engines[key] = engine
        return engine, reused

    def _scene_digest(self, scene: SceneData) -> bytes:
        """`scene_digest(scene)`, once a scene object where the cache keeps `digests` (the
        scene held with it, so no other object takes its id)."""
        if self.digests is None:
            return scene_digest(scene)
        known = self.digests.get(id(scene))
        if known is None:
            known = self.digests[id(scene)] = (scene, scene_digest(scene))
        return known[1]

    def sightlines(self, engine: Engine, key: tuple, make: Callable):
        """`make()` once for every engine on one occupancy map and scene box and the same
        `key` (view, image, cells: what the eye sees of the map, `meshnode.engine.
        sightlines`, and where the blocks' middle rays start, `meshnode.mesh.claims`): the
        same for every node of a mesh, so a simulated mesh makes it once, not once a node
        (a 3x3 plan's 13 simulations made it 117 times: 0.8 s of its 2.7 s). The newest
        SIGHTLINES_KEPT are kept; each entry holds the map it was keyed by, so no other
        map's array can take its id while it stays."""
        occ = engine.occupancy
        where = (engine.scene_lo.tobytes(), engine.scene_hi.tobytes())
        full = (*map_key(occ), where, *key)
        if full in self.seen:
            return self.seen[full][2]
        began, once = cpu_less_loads(), per_map_seconds()
        made = make()
        self.sights += 1
        self.sight_seconds += cpu_less_loads() - began - (per_map_seconds() - once)
        self.seen[full] = (occ.clear, occ.fine, made)
        while len(self.seen) > SIGHTLINES_KEPT:
            del self.seen[next(iter(self.seen))]
        return made


SIGHTLINES_KEPT = 8  # `EngineCache.sightlines` entries kept


def scene_digest(scene: SceneData) -> bytes:
    """A digest of a scene's objects and background, bytes as they are. SHA-256, which CPUs
    hash in hardware: 8 ms for the 12 MB of a 65,536-triangle tetra's records, against
    BLAKE2b's 21."""
    h = hashlib.sha256()
    for table in (getattr(scene, t) for t in SCENE_TABLES):
        h.update(len(table).to_bytes(8, "little"))
        h.update(np.ascontiguousarray(table).view(np.uint8))  # its bytes, not copied
    h.update(repr(tuple(scene.background)).encode())
    return h.digest()


def _engine_key(objects: bytes, options: dict, blobs: dict | None = None) -> bytes:
    """A digest of everything an engine is built from: its scene's digest `objects`
    (`scene_digest`) and options (bytes and arrays digested as they are: the repr of an
    occupancy map's 32 KB of bits was a tenth of a plan's CPU; `blobs`: `_digest`'s)."""
    h = hashlib.sha256(objects)
    for name, value in sorted(options.items()):
        h.update(name.encode())
        _digest(h, value, blobs)
    return h.digest()


BLOB = 4096  # bytes at least, digested on their own first (`_digest`)
BLOBS_KEPT = 32  # `EngineCache.blobs` entries kept, the oldest dropped first


def _digest(h, value, blobs: dict | None = None) -> None:
    """`value` into the digest h: bytes and arrays as their bytes (with their length and
    shape; bytes of BLOB or more as their own digest, which `blobs` keeps by identity where
    given: bytes never change, and each is held there so no other takes its id), tuples
    item by item, anything else by its repr."""
    if isinstance(value, tuple | list):
        h.update(b"(%d" % len(value))
        for v in value:
            _digest(h, v, blobs)
    elif isinstance(value, bytes) and len(value) >= BLOB:
        h.update(b"blob%d" % len(value))
        known = blobs.get(id(value)) if blobs is not None else None
        if known is None:
            known = (value, hashlib.sha256(value).digest())
            if blobs is not None:
                blobs[id(value)] = known
                while len(blobs) > BLOBS_KEPT:
                    del blobs[next(iter(blobs))]
        h.update(known[1])
    elif isinstance(value, bytes | np.ndarray):
        data = np.ascontiguousarray(value).tobytes() if isinstance(value, np.ndarray) else value
        shape = getattr(value, "shape", (len(value),))
        h.update(repr((type(value).__name__, getattr(value, "dtype", None), shape)).encode())
        h.update(data)
    else:
        h.update(repr(value).encode())
