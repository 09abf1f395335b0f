"""`docker compose up` for real: the Dockerfile builds, the compose file's 2x2 mesh comes up,
renders, and its image equals one process's, bit for bit.

The public image registry may be out of reach (it is on CI), so the base image is made from
Debian's packages: `debootstrap --variant=minbase` with python3 (3.11 in bookworm) and
python3-venv, imported with `docker import` and kept under a tag named after what went into it
(built once per machine, reused after). It is passed to the Dockerfile as BASE; WARMUP limits
the build's kernel warm-up to the one variant the scene needs (every variant takes minutes).
The mesh runs with docker-compose.loopback.yml (host networking, each node on its own port of
127.0.0.1: nothing leaves the machine) and a file of this test's own that names the image, the
scene, the size and the output folder. The nodes work in object space, so rays cross between
the containers, and load their kernels from the image: none compiles.

pip inside the build reaches its index as pip here does: a CA bundle pip is told to trust
(behind a TLS-inspecting proxy) goes into the base image, an http(s) index URL and the proxy
variables are passed on, and the build uses the host's network.

Docker, a compose (`docker compose` or Debian's `docker-compose`), debootstrap and root are
needed; without them the test skips, or fails when MESHTRACE_REQUIRE_DOCKER=1 (.ci/run
installs them and starts dockerd).
"""

import functools
import hashlib
import json
import os
import re
import secrets
import shlex
import shutil
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import pytest
import yaml
from PIL import Image

from host.cli import _parser, main
from host.run.cluster import read_cluster
from host.run.framebuffer import read_pfm
from meshnode.engine.counters import RAY_COUNTS
from tests.conftest import spd_scene

ROOT = Path(__file__).resolve().parents[1]
COMPOSE_FILES = [ROOT / "docker-compose.yml", ROOT / "docker-compose.loopback.yml"]
SUITE = "bookworm"  # its python3 is 3.11, the version the project is built for
PACKAGES = ("python3", "python3-venv", "ca-certificates")
MIRROR = os.environ.get("MESHTRACE_DEBIAN_MIRROR", "http://deb.debian.org/debian")
IMAGE = "meshtrace:compose-test"
PROJECT = "meshtrace-compose-test"
SCENE, SIZE = "gears_s1.nff", 40  # as tests/test_mesh_service.py renders it on a 2x2
CA_IN_IMAGE = "/etc/ssl/certs/ca-certificates.crt"  # Debian's system bundle
PROXIES = ("HTTP_PROXY", "HTTPS_PROXY", "NO_PROXY", "http_proxy", "https_proxy", "no_proxy")


def _run(cmd, timeout: float, **kw) -> subprocess.CompletedProcess:
    return subprocess.run(cmd, capture_output=True, text=True, timeout=timeout, **kw)


def compose_command() -> list[str] | None:
    """`docker compose` (the plugin) if there is one, else `docker-compose` (Debian
    bookworm packages only this, version 1)."""
    if shutil.which("docker"):
        try:
            if _run(["docker", "compose", "version"], 30).returncode == 0:
                return ["docker", "compose"]
        except subprocess.TimeoutExpired:
            pass
    tool = shutil.which("docker-compose")
    return [tool] if tool else None


def missing() -> str | None:
    """Why this machine cannot run the test, or None."""
    if shutil.which("docker") is None:
        return "no docker command (apt-get install docker.io)"
    try:
        info = _run(["docker", "info", "--format", "{{.ServerVersion}}"], 30)
    except subprocess.TimeoutExpired:
        return "the Docker daemon does not answer"
    if info.returncode != 0:
        return f"no Docker daemon: {info.stderr.strip()[:200]}"
    if compose_command() is None:
        return "no docker compose nor docker-compose (apt-get install docker-compose)"
    if _image_exists(base_tag()):
        return None
    if shutil.which("debootstrap") is None:
        return "no debootstrap to make the base image (apt-get install debootstrap)"
    if os.geteuid() != 0:
        return "debootstrap needs root to make the base image"
    return None


@pytest.fixture(scope="module")
def docker_ready():
    reason = missing()
    if reason is not None:
        if os.environ.get("MESHTRACE_REQUIRE_DOCKER") == "1":
            pytest.fail(f"{reason}, and MESHTRACE_REQUIRE_DOCKER=1")
        pytest.skip(reason)


