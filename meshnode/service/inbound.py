"""What a neighbour may send during a render: each RAYS, PIXELS, STATE, ECHO and GIVE checked before
the session acts on it (DESIGN.md 5: everything a peer sends is validated and bounded before
anything is allocated). A bad message raises BadFrame naming the message and its field; the
session reports it as that neighbour's link failing.
"""

import numpy as np

from meshnode.engine.raycheck import first_untraceable
from meshnode.mesh.termination import Echo, Probe
from protocols.errors import BadFrame
from protocols.render import RenderSpec
from protocols.state import State


def check_dest(f: dict, kind: str, nodes: int) -> int:
    """A message's destination node, checked: a neighbour cannot route outside the mesh."""
    dest = f["dest"]
    if not 0 <= dest < nodes:
        raise BadFrame(f"{kind}.dest = {dest}: no such node")
    return dest


def check_rays(f: dict, nodes: int) -> None:
    """RAYS: rays the engine can trace (finite, of a known kind, depth >= 1) for a node of
    the mesh and one of its cells; a NaN would poison every batch it joins. (Whether the
    node holds that cell's engine is its own check, `checked_cell`.)"""
    check_dest(f, "RAYS", nodes)
    if not 0 <= f["cell"] < nodes:
        raise BadFrame(f"RAYS.cell = {f['cell']}: no such cell")
    _traceable(f["rays"], "RAYS")


def checked_parts(f: dict, nodes: int) -> list:
    """RAYS_SET: its parts as (dest, cell, first ray, end), each a node and cell of the mesh
    and at least one ray, their counts adding up to the rays sent (checked as RAYS' are)."""
    parts, r = f["parts"], f["rays"]
    if len(parts) % 3 or not 2 <= len(parts) // 3 <= nodes * nodes:
        raise BadFrame(f"RAYS_SET.parts: {len(parts)} numbers, not 2 to {nodes * nodes} triples")
    dest, cell, count = parts[0::3], parts[1::3], parts[2::3]
    if not ((0 <= dest) & (dest < nodes) & (0 <= cell) & (cell < nodes)).all():
        raise BadFrame("RAYS_SET.parts: a destination or cell outside the mesh")
    if (count < 1).any() or int(count.sum()) != len(r):
        raise BadFrame(f"RAYS_SET.parts: counts must each be at least 1 and add up to {len(r)}")
    _traceable(r, "RAYS_SET")
    ends = np.cumsum(count)
    return [
        (int(d), int(c), int(e - n), int(e))
        for d, c, n, e in zip(dest, cell, count, ends, strict=True)
    ]


def _traceable(r, kind: str) -> None:
    """Rays the engine can trace: finite, of a known kind, depth >= 1."""
    bad = first_untraceable(r) if len(r) else -1
    if bad >= 0:
        raise BadFrame(
            f"{kind}: ray {bad} of {len(r)} cannot be traced (each must be finite, of a known "
            "kind, depth >= 1)"
        )


def checked_cell(f: dict, node: int, held) -> int:
    """The cell whose engine node `node` traces these RAYS with: one it holds (its own, or a
    copy, `MeshPlan.held`)."""
    if f["cell"] not in held:
        raise BadFrame(f"RAYS.cell = {f['cell']}: node {node} holds no engine of that cell")
    return f["cell"]


def check_pixels(f: dict, nodes: int) -> None:
    """PIXELS: finite colours for a node of the mesh (they are summed into the image)."""
    check_dest(f, "PIXELS", nodes)
    if not np.isfinite(f["deposits"]["rgb"]).all():
        raise BadFrame("PIXELS: colours must be finite")


def checked_probe(f: dict, sender: int, parent: int | None) -> Probe:
    """STATE: a wave's probe, only from this node's parent in the tree, in a known state."""
    if sender != parent:
        raise BadFrame(f"STATE from node {sender}, which is not this node's parent in the tree")
    if not 0 <= f["state"] <= State.DONE or f["wave"] < 1:
        raise BadFrame(f"STATE: wave {f['wave']} in state {f['state']} does not exist")
    return Probe(f["wave"], f["state"])


def checked_echo(f: dict) -> Echo:
    """ECHO: a wave's answer with counts a render can reach (the scheduler checks that it
    comes from a child and answers the open wave)."""
    if f["wave"] < 1 or not 0 <= f["sent"] < 2**62 or not 0 <= f["received"] < 2**62:
        raise BadFrame("ECHO: wave or message counts out of range")
    return Echo(f["wave"], f["dirty"], f["sent"], f["received"])


def checked_chunks(chunks: list, render: RenderSpec) -> list:
    """A neighbour's GIVE checked: chunks inside the image (the message kind checked
    their shape), and only when stealing was asked for."""
    if not render.steals:
        raise BadFrame("GIVE in a render without stealing")
    w, h = render.sample_grid
    if any(c[1] > w or c[3] > h for c in chunks):
        raise BadFrame(f"GIVE: a chunk reaches beyond the {w}x{h} sample grid")
    return chunks
