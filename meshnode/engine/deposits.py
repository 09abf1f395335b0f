"""A batch's colour on its way to the framebuffer, as DEPOSIT records: one per ray that
brought any, then summed per framebuffer cell, so a pixel's samples travel as one deposit.

Both are one pass over the batch in a kernel: in numpy they were five passes a batch and a
sort (tetra 3x3 simulated, 384x384 at 32 spp: 0.36 s of the 0.97 s its nodes spent outside
their tracing kernels; 0.08 s in these kernels, `bench.batch_cpu`)."""

import numpy as np

from meshnode.engine.jit import kernel


@kernel
def lit(rays, rgb, out):
    """Write (pixel, colour) of each of `rays` whose colour (rgb row) is not zero (NaN
    counts as colour) into `out`, in order; returns how many."""
    n = 0
    for i in range(rays.shape[0]):
        r, g, b = rgb[i, 0], rgb[i, 1], rgb[i, 2]
        if r != 0.0 or g != 0.0 or b != 0.0:
            out[n].pixel = rays[i].pixel
            out[n].rgb[0], out[n].rgb[1], out[n].rgb[2] = r, g, b
            n += 1
    return n


@kernel
def cell_sums(deposits, ids_per_cell, out):
    """Write each framebuffer cell's sum of `deposits` into `out` under the cell's first id,
    cells in increasing order, and return how many. Each cell's deposits are added in the
    order they came, from zero, as the host's framebuffer adds them (`np.bincount`), so the
    frame is the same to the bit; deposits already in cell order (eye rays) need no sort."""
    n = deposits.shape[0]
    cells = np.empty(n, np.int64)
    in_order = True
    for i in range(n):
        cells[i] = deposits[i].pixel // ids_per_cell
        if i > 0 and cells[i] < cells[i - 1]:
            in_order = False
    order = np.arange(n) if in_order else np.argsort(cells, kind="mergesort")  # stable
    m = -1
    last = -1
    for j in range(n):
        i = order[j]
        if m < 0 or cells[i] != last:
            m += 1
            last = cells[i]
            out[m].pixel = last * ids_per_cell
            out[m].rgb[0], out[m].rgb[1], out[m].rgb[2] = 0.0, 0.0, 0.0
        for c in range(3):
            out[m].rgb[c] += deposits[i].rgb[c]
    return m + 1
