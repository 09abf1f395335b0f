"""What the host's planning derives from a whole scene, made once while the scene lives: its
kernel tables (its bounds, clipping, occupancy map and object counts each built them anew:
gears 3x3 under a quarter share, 168 builds, 1.6 s of a 3.3 s plan) and which objects a box
holds (`host.planning.clip.holders`: the same cells clipped by the partition, the budget and
every trial of growth). Scenes are not changed once read: a subset or a replaced scene is
another object, with its own."""

import weakref
from collections.abc import Callable, Hashable

from meshnode.engine.tables import Tables, build_tables
from protocols.scene import SceneData

_KEPT: dict[int, tuple[weakref.ref, dict]] = {}


def derived(scene: SceneData) -> dict:
    """The things kept for `scene` (by name), dropped with it."""
    key = id(scene)
    kept = _KEPT.get(key)
    if kept is not None and kept[0]() is scene:
        return kept[1]
    store: dict = {}
    _KEPT[key] = (weakref.ref(scene, lambda _, key=key: _KEPT.pop(key, None)), store)
    return store


def kept(scene: SceneData, name: Hashable, make: Callable):
    """`make()` once while `scene` lives, under `name` (a string, or a tuple naming what it
    was made from)."""
    store = derived(scene)
    if name not in store:
        store[name] = make()
    return store[name]


def scene_tables(scene: SceneData) -> Tables:
    """`build_tables(scene)`, once while the scene lives."""
    return kept(scene, "tables", lambda: build_tables(scene))
