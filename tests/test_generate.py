"""The generated SPD scenes against the SPD's own files: every generator against every file of
the shared scenes folder (record for record, after rounding as the SPD prints), the SPD's object
counts at every size factor, NFF written back, and the data shipped for a clone without the
shared folder (lens tables, the published ray counts) against the originals.

The comparisons with the shared folder are the only tests that skip without it (or fail when
MESHTRACE_REQUIRE_SCENES=1, as in CI)."""

import re

import numpy as np
import pytest

from bench import read_scene
from bench.generate import (
    DEFAULT_SIZES,
    GENERATORS,
    balls,
    balls_count,
    gears_count,
    spd,
    tetra,
    tetra_count,
    write_nff,
)
from bench.generate.jacks import jacks_count
from bench.generate.lattice import lattice_count
from bench.generate.mount import mount
from bench.generate.nffwrite import nff_text
from bench.generate.records import printed
from bench.generate.rings import rings_count
from bench.generate.shells import shells_count
from bench.generate.sombrero import sombrero_count
from bench.generate.tree import tree_count
from bench.spd import parse_scaling
from bench.spd_published import parse_published
from host.camera.lensfile import read_camera
from host.scene.nff import parse_nff, read_nff
from protocols.scene import OBJECT_KINDS
from tests.conftest import SCENES, SHIPPED, shared_file, shared_lenses
from tests.test_lens_files import SHIPPED as LENS_FILES

# The SPD files of the shared folder (README.md lists them), each checked against its generator.
SPD_FILES = (
    *(f"tetra_s{k}" for k in range(1, 6)),
    "tetra",
    *(f"balls_s{k}" for k in range(1, 4)),
    "balls",
    "gears_s1",
    "gears",
    "jacks",
    "mount_s1",
    "rings_s1",
    "rings",
    "shells",
    "teapot_s1",
    "teapot",
    "tree_s1",
    "tree",
)
# Where the exact value is 0 the SPD prints its own rounding noise (balls: 1.11022e-16).
NOISE = 1e-12


def assert_same_records(made, read, tol: float = 0.0) -> None:
    """Every record of `made` as `read` has it: same kinds in the same order, integers equal,
    numbers within `tol` of `read`'s magnitude (0: equal but for the noise about 0)."""
    for kind in ("lights", "materials", *OBJECT_KINDS):
        a, b = getattr(made, kind), getattr(read, kind)
        assert len(a) == len(b), kind
        for name in a.dtype.names:
            if a[name].dtype.kind == "f":
                assert np.allclose(a[name], b[name], rtol=tol, atol=NOISE), (kind, name)
            else:
                assert np.array_equal(a[name], b[name]), (kind, name)
    assert np.allclose(made.vertices, read.vertices, rtol=tol, atol=NOISE)


def shared_scene(stem: str):
    """The shared folder's SPD file, read (skipped or failed without it)."""
    return read_nff(shared_file(SCENES / f"{stem}.nff"))


def same_as_printed(stem: str, read) -> None:
    """Rounded as the SPD prints, the generated scene is the file's: view, background, lights,
    materials and every object in order, normals and polygon tables included."""
    made = spd(stem, printed=True)
    assert made.view == read.view and made.background == read.background
    assert_same_records(made, read)


def same_numbers(stem: str, read) -> None:
    """Unrounded, every number the file states is the generated one to the file's six
    significant digits (half a unit of the sixth digit); normals follow the vertices."""
    made = spd(stem)
    for kind, fields in (
        ("spheres", ("center", "radius")),
        ("cones", ("base", "base_r", "apex", "apex_r")),
        ("triangles", ("v",)),
    ):
        for name in fields:
            a, b = getattr(made, kind)[name], getattr(read, kind)[name]
            assert np.allclose(b, a, rtol=5.000001e-6, atol=NOISE), (kind, name)
    assert np.allclose(read.vertices, made.vertices, rtol=5.000001e-6, atol=NOISE)


