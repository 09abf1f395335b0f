"""`host render` end to end: images, statistics JSON, and clear errors before any work."""

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from host.cli import main
from host.run.framebuffer import Framebuffer, read_pfm, to_srgb8, write_pfm
from meshnode.engine.counters import RAY_COUNTS
from tests.conftest import spd_scene

EXAMPLE = Path(__file__).resolve().parents[1] / "host" / "examples" / "showcase.nff"
STAT_KEYS = RAY_COUNTS


def test_render_writes_png_pfm_and_stats(tmp_path):
    out, stats = tmp_path / "a.png", tmp_path / "s.json"
    code = main(
        [
            "render",
            str(EXAMPLE),
            "-o",
            str(out),
            "--width",
            "48",
            "--height",
            "32",
            "--spp",
            "2",
            "--stats",
            str(stats),
            "--quiet",
            "--mesh",
            "1x1",
        ]
    )
    assert code == 0
    png = np.asarray(Image.open(out))
    assert png.shape == (32, 48, 3)
    img = read_pfm(out.with_suffix(".pfm"))
    assert img.shape == (32, 48, 3)
    np.testing.assert_array_equal(to_srgb8(img), png)  # the PNG is the float image, encoded
    s = json.loads(stats.read_text())
    assert s["rays"]["eye_rays"] == 48 * 32 * 2
    for key in STAT_KEYS:
        assert isinstance(s["rays"][key], int)
    total = sum(
        s["rays"][k] for k in ("eye_rays", "reflected_rays", "refracted_rays", "shadow_rays")
    )
    assert s["total_rays"] == total
    engine = s["engine"]
    assert engine["structure"] in ("grid", "bvh") and engine["structure_reason"]
    if engine["structure"] == "grid":
        for key in ("resolution", "empty_voxels", "object_references", "storage"):
            assert key in engine["grid"]
    else:
        for key in ("inner_nodes", "leaves", "expected_tests", "expected_visits"):
            assert key in engine["bvh"]
    assert engine["structure_bytes"] > 0
    assert engine["kinds_present"] == ["spheres", "triangles", "polygons", "cones"]
    storage = "bvh" if engine["structure"] == "bvh" else engine["grid"]["storage"]
    assert engine["kernel_variant"].endswith("/refraction/" + storage)
    assert s["tests_per_ray"] > 0 and s["steps_per_ray"] >= 0
    assert s["trace_seconds"] > 0 and s["rays_per_second"] > 0


def test_spd_mode_shoots_corner_rays(tmp_path):
    stats = tmp_path / "s.json"
    scene = spd_scene("tetra_s1.nff")
    assert (
        main(
            [
                "render",
                str(scene),
                "--spd",
                "-o",
                str(tmp_path / "t.png"),
                "--stats",
                str(stats),
                "--quiet",
                "--mesh",
                "1x1",
            ]
        )
        == 0
    )
    s = json.loads(stats.read_text())
    assert s["rays"]["eye_rays"] == 513 * 513
    assert s["image"] == {"width": 512, "height": 512, "spd": True, "spp": 1, "depth": 5, "seed": 0}
    assert s["max_depth"] == 5


def test_malformed_scene_fails_with_file_and_line(tmp_path, capsys):
    bad = tmp_path / "bad.nff"
    lines = [
        "v",
        "from 0 0 -5",
        "at 0 0 0",
        "up 0 1 0",
        "angle 45",
        "f 1 1 1 1 0 1 0 1",
        "s 0 0 oops 1",
    ]
    bad.write_text("\n".join(lines) + "\n")
    out = tmp_path / "never.png"
    assert main(["render", str(bad), "-o", str(out), "--quiet"]) == 2
    err = capsys.readouterr().err
    assert f"{bad}:7:" in err
    assert not out.exists()


def test_missing_file_is_a_clear_error(tmp_path, capsys):
    assert main(["render", str(tmp_path / "nope.nff"), "--quiet"]) == 2
    assert "nope.nff" in capsys.readouterr().err


