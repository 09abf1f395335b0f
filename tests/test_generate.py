"""The generated SPD scenes of the scaling benchmark: the SPD object counts at every size
factor, and the same scene as the SPD files where those exist (within their printed digits)."""

import numpy as np
import pytest

from bench.generate import balls, balls_count, tetra, tetra_count
from bench.spd import parse_scaling
from host.scene.nff import read_nff
from tests.conftest import spd_scene

TOL = 1e-4  # the SPD files print six significant digits


def assert_same_scene(made, read) -> None:
    """View, background, lights, materials and every record of `made` as `read` has them."""
    assert made.view == read.view
    assert np.allclose(made.background, read.background, rtol=0, atol=TOL)
    assert np.array_equal(made.lights, read.lights)
    assert np.array_equal(made.materials, read.materials)
    for kind in ("spheres", "triangles", "polygons", "cones"):
        a, b = getattr(made, kind), getattr(read, kind)
        assert len(a) == len(b), kind
        for name in a.dtype.names:
            if a[name].dtype.kind == "f":
                assert np.allclose(a[name], b[name], rtol=0, atol=TOL), (kind, name)
            else:
                assert np.array_equal(a[name], b[name]), (kind, name)
    assert np.allclose(made.vertices, read.vertices, rtol=0, atol=TOL)


@pytest.mark.parametrize(
    "n,name",
    [
        (1, "tetra_s1"),
        (2, "tetra_s2"),
        (3, "tetra_s3"),
        (4, "tetra_s4"),
        (5, "tetra_s5"),
        (6, "tetra"),
    ],
)
def test_tetra_is_the_spd_file(n, name):
    assert_same_scene(tetra(n), read_nff(spd_scene(f"{name}.nff")))


@pytest.mark.parametrize(
    "n,name", [(1, "balls_s1"), (2, "balls_s2"), (3, "balls_s3"), (4, "balls")]
)
def test_balls_is_the_spd_file(n, name):
    assert_same_scene(balls(n), read_nff(spd_scene(f"{name}.nff")))


@pytest.mark.parametrize("n", range(1, 8))
def test_tetra_has_4_to_the_n_triangles(n):
    scene = tetra(n)
    assert tetra_count(n) == 4**n == len(scene.triangles) == scene.n_objects
    assert len(scene.spheres) == len(scene.polygons) == 0


@pytest.mark.parametrize("n", range(0, 6))
def test_sphereflake_has_sum_of_9_to_the_k_spheres_and_a_floor(n):
    scene = balls(n)
    spheres = sum(9**k for k in range(n + 1))
    assert balls_count(n) == spheres == len(scene.spheres)
    assert scene.n_objects == spheres + 1 and len(scene.polygons) == 1
    radii = np.sort(scene.spheres["radius"])[::-1]
    sizes = np.repeat(0.5 / 3.0 ** np.arange(n + 1), 9 ** np.arange(n + 1))
    assert np.allclose(radii, sizes)  # 9^k spheres a third as large at each level


def test_scaling_option():
    assert parse_scaling("tetra:1-3, balls:2") == [("tetra", [1, 2, 3]), ("balls", [2])]
    for bad in ("cube:1-2", "tetra:3-1", "tetra:0-2", "balls:x", ""):
        with pytest.raises(ValueError):
            parse_scaling(bad)
