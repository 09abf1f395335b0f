"""The engines a node built, kept across renders: building a grid or hierarchy for millions
of objects costs seconds, and a user re-rendering the same scene on a running cluster (another
size, sampling or camera) should not pay it again."""

import hashlib

import numpy as np

from meshnode.engine import Engine
from protocols.render import EngineSpec
from protocols.scene import SCENE_TABLES, SceneData


class EngineCache:
    """The engines this node built for its last render, kept for the next render of the same
    objects in the same box with the same engine settings (a user re-rendering a scene at
    another size, sampling or camera on a running cluster pays no build). At most `keep`
    engines (one, or one per box held under MeshPlan.copies), least recently used dropped
    first: bounded memory; and after a render (`trim`) at most `keep_bytes` of them."""

    def __init__(self, keep_bytes: int | None = None):
        self.engines: dict[bytes, Engine] = {}  # oldest use first
        self.keep_bytes = keep_bytes  # kept between renders at most (None: no bound)

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
        key = _engine_key(scene, {"spec": spec, **built_from})
        engine = self.engines.pop(key, None)
        reused = engine is not None
        if engine is None:
            while len(self.engines) >= max(1, keep):  # old memory goes before the build
                del self.engines[next(iter(self.engines))]
            engine = Engine.from_spec(scene, spec, **placement)
        self.engines[key] = engine
        return engine, reused


def _engine_key(scene: SceneData, options: dict) -> bytes:
    """A digest of everything an engine is built from: objects, background, options."""
    h = hashlib.blake2b(digest_size=32)
    for table in (getattr(scene, t) for t in SCENE_TABLES):
        h.update(len(table).to_bytes(8, "little"))
        h.update(np.ascontiguousarray(table).tobytes())
    h.update(
        repr((tuple(scene.background), sorted((k, repr(v)) for k, v in options.items()))).encode()
    )
    return h.digest()