def test_console_script_runs_as_module(tmp_path):
    r = subprocess.run(
        [sys.executable, "-m", "host.cli", "render", "--help"],
        capture_output=True,
        text=True,
        check=True,
    )
    assert "--spd" in r.stdout and "--stats" in r.stdout


def test_framebuffer_resolves_corners_and_samples():
    fb = Framebuffer(2, 1, corners=True)
    fb.add(np.arange(6), np.arange(18, dtype=float).reshape(6, 3))
    # Corners (3 x 2): pixel 0 averages corners 0, 1, 3, 4.
    np.testing.assert_allclose(
        fb.image()[0, 0], np.mean([[0, 1, 2], [3, 4, 5], [9, 10, 11], [12, 13, 14]], axis=0)
    )
    fb = Framebuffer(1, 1, corners=False, spp=4)
    fb.add(np.array([0, 1, 2, 3, 3]), np.ones((5, 3)))
    np.testing.assert_allclose(fb.image()[0, 0], [1.25] * 3)


def test_pfm_round_trip(tmp_path):
    img = np.random.default_rng(0).random((5, 7, 3))
    write_pfm(tmp_path / "x.pfm", img)
    np.testing.assert_allclose(read_pfm(tmp_path / "x.pfm"), img.astype(np.float32))


def test_the_default_plan_on_one_machine_is_one_process_and_says_why(tmp_path, capsys):
    stats = tmp_path / "s.json"
    assert (
        main(
            [
                "render",
                str(EXAMPLE),
                "-o",
                str(tmp_path / "a.png"),
                "--width",
                "16",
                "--height",
                "16",
                "--stats",
                str(stats),
            ]
        )
        == 0
    )
    plan = json.loads(stats.read_text())["plan"]
    assert plan["choice"] == "one process" and "one machine" in plan["why"]
    first = capsys.readouterr().err.strip().splitlines()[0]
    assert first.startswith("host: plan: one process")


@pytest.mark.parametrize("cached", [False, True])
def test_a_first_run_says_kernels_compile_before_the_progress_starts(
    tmp_path, capsys, monkeypatch, cached
):
    from meshnode.engine import kernelcache

    monkeypatch.setattr(kernelcache, "is_warm", lambda name: cached)
    assert (
        main(
            ["render", str(EXAMPLE), "-o", str(tmp_path / "a.png"), "--width", "8", "--height", "8"]
        )
        == 0
    )
    lines = capsys.readouterr().err.splitlines()
    said = [line for line in lines if "compiling kernels" in line]
    if cached:
        assert not said
    else:
        # the hierarchy foreseen; said again if "auto" takes the grid for so few rays
        assert said[0].startswith("host: compiling kernels for spheres+")
        assert said[0].endswith(
            "/shadows/refraction/bvh, first run only: the structure build, the primary rays, "
            "the tracing kernel"
        )
        assert said[1:] in (
            [],
            [said[0].split(",")[0][:-3] + "grid instead (the structure chosen)"],
        )
        assert lines.index(said[0]) < min(i for i, x in enumerate(lines) if "tracing:" in x)
    assert (
        main(
            [
                "render",
                str(EXAMPLE),
                "-o",
                str(tmp_path / "b.png"),
                "--width",
                "8",
                "--height",
                "8",
                "--quiet",
            ]
        )
        == 0
    )
    assert capsys.readouterr().err == ""


def test_a_mesh_render_waits_for_its_nodes_before_counting_progress(tmp_path, capsys):
    assert (
        main(
            [
                "render",
                str(EXAMPLE),
                "--mesh",
                "1x2",
                "-o",
                str(tmp_path / "a.png"),
                "--width",
                "16",
                "--height",
                "16",
            ]
        )
        == 0
    )
    err = capsys.readouterr().err
    waiting = err.index("mesh 1x2: waiting for the nodes")
    assert waiting < err.index("mesh 1x2 primary:")  # the bar restarts once all are ready
    assert "Traceback" not in err


