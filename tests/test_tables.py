"""The kernel tables: material and light columns sit where their named constants say, and the
named tables the kernels take carry the node's arrays (absent kinds as None)."""

import numpy as np

from meshnode.engine import Engine
from meshnode.engine.tables import (
    LIGHT_COLS,
    LIGHT_POS,
    LIGHT_RGB,
    MAT_COLS,
    MAT_IOR,
    MAT_KD,
    MAT_KS,
    MAT_RGB,
    MAT_SHINE,
    MAT_TRANSMIT,
    build_tables,
)
from tests.conftest import make_scene

MATERIALS = [((0.1, 0.2, 0.3), 0.4, 0.5, 6.0, 0.7, 1.8), ((0.9, 0.8, 0.7), 0.6, 0.0, 2.0, 0.0, 1.0)]


def test_material_and_light_columns_follow_their_constants():
    lights = [(1.0, 2.0, 3.0), (-4.0, 5.0, -6.0)]
    tb = build_tables(make_scene(spheres=[((0, 0, 0), 1.0, 0)], lights=lights, materials=MATERIALS))
    assert tb.materials.shape == (2, MAT_COLS)
    for row, (rgb, kd, ks, shine, t, ior) in zip(tb.materials, MATERIALS, strict=True):
        np.testing.assert_array_equal(row[MAT_RGB : MAT_RGB + 3], rgb)
        assert (row[MAT_KD], row[MAT_KS], row[MAT_SHINE]) == (kd, ks, shine)
        assert (row[MAT_TRANSMIT], row[MAT_IOR]) == (t, ior)
    assert tb.lights.shape == (2, LIGHT_COLS)
    np.testing.assert_array_equal(tb.lights[:, LIGHT_POS : LIGHT_POS + 3], lights)
    # SPD rule: white lights scaled to sqrt(L) / (2 L) each.
    np.testing.assert_allclose(tb.lights[:, LIGHT_RGB : LIGHT_RGB + 3], np.sqrt(2) / 4)


def test_named_tables_hold_the_node_arrays():
    scene = make_scene(triangles=[((0, 0, 0), (1, 0, 0), (0, 1, 0), 1)], materials=MATERIALS)
    engine = Engine(scene, storage="hash", structure="grid")
    geo, grid, shading = engine.geometry, engine.grid_arrays, engine.shading
    assert geo.sph is None and geo.poly is None and geo.cone is None
    assert geo.tri is engine.tables.triangles
    assert shading.tri_n is None and shading.mat.tolist() == [1]
    assert engine.transmit is None  # the triangle's material does not transmit
    assert grid.refs is engine.grid.refs and grid.bits is engine.grid.bits
    assert len(grid.offsets) == 0  # hash storage: the CSR offsets are passed empty
    assert engine.bvh_arrays is None  # the grid answers: the hierarchy is compiled out
