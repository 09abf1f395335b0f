"""The object side of a partition: each node's cell of the scene's box, and the box it
traces.

The two world axes most perpendicular to the view are cut where test rays through the
rectangle boundaries meet the near face of the scene box (or, when the eye is inside the box's
slab, the plane through the view's target), so a rectangle's primary rays enter its node's
cell; outer cells reach the scene bounds, so the cells tile the scene. A node's box is its cell
grown by the overlap percentage of its size: the node holds the box's objects and traces a ray
until it leaves the box, then hands it to the node whose cell holds the exit (so overlap keeps
rays longer on one node, while the cells, not the overlap, decide who takes them on). The cost
pre-pass may instead cut the cells where its work map puts the work (`host.planning.workmap`).
"""

import numpy as np

from host.planning.rectangles import column_rows, splits
from host.scene.derived import scene_tables
from meshnode.engine.camera import view_basis
from meshnode.engine.grid import grow_box
from protocols.scene import SceneData, View


def scene_box(scene: SceneData) -> tuple[np.ndarray, np.ndarray]:
    """Bounds of every object, padded as the grid pads them."""
    tb = scene_tables(scene)
    if not tb.n:
        return np.zeros(3), np.ones(3)
    return grow_box(tb.lo.min(axis=0), tb.hi.max(axis=0))


def _cuts(view: View, width, height, bounds, lo, hi, n_parts, along, image_axis):
    """Cut positions on world axis `along` for the sample-grid boundaries on `image_axis`."""
    eye, fwd, right, up, step = view_basis(view, width, height)
    depth = int(np.argmax(np.abs(fwd)))
    face = lo[depth] if fwd[depth] > 0 else hi[depth]  # the near face
    if (face - eye[depth]) * fwd[depth] <= 0:
        # The eye is inside the box's slab on this axis: cut where the view is aimed instead.
        face = float(np.clip(view.at[depth], lo[depth], hi[depth]))
    cuts = []
    for b in bounds[1:-1]:
        # A ray through the boundary on the image's centre line.
        px = (b - 0.5 * width) * step if image_axis == 0 else 0.0
        py = (0.5 * height - b) * step if image_axis == 1 else 0.0
        d = fwd + px * right + py * up
        if abs(d[depth]) < 1e-12:
            cuts.append(None)
            continue
        t = (face - eye[depth]) / d[depth]
        cuts.append(float(eye[along] + t * d[along]))
    if any(c is None for c in cuts) or len(set(np.sign(np.diff(cuts)))) > 1:
        # Degenerate view: fall back to equal slices.
        cuts = list(lo[along] + (hi[along] - lo[along]) * np.arange(1, n_parts) / n_parts)
    cuts = np.clip(cuts, lo[along], hi[along])
    if len(cuts) and cuts[0] > cuts[-1]:  # the image axis runs against the world axis
        return np.concatenate([[hi[along]], cuts, [lo[along]]])
    return np.concatenate([[lo[along]], cuts, [hi[along]]])


def node_cells(
    scene: SceneData, box, width: int, height: int, rows: int, cols: int, xs=None, ys=None
):
    """(los, his), each (rows*cols, 3): node r*cols+c's cell of object space, cut where rays
    through the rectangles' boundaries (`xs`, `ys` as `host.planning.rectangles.rectangles`
    takes them; default even) meet the scene. The cells tile the scene's box."""
    lo, hi = (np.asarray(b, float) for b in box)
    col_axis, row_axis = cell_axes(scene.view, width, height)
    xs = xs or splits(width, cols)
    xcuts = _cuts(scene.view, width, height, xs, lo, hi, cols, col_axis, 0)
    ycuts = [
        _cuts(scene.view, width, height, ys_c, lo, hi, rows, row_axis, 1)
        for ys_c in column_rows(ys, height, rows, cols)
    ]
    return cells_from_cuts(box, (col_axis, row_axis), xcuts, ycuts)


def cell_axes(view: View, width: int, height: int) -> tuple[int, int]:
    """(column axis, row axis): the world axes cells are cut along, the two most
    perpendicular to the view; columns follow the one closest to the image's `right`."""
    _, fwd, right, _, _ = view_basis(view, width, height)
    depth = int(np.argmax(np.abs(fwd)))
    others = [a for a in range(3) if a != depth]
    col_axis = max(others, key=lambda a: abs(right[a]))
    return col_axis, [a for a in others if a != col_axis][0]


def cells_from_cuts(box, axes: tuple[int, int], xcuts, ycuts) -> tuple[np.ndarray, np.ndarray]:
    """(los, his) of rows x cols cells of `box`: column c between world positions xcuts[c]
    and xcuts[c + 1] on axes[0], its row r between ycuts[c][r] and ycuts[c][r + 1] on axes[1]
    (each list running either way); the third axis spans the box."""
    lo, hi = (np.asarray(b, float) for b in box)
    cols, rows = len(xcuts) - 1, len(ycuts[0]) - 1
    col_axis, row_axis = axes
    los = np.tile(lo, (rows * cols, 1))
    his = np.tile(hi, (rows * cols, 1))
    for r in range(rows):
        for c in range(cols):
            n = r * cols + c
            xa, xb = sorted((xcuts[c], xcuts[c + 1]))
            ya, yb = sorted((ycuts[c][r], ycuts[c][r + 1]))
            los[n, col_axis], his[n, col_axis] = xa, xb
            los[n, row_axis], his[n, row_axis] = ya, yb
    return los, his


def grown(los: np.ndarray, his: np.ndarray, overlap: float) -> tuple[np.ndarray, np.ndarray]:
    """Boxes grown by `overlap` percent of their size on every side: what each node holds
    and traces (its cell only decides which rays it takes on)."""
    if overlap < 0:
        raise ValueError("overlap must not be negative")
    grow = (his - los) * (overlap / 100.0)
    return los - grow, his + grow


def traced(los: np.ndarray, his: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The space each node traces: its box padded as its engine pads it (`grow_box`). A
    node holds every object that reaches this, not only its box: an object in the padding
    was missed there while the node traced past it and sent the ray on beyond it (balls
    2x2 at 1024x1024, 6 spp: 4 shadow rays in 33 M lit that one node found blocked)."""
    lo, hi = zip(*(grow_box(lo, hi) for lo, hi in zip(los, his, strict=True)), strict=True)
    return np.array(lo), np.array(hi)  # a box at a time, once a plan