@pytest.mark.parametrize(
    "flags,what",
    [
        (["-o", "{tmp}/missing/a.png"], "no folder"),
        (["-o", "{tmp}/a.jpgg"], "writes .png or .exr images, not '.jpgg'"),
        (["-o", "{tmp}/a"], "not 'a name without a suffix'"),
        (["-o", "{tmp}/a.png", "--float", "{tmp}/a.tiff"], "writes .pfm or .exr images"),
        (["-o", "{tmp}/missing/a.exr"], "no folder"),
        (["-o", "{tmp}/a.png", "--stats", "{tmp}/nowhere/s.json"], "no folder"),
    ],
)
def test_bad_output_paths_fail_before_any_work(tmp_path, capsys, flags, what):
    argv = ["render", str(EXAMPLE), "--quiet", *[f.format(tmp=tmp_path) for f in flags]]
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert what in err and "Traceback" not in err
    assert not [p for p in tmp_path.rglob("*") if p.is_file()]  # nothing written


def test_exr_output_holds_the_linear_image_of_the_pfm(tmp_path):
    import OpenEXR

    small = ["--width", "12", "--height", "8", "--quiet"]
    assert main(["render", str(EXAMPLE), "-o", str(tmp_path / "a.exr"), *small]) == 0
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.exr"]  # the float image itself
    assert (
        main(
            [
                "render",
                str(EXAMPLE),
                "-o",
                str(tmp_path / "b.png"),
                "--float",
                str(tmp_path / "b.exr"),
                *small,
            ]
        )
        == 0
    )
    assert main(["render", str(EXAMPLE), "-o", str(tmp_path / "c.png"), *small]) == 0
    reference = read_pfm(tmp_path / "c.pfm")
    assert reference.shape == (8, 12, 3) and reference.max() > 0
    for name in ("a.exr", "b.exr"):
        with OpenEXR.File(str(tmp_path / name)) as f:
            rgb = f.channels()["RGB"].pixels
        np.testing.assert_array_equal(rgb, reference.astype(np.float32))


def test_exr_without_its_library_is_refused_before_any_work(tmp_path, capsys, monkeypatch):
    monkeypatch.setitem(sys.modules, "OpenEXR", None)  # import OpenEXR now fails
    assert main(["render", str(EXAMPLE), "-o", str(tmp_path / "a.exr")]) == 2
    err = capsys.readouterr().err
    assert (
        err == f"host: -o {tmp_path / 'a.exr'}: writing .exr needs the OpenEXR package "
        "(pip install OpenEXR)\n"
    )
    assert not list(tmp_path.iterdir())


def test_a_cluster_node_that_never_comes_up_is_named_after_the_wait(tmp_path, capsys):
    import socket

    with socket.socket() as s:  # a port nothing listens on once closed
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    cluster = tmp_path / "cluster.txt"
    cluster.write_text(f"0 0 127.0.0.1:{port}\n")
    assert (
        main(
            [
                "render",
                str(EXAMPLE),
                "--cluster",
                str(cluster),
                "--wait",
                "1.5",
                "-o",
                str(tmp_path / "a.png"),
                "--quiet",
            ]
        )
        == 1
    )
    err = capsys.readouterr().err.splitlines()
    assert len(err) == 1 and f"node 0 (127.0.0.1:{port})" in err[0]
    assert f"cannot connect to 127.0.0.1:{port} within 1.5 s" in err[0]


def test_camera_json_is_strict_json_even_focused_at_infinity(capsys):
    cameras = Path(__file__).resolve().parents[1] / "host" / "cameras"
    assert main(["camera", str(cameras / "thin_f2.8.toml"), "--json", "--focus", "inf"]) == 0
    d = json.loads(capsys.readouterr().out, parse_constant=lambda c: pytest.fail(c))
    assert d["focus_distance_m"] == "infinity" and d["effective_focal_length_m"] > 0


