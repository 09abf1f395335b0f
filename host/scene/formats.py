"""A scene file of any format the host reads, chosen by its extension (the error every
reader raises is host.scene.errors.SceneError, re-exported here).

Every reader fills the same `SceneData`; what a format lacks (a bare mesh has no camera, light
or material) comes from a TOML file beside it, or from defaults that a note names.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

from host.scene.errors import SceneError
from protocols.scene import SceneData

__all__ = ["FORMATS", "SceneError", "read_scene"]

# Extension -> what the file is, for --help and the unknown-extension error.
FORMATS = {
    ".nff": "NFF (Standard Procedural Databases)",
    ".obj": "Wavefront OBJ mesh",
    ".ply": "PLY mesh (ASCII or binary)",
    ".iv": "Open Inventor 2.1 ASCII",
}


def read_scene(path, settings=None, note: Callable[[str], None] | None = None) -> SceneData:
    """Read a scene file by its extension. `settings`: a TOML file of view, lights and material
    (for meshes and Inventor; default: the file's stem + .toml beside it, when there is one);
    `note` receives one line when defaults stand in for what the file lacks."""
    path = Path(path)
    ext = path.suffix.lower()
    if ext == ".nff":
        if settings is not None:
            raise SceneError(
                str(settings),
                1,
                "an NFF scene has its own view, lights and "
                "materials: settings are for .obj, .ply and .iv",
            )
        from host.scene.nff import read_nff

        return read_nff(path)
    if ext in (".obj", ".ply"):
        from host.scene.polymesh import read_polymesh

        return read_polymesh(path, settings, note)
    if ext == ".iv":
        from host.scene.inventor import read_inventor

        return read_inventor(path, settings, note)
    known = ", ".join(FORMATS)
    raise SceneError(
        str(path),
        1,
        f"unknown scene format {path.suffix or '(no extension)'!r}: the host reads {known}",
    )
