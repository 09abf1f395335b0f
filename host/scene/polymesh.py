"""A polygon mesh file (OBJ, PLY) as a scene: its faces with one material, and the view,
lights and material from the settings TOML beside it (or given), defaults for the rest.

Faces with a normal at every corner are smooth patches (NFF `pp`), the others flat polygons
(NFF `p`): a mesh gives the image of the NFF file that lists the same faces in the same order.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import numpy as np

from host.scene.builder import SceneBuilder
from host.scene.errors import SceneError
from host.scene.meshfaces import MeshFaces
from host.scene.settings import (
    Settings,
    beside,
    default_light,
    framing,
    material_row,
    read_settings,
)
from protocols.scene import SceneData


def read_polymesh(path, settings=None, note: Callable[[str], None] | None = None) -> SceneData:
    """Read an .obj or .ply mesh; `settings`: a TOML (default: the one beside the mesh)."""
    path = Path(path)
    if path.suffix.lower() == ".obj":
        from host.scene.obj import read_obj as read
    else:
        from host.scene.ply import read_ply as read
    faces = read(path)
    toml = Path(settings) if settings is not None else beside(path)
    given = read_settings(toml) if toml is not None else Settings()
    if not len(faces.counts):
        raise SceneError(str(path), 1, "the mesh has no faces")
    build = SceneBuilder(str(path))
    add_faces(build, faces, build.material(material_row(given.material)))
    lo, hi = build.bounds()
    view = framing(lo, hi, given)
    for pos, rgb in given.lights or [default_light(lo, hi, view)]:
        build.light(pos, rgb)
    scene = build.build(view, given.background or (0.0, 0.0, 0.0))
    if note is not None:
        for line in build.notes + _defaults(path, toml, given):
            note(line)
    return scene


def add_faces(build: SceneBuilder, faces: MeshFaces, mat: int) -> None:
    """Every face, in file order: runs of smooth faces as patches, the rest as polygons."""
    smooth = faces.smooth()
    corners = faces.corners()
    starts = np.concatenate(([0], np.cumsum(faces.counts)))
    cuts = np.flatnonzero(np.diff(smooth.astype(np.int8))) + 1
    for a, b in zip(
        np.concatenate(([0], cuts)), np.concatenate((cuts, [len(smooth)])), strict=True
    ):
        sl = slice(starts[a], starts[b])
        normals = faces.normals[faces.corner_n[sl]] if smooth[a] else None
        build.faces(corners[sl], faces.counts[a:b], mat, faces.lines[a:b], normals)


def _defaults(path: Path, toml: Path | None, given: Settings) -> list[str]:
    """One line naming what defaults stood in for, or nothing."""
    used = []
    if "from" not in given.view:
        used.append("a camera framing the mesh")
    if not given.lights:
        used.append("one white light above the eye")
    if given.material is None:
        used.append("a grey matte material")
    if not used:
        return []
    where = f"no {path.with_suffix('.toml').name} beside it" if toml is None else f"{toml}"
    return [f"{path}: {where}: using {', '.join(used)}"]