def test_meshtrace_is_a_second_name_for_the_host_commands():
    import tomllib

    root = Path(__file__).resolve().parents[1]
    scripts = tomllib.loads((root / "pyproject.toml").read_text())["project"]["scripts"]
    assert scripts["meshtrace"] == scripts["host"] == "host.cli:main"
    r = subprocess.run(
        [
            sys.executable,
            "-c",
            "import sys; from host.cli import main; "
            "sys.argv[0] = '/usr/local/bin/meshtrace'; main(['--version'])",
        ],
        capture_output=True,
        text=True,
    )
    assert r.stdout.startswith("meshtrace "), r.stderr


def test_version_and_a_closed_pipe_are_quiet(monkeypatch):
    r = subprocess.run(
        [sys.executable, "-m", "host.cli", "--version"], capture_output=True, text=True, check=True
    )
    assert r.stdout.startswith("host ")

    class ClosedPipe:  # what stdout is once `| head` has read enough and left
        def write(self, text):
            raise BrokenPipeError(32, "Broken pipe")

        def flush(self):
            raise BrokenPipeError(32, "Broken pipe")

        def fileno(self):
            return os.open(os.devnull, os.O_WRONLY)

    cameras = Path(__file__).resolve().parents[1] / "host" / "cameras"
    monkeypatch.setattr(sys, "stdout", ClosedPipe())
    assert main(["camera", str(cameras / "thin_f2.8.toml")]) == 0


def test_overlap_auto_renders_at_the_overlap_the_pre_pass_chose(tmp_path, capsys, monkeypatch):
    from host.planning import allowance
    from host.planning.holding import OVERLAPS

    # every overlap simulated: a 24x24 render affords none past the first (its allowance)
    monkeypatch.setattr(allowance, "PREPASS_SHARE", float("inf"))

    stats = tmp_path / "s.json"
    assert (
        main(
            [
                "render",
                str(EXAMPLE),
                "--mesh",
                "1x2",
                "--mode",
                "object",
                "--overlap",
                "auto",
                "--balance",
                "cost",
                "--width",
                "24",
                "--height",
                "24",
                "--quiet",
                "-o",
                str(tmp_path / "a.png"),
                "--stats",
                str(stats),
            ]
        )
        == 0
    )
    got = json.loads(stats.read_text())
    chosen = got["balance"]["overlap"]["chosen"]
    assert chosen in OVERLAPS and got["mesh"]["overlap"] == chosen  # what the nodes ran
    assert sorted(got["balance"]["overlap"]["simulated_busiest_vs_chosen"]) == sorted(
        f"{o:g}" for o in OVERLAPS
    )
    with pytest.raises(SystemExit) as bad:
        main(["render", str(EXAMPLE), "--mesh", "2x2", "--overlap", "wide"])
    assert bad.value.code == 2
    assert "'wide' is neither a percentage nor auto" in capsys.readouterr().err


def test_copies_render_on_a_mesh_where_each_node_holds_the_others_objects(tmp_path):
    stats = tmp_path / "s.json"
    assert (
        main(
            [
                "render",
                str(EXAMPLE),
                "--mesh",
                "1x2",
                "--copies",
                "--steal",
                "--width",
                "24",
                "--height",
                "24",
                "--quiet",
                "-o",
                str(tmp_path / "a.png"),
                "--stats",
                str(stats),
            ]
        )
        == 0
    )
    got = json.loads(stats.read_text())
    assert got["mesh"]["copies"] is True and got["mesh"]["mode"] == "object"
    own = got["objects_per_node"]
    assert got["objects_held_per_node"] == [own[0] + own[1]] * 2  # each holds both boxes
    assert got["rays_passed"] == 0  # the only neighbour's rays are traced with its copy