@functools.cache
def pip_settings() -> dict[str, str]:
    """pip's cert, index-url and extra-index-url here: its environment variables, else its
    configuration files."""
    found = {}
    listed = _run([sys.executable, "-m", "pip", "config", "list"], 60).stdout
    for line in listed.splitlines():
        m = re.match(r"^[\w:.-]*?\.(cert|index-url|extra-index-url)='(.*)'$", line)
        if m:
            found.setdefault(m.group(1), m.group(2))
    for key in ("cert", "index-url", "extra-index-url"):
        value = os.environ.get("PIP_" + key.upper().replace("-", "_"))
        if value:
            found[key] = value
    return found


def ca_bundle() -> Path | None:
    """The CA bundle pip here is told to trust, if any: the base image trusts it too."""
    cert = pip_settings().get("cert")
    return Path(cert) if cert and Path(cert).is_file() else None


def base_tag() -> str:
    """The base image's tag, named after the suite, packages and CA bundle that make it."""
    digest = hashlib.sha256(f"{SUITE} {' '.join(PACKAGES)} {MIRROR}".encode())
    bundle = ca_bundle()
    if bundle is not None:
        digest.update(bundle.read_bytes())
    return f"meshtrace-base:{SUITE}-{digest.hexdigest()[:12]}"


def _image_exists(tag: str) -> bool:
    return _run(["docker", "image", "inspect", tag], 60).returncode == 0


def _mounts_under(root: Path) -> list[str]:
    text = Path("/proc/mounts").read_text() if Path("/proc/mounts").exists() else ""
    return [line.split()[1] for line in text.splitlines() if line.split()[1].startswith(str(root))]


def base_image() -> tuple[str, float]:
    """The Debian base image (its tag, and the seconds spent making it: 0 when cached)."""
    tag = base_tag()
    if _image_exists(tag):
        return tag, 0.0
    start = time.perf_counter()
    work = Path(tempfile.mkdtemp(prefix="meshtrace-debootstrap-"))
    root = work / "root"
    try:
        r = _run(
            ["debootstrap", "--variant=minbase", "--include=" + ",".join(PACKAGES), SUITE]
            + [str(root), MIRROR],
            1200,
        )
        assert r.returncode == 0, f"debootstrap failed:\n{r.stdout[-3000:]}\n{r.stderr[-3000:]}"
        bundle = ca_bundle()
        if bundle is not None:
            shutil.copyfile(bundle, root / CA_IN_IMAGE.lstrip("/"))
        r = _run(
            [
                "bash",
                "-o",
                "pipefail",
                "-c",
                f"tar -C {shlex.quote(str(root))} -c . "
                f"| docker import -c 'ENV LANG=C.UTF-8' - {shlex.quote(tag)}",
            ],
            600,
        )
        assert r.returncode == 0, f"docker import failed: {r.stderr[-3000:]}"
    finally:
        # Never delete through a mount debootstrap left behind (it may bind /dev).
        left = _mounts_under(work)
        if left:
            subprocess.run(["umount", "-R", "-l", *reversed(left)], timeout=60, check=False)
        if not _mounts_under(work):
            subprocess.run(["rm", "-rf", "--one-file-system", str(work)], timeout=300, check=False)
    return tag, time.perf_counter() - start


def build_args(base: str, variant: str) -> list[str]:
    """The build's arguments: the base, the warm-up, and how pip reaches its index here."""
    args = {"BASE": base, "WARMUP": variant}
    settings = pip_settings()
    if ca_bundle() is not None:
        args["PIP_CERT"] = CA_IN_IMAGE  # the bundle base_image put there
    for key in ("index-url", "extra-index-url"):
        urls = [u for u in settings.get(key, "").split() if u.startswith(("http://", "https://"))]
        if urls:  # a file:// index is on this machine's disk, not in the build
            args["PIP_" + key.upper().replace("-", "_")] = " ".join(urls)
    out = [f"--build-arg={k}={v}" for k, v in args.items()]
    # Docker's predefined proxy arguments: given by name, the value comes from the environment
    return out + [f"--build-arg={name}" for name in PROXIES if os.environ.get(name)]


def test_the_loopback_override_keeps_every_node_on_its_own_loopback_port():
    base, override = (yaml.safe_load(f.read_text())["services"] for f in COMPOSE_FILES)
    assert set(override) == set(base)
    assert all(s["network_mode"] == "host" for s in override.values())
    host = override["host"]
    cluster = _parser().parse_args(host["command"][1:]).cluster
    assert f"./{cluster}:/app/{cluster}:ro" in host["volumes"]
    rows, cols, addresses = read_cluster(ROOT / cluster)
    assert rows == cols == 2
    listens = [override[f"node{r}{c}"]["command"] for r in range(2) for c in range(2)]
    assert [cmd[cmd.index("--listen") + 1] for cmd in listens] == addresses
    assert all(a.startswith("127.0.0.1:") for a in addresses) and len(set(addresses)) == 4


