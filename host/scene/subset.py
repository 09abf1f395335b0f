"""A scene restricted to some of its objects: what a node holds, or what the autofocus probe
can hit. Object ids (gids) and materials are kept, so hits and colours are the whole scene's."""

from dataclasses import replace

import numpy as np

from meshnode.engine.tables import segments
from protocols.scene import SceneData


def subset(scene: SceneData, keep: np.ndarray) -> SceneData:
    """The scene restricted to objects `keep` (engine local order), gids and materials kept."""
    counts = list(scene.records_by_kind.values())
    parts = np.split(keep, np.cumsum(counts)[:-1])
    polys = scene.polygons[parts[2]].copy()
    rows, new_start, _, _ = segments(polys["start"], polys["count"])  # kept vertices, in order
    polys["start"] = new_start
    return replace(
        scene,
        spheres=scene.spheres[parts[0]],
        triangles=scene.triangles[parts[1]],
        polygons=polys,
        vertices=scene.vertices[rows].reshape(-1, 3),
        cones=scene.cones[parts[3]],
    )