def test_generated_scenes_are_the_spd_files():
    """Every generator against every SPD file of the shared folder, both ways: one test, so
    a clone without the folder skips it once (issue 39: at most 10 skips), and a failure
    names every file that differs."""
    shared_file(SCENES / "tetra.nff")  # skipped, or failed when the folder is required
    differ = {}
    for stem in SPD_FILES:
        read = shared_scene(stem)
        for check in (same_as_printed, same_numbers):
            try:
                check(stem, read)
            except AssertionError as e:
                differ[f"{stem} ({check.__name__})"] = str(e)[:200]
    assert not differ, differ


def test_every_spd_file_of_the_shared_folder_has_its_generator_and_is_checked():
    stems = {p.stem for p in SCENES.glob("*.nff")}
    if not stems:
        shared_file(SCENES / "tetra.nff")  # skipped, or failed when the folder is required
    assert stems <= set(SPD_FILES), sorted(stems - set(SPD_FILES))
    assert all(re.sub(r"_s\d+$", "", s) in GENERATORS for s in stems)


# ---------------------------------------------------------------------------- shipped data


def test_shipped_published_counts_are_the_shared_readmes():
    ours = parse_published((SHIPPED / "spd" / "README.md").read_text())
    assert ours == parse_published(shared_file(SCENES / "README.md").read_text())
    assert set(ours) == {"balls", "gears", "rings", "teapot", "tetra", "tree"}


def test_shipped_lens_tables_are_the_shared_ones():
    """The same rows, number for number, and so the same lens."""

    def rows(path):
        lines = (ln.split("#", 1)[0].split() for ln in path.read_text().splitlines())
        return [[float(w) for w in words] for words in lines if words]

    for name in LENS_FILES:
        shared = shared_file(shared_lenses() / name)
        ours = SHIPPED / "lenses" / name
        assert rows(ours) == rows(shared), name
        np.testing.assert_array_equal(
            read_camera(ours).elements, read_camera(shared).elements, err_msg=name
        )


# ---------------------------------------------------------------------------- the generators


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


@pytest.mark.parametrize(
    "name,count,sizes",
    [
        ("gears", gears_count, (1, 2, 3)),
        ("jacks", jacks_count, (1, 2, 3)),
        ("lattice", lattice_count, (1, 2, 5)),
        ("rings", rings_count, (1, 2, 3)),
        ("shells", shells_count, (1, 2)),
        ("sombrero", sombrero_count, (1, 2)),
        ("tree", tree_count, (1, 2, 6)),
    ],
)
def test_object_counts_follow_the_spd_programs_formulas(name, count, sizes):
    """The counts the SPD programs' headers give (gears: SF^3 gears of 2 faces and 4 x 36
    sides; tree: 2^(SF+1) - 1 branches; ...), and gids numbering the objects 0, 1, ..."""
    for n in sizes:
        scene = GENERATORS[name](n)
        assert scene.n_objects == count(n), (name, n)
        gids = np.concatenate([getattr(scene, k)["gid"] for k in OBJECT_KINDS])
        assert np.array_equal(np.unique(gids), np.arange(count(n)))


def test_teapot_has_64_n_squared_less_8_n_triangles_past_size_1():
    for n in (2, 3):
        scene = spd(f"teapot_s{n}")
        smooth = scene.triangles[scene.triangles["smooth"] == 1]
        assert len(np.unique(smooth["gid"])) == 64 * n * n - 8 * n  # the SPD's own count
        assert len(scene.polygons) == n * n  # the checkerboard


@pytest.mark.parametrize("name", sorted(set(GENERATORS) - {"teapot"}))
def test_counts_table_gives_each_generators_objects(name):
    from bench.generate import COUNTS

    for n in (1, 2):
        assert GENERATORS[name](n).n_objects == COUNTS[name](n), (name, n)