def _free(address: str) -> bool:
    host, port = address.rsplit(":", 1)
    with socket.socket() as s:
        s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)  # as the nodes bind
        try:
            s.bind((host, int(port)))
        except OSError:
            return False
    return True


@pytest.mark.slow
def test_compose_up_renders_the_one_process_image(docker_ready, tmp_path):
    scene = spd_scene(SCENE).resolve()
    size = ["--width", str(SIZE), "--height", str(SIZE)]
    one = tmp_path / "one"
    one.mkdir()
    assert (
        main(
            ["render", str(scene), "--mesh", "1x1", *size, "--quiet"]
            + ["-o", str(one / "image.png"), "--stats", str(one / "stats.json")]
        )
        == 0
    )
    ref_stats = json.loads((one / "stats.json").read_text())
    # What the nodes will need too, under either structure (each node chooses its own)
    kinds = ref_stats["engine"]["kernel_variant"].rsplit("/", 1)[0]
    variant = f"{kinds}/grid,{kinds}/bvh"

    base, base_seconds = base_image()
    start = time.perf_counter()
    r = _run(
        [
            "docker",
            "build",
            "--force-rm",
            "--network",
            "host",
            *build_args(base, variant),
            "-t",
            IMAGE,
        ]
        + [str(ROOT)],
        1800,
    )
    build_seconds = time.perf_counter() - start
    assert r.returncode == 0, f"docker build failed:\n{r.stdout[-4000:]}\n{r.stderr[-4000:]}"

    _, _, addresses = read_cluster(ROOT / "cluster-loopback.txt")
    busy = [a for a in addresses if not _free(a)]
    assert not busy, f"the loopback ports the override uses are taken: {busy}"
    out = tmp_path / "out"
    out.mkdir()
    mine = {name: {"image": IMAGE} for name in ("node00", "node01", "node10", "node11")}
    mine["host"] = {
        "image": IMAGE,
        "volumes": [f"{out}:/out", f"{scene}:/scene/{SCENE}:ro"],
        "command": ["meshtrace", "render", f"/scene/{SCENE}", *size]
        + ["--cluster", "cluster-loopback.txt", "--wait", "120", "--mode", "object"]
        + ["--overlap", "24", "-o", "/out/image.png", "--stats", "/out/stats.json"],
    }
    (tmp_path / "test.yml").write_text(yaml.safe_dump({"services": mine}))
    compose = compose_command() + ["-p", PROJECT]
    for path in COMPOSE_FILES:
        compose += ["-f", str(path)]
    compose += ["-f", str(tmp_path / "test.yml")]
    env = {**os.environ, "MESHTRACE_SECRET": secrets.token_hex(32)}
    start = time.perf_counter()
    try:
        up = _run(compose + ["up", "--no-build", "--exit-code-from", "host"], 600, env=env)
    finally:
        down = _run(compose + ["down", "--remove-orphans", "--timeout", "10"], 300, env=env)
    up_seconds = time.perf_counter() - start
    assert up.returncode == 0, f"compose up failed:\n{up.stdout[-6000:]}\n{up.stderr[-3000:]}"
    assert down.returncode == 0, down.stderr

    # The mesh's image is one process's, bit for bit: the 8-bit PNG and the float PFM.
    png = [np.asarray(Image.open(d / "image.png")) for d in (one, out)]
    assert png[0].shape == (SIZE, SIZE, 3) and np.array_equal(png[0], png[1])
    pfm = [read_pfm(d / "image.pfm") for d in (one, out)]
    assert np.array_equal(pfm[0], pfm[1])
    stats = json.loads((out / "stats.json").read_text())
    assert {k: stats["rays"][k] for k in RAY_COUNTS} == {
        k: ref_stats["rays"][k] for k in RAY_COUNTS
    }
    # Four containers in object space, passing rays across the torus; none lost.
    assert stats["mode"]["choice"] == "object" and stats["rays_passed"] > 0
    assert stats["addresses"] == addresses and stats["lost_nodes"] == []
    # Every node loaded the image's kernels: the build's warm-up served them.
    assert [n["engine"]["kernel_variant"].rsplit("/", 1)[0] for n in stats["nodes"]] == [kinds] * 4
    assert [n["compile_seconds"] for n in stats["nodes"]] == [0] * 4, up.stdout[-3000:]
    print(
        f"compose test: base image {base_seconds:.0f} s (0: cached), build {build_seconds:.0f} s, "
        f"up to down {up_seconds:.0f} s (host wall {stats['wall_seconds']:.1f} s)"
    )
