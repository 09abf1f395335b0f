"""One node's render (host.run.oneprocess): its pinhole jobs cover every sample once, in bounded
batches, and a high-spp render's bounded bands trace to the image of whole-row bands."""

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from host.planning.request import Request
from host.run.oneprocess import BAND_RAYS, BAND_ROWS, pinhole_bands


@settings(max_examples=200, deadline=None)
@given(st.integers(1, 3000), st.integers(1, 300), st.integers(1, 200))
def test_pinhole_bands_cover_every_sample_once_within_the_bounds(w, h, spp):
    seen = np.zeros((h, w), np.int64)
    for (y0, y1), (x0, x1) in pinhole_bands(w, h, spp):
        seen[y0:y1, x0:x1] += 1
        assert y1 - y0 <= BAND_ROWS
        assert (y1 - y0) * (x1 - x0) * spp <= max(BAND_RAYS, spp)  # one sample may exceed
    assert (seen == 1).all()


def test_a_high_spp_render_in_bounded_bands_equals_whole_row_bands(monkeypatch):
    # tetra_s1 at 40 spp: 16 rows of 48 pixels are 30,720 rays; with the bound at 1000 rays
    # a job is part of one row. The image is the same to the bit either way (a pixel's
    # samples stay in one job), and so are the counts.
    from host.run.oneprocess import render
    from host.scene.nff import read_nff
    from protocols.render import EngineSpec, ImageSpec
    from tests.conftest import spd_scene

    scene = read_nff(spd_scene("tetra_s1.nff"))
    image = ImageSpec(width=48, height=32, spp=40)
    whole, a = render(Request(scene, image, EngineSpec(threads=1)))
    monkeypatch.setattr("host.run.oneprocess.BAND_RAYS", 1000)
    parts, b = render(Request(scene, image, EngineSpec(threads=1)))
    assert np.array_equal(whole, parts)
    assert a["rays"] == b["rays"]