def test_mount_is_a_deterministic_landscape_of_2_4_to_the_n_triangles():
    a, b = mount(3), mount(3)
    assert len(a.triangles) == 2 * 4**3 and len(a.spheres) == 4
    np.testing.assert_array_equal(a.triangles["v"], b.triangles["v"])
    # Corners shared by neighbouring squares get one height: the seeds follow grid points.
    v = a.triangles["v"].reshape(-1, 3)
    _, inverse = np.unique(v[:, :2], axis=0, return_inverse=True)
    heights = np.zeros(inverse.max() + 1)
    heights[inverse] = v[:, 2]
    np.testing.assert_array_equal(heights[inverse], v[:, 2])


def test_spd_names_sizes_and_refuses_unknown_ones():
    assert spd("tetra_s2").n_objects == tetra(2).n_objects == 16
    assert spd("gears.nff").n_objects == gears_count(DEFAULT_SIZES["gears"]) == 9345
    for bad in ("cube", "tetra_2", "tetra_sx", ""):
        with pytest.raises(ValueError, match="no SPD generator"):
            spd(bad)


def test_benchmarks_read_a_scene_file_first_and_generate_an_spd_name_without_one(tmp_path):
    """`bench.read_scene`: a file in the folder is read even where a generator has its name;
    without one an SPD name is generated as the SPD prints it; any other name is refused,
    naming the file looked for."""
    write_nff(tetra(1), tmp_path / "tetra_s2.nff")
    assert read_scene(tmp_path, "tetra_s2").n_objects == 4  # the file's, not size 2's 16
    assert_same_records(read_scene(tmp_path, "mount_s2"), spd("mount_s2", printed=True))
    with pytest.raises(FileNotFoundError, match=r"cube\.nff: no such scene file.*no SPD"):
        read_scene(tmp_path, "cube")


def test_printed_rounds_as_printf_g():
    np.testing.assert_array_equal(
        printed([1.0228459, -0.0041034, 100000.0, 1234567.0, 1.11022302e-16]),
        [1.02285, -0.0041034, 100000.0, 1.23457e6, 1.11022e-16],
    )


# ---------------------------------------------------------------------------- NFF written back


@pytest.mark.parametrize("name", sorted(GENERATORS))
def test_written_nff_reads_back_as_the_same_scene(name, tmp_path):
    """Bit for bit, but for smooth normals (the reader normalises them again: an ulp)."""
    made = spd(f"{name}_s2", printed=True)
    read = read_nff(write_nff(made, tmp_path / f"{name}.nff"))
    assert read.view == made.view and read.background == made.background
    for kind in ("lights", "materials", *OBJECT_KINDS):
        a, b = getattr(made, kind), getattr(read, kind)
        for field in a.dtype.names:
            if kind == "triangles" and field == "n":
                np.testing.assert_allclose(b[field], a[field], rtol=0, atol=1e-15)
            else:
                np.testing.assert_array_equal(b[field], a[field], err_msg=f"{kind}.{field}")
    np.testing.assert_array_equal(read.vertices, made.vertices)


def test_written_nff_repeats_a_material_when_objects_do_not_follow_the_table():
    from tests.conftest import make_scene

    scene = make_scene(
        spheres=[((0, 0, 0), 1.0, 1), ((3, 0, 0), 1.0, 0), ((6, 0, 0), 1.0, 1)],
        polygons=[([(0, 0, 5), (1, 0, 5), (1, 1, 5), (0, 1, 5)], 0)],
        lights=[(5, 5, 5)],
        materials=[((1, 0, 0), 1, 0, 1, 0, 1), ((0, 1, 0), 1, 0, 1, 0, 1)],
    )
    read = parse_nff(nff_text(scene))
    assert read.n_objects == 4
    for kind in ("spheres", "polygons"):
        np.testing.assert_array_equal(
            read.materials[getattr(read, kind)["mat"]], scene.materials[getattr(scene, kind)["mat"]]
        )


def test_scaling_option():
    assert parse_scaling("tetra:1-3, balls:2") == [("tetra", [1, 2, 3]), ("balls", [2])]
    for bad in ("cube:1-2", "tetra:3-1", "tetra:0-2", "balls:x", ""):
        with pytest.raises(ValueError):
            parse_scaling(bad)
