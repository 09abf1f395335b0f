"""docker-compose.yml and the Dockerfile describe a cluster that can work: every node service
runs a `meshnode serve` its own parser accepts, on the port and cluster id the host's cluster
file and defaults expect, and serves one render so `docker compose up` ends; the host service
is built, waits for the nodes, and its command parses with the real host CLI and renders a
scene that is inside the image; `docker-compose config` (Debian's docker-compose parses and
validates without a daemon) accepts the file. (Docker itself cannot run here; this checks
what can be checked without it.)"""

import json
import os
import shutil
import subprocess
from pathlib import Path

import pytest
import yaml

from host.cli import _parser
from host.run.cluster import read_cluster
from meshnode.service.cli import parse as parse_node

ROOT = Path(__file__).resolve().parents[1]
COMPOSE_FILE = ROOT / "docker-compose.yml"  # a name, so the tests that read it are not `spawn`


def compose() -> dict:
    return yaml.safe_load(COMPOSE_FILE.read_text())


def test_node_services_serve_where_the_host_looks_for_them():
    services = compose()["services"]
    host = services.pop("host")
    host_args = _parser().parse_args(host["command"][1:])
    rows, cols, addresses = read_cluster(ROOT / host_args.cluster)
    assert len(addresses) == rows * cols == len(services)
    for address in addresses:
        name, port = address.rsplit(":", 1)
        node = parse_node(services[name]["command"][1:])  # the node's own parser accepts it
        assert node.command == "serve"
        assert node.listen.rsplit(":", 1)[1] == port
        assert node.cluster == "meshtrace"  # the host's default cluster id
        assert node.once  # it exits when the host's render is done: compose up ends
        assert "build" in services[name] or services[name]["image"] == host["image"]
        # Listening beyond loopback, a node needs the cluster secret; the host proves it too.
        assert (
            node.listen.startswith("0.0.0.0")
            and "MESHTRACE_SECRET" in services[name]["environment"]
        )
    assert "MESHTRACE_SECRET" in host["environment"]
    assert set(host["depends_on"]) == set(services)
    assert host["build"] == "." and host["command"][0] in ("host", "meshtrace")
    assert host_args.wait >= 60  # containers start in parallel: the host waits for the nodes


def test_host_service_renders_a_scene_inside_the_image_to_the_mounted_volume():
    host = compose()["services"]["host"]
    args = _parser().parse_args(host["command"][1:])
    assert args.command == "render" and (ROOT / args.scene).is_file()
    recipe = (ROOT / "Dockerfile").read_text()
    assert f"COPY {args.scene.split('/')[0]} " in recipe  # the scene's folder is copied
    mounts = {m.split(":")[1] for m in host["volumes"]}
    assert str(Path(args.output).parent) in mounts
    assert f"/app/{args.cluster}" in mounts


def instructions() -> list[str]:
    """The Dockerfile's instructions, continuation lines joined, comments left out."""
    text = (ROOT / "Dockerfile").read_text()
    lines = [line for line in text.splitlines() if not line.lstrip().startswith("#")]
    return [line for line in "\n".join(lines).replace("\\\n", " ").splitlines() if line]


def test_dockerfile_compiles_every_kernel_variant_and_serves_by_default():
    lines = instructions()
    # By default: the standard python image, and every variant (not the common one only);
    # a build argument narrows the warm-up (tests/test_compose_up.py) or skips it.
    assert "ARG BASE=python:3.11-slim" in lines and "FROM ${BASE}" in lines
    assert "ARG WARMUP=all" in lines
    [run] = [line for line in lines if line.startswith("RUN ") and "meshnode warmup" in line]
    assert '[ "$WARMUP" = all ]; then meshnode warmup;' in " ".join(run.split())
    assert "ENV NUMBA_CACHE_DIR=/opt/meshtrace/kernels" in lines  # found whatever user runs it
    cmd = json.loads([line for line in lines if line.startswith("CMD ")][0][4:])
    node = parse_node(cmd[1:])
    assert cmd[0] == "meshnode" and node.command == "serve"


def test_docker_compose_config_accepts_the_file():
    tool = shutil.which("docker-compose")
    if tool is None:
        if os.environ.get("MESHTRACE_REQUIRE_SCENES") == "1":
            pytest.fail(
                "docker-compose is missing and MESHTRACE_REQUIRE_SCENES=1 (.ci/run "
                "installs it: apt-get install docker-compose)"
            )
        pytest.skip("docker-compose not installed")
    env = {**os.environ, "MESHTRACE_SECRET": "x" * 64}
    r = subprocess.run(
        [tool, "-f", str(ROOT / "docker-compose.yml"), "config"],
        env=env,
        capture_output=True,
        text=True,
        cwd=ROOT,
    )
    assert r.returncode == 0, r.stderr
    resolved = yaml.safe_load(r.stdout)["services"]
    assert set(resolved) == set(compose()["services"])
    assert resolved["host"]["environment"]["MESHTRACE_SECRET"] == "x" * 64
    without = {k: v for k, v in env.items() if k != "MESHTRACE_SECRET"}
    r = subprocess.run(
        [tool, "-f", str(ROOT / "docker-compose.yml"), "config", "-q"],
        env=without,
        capture_output=True,
        text=True,
        cwd=ROOT,
    )
    assert r.returncode != 0 and "set MESHTRACE_SECRET" in r.stderr  # no default secret
    # With the loopback override: every service on the host's network, nothing published.
    files = [
        "-f",
        str(ROOT / "docker-compose.yml"),
        "-f",
        str(ROOT / "docker-compose.loopback.yml"),
    ]
    r = subprocess.run(
        [tool, *files, "config"], env=env, capture_output=True, text=True, cwd=ROOT, timeout=60
    )
    assert r.returncode == 0, r.stderr
    resolved = yaml.safe_load(r.stdout)["services"]
    assert {s["network_mode"] for s in resolved.values()} == {"host"}
    assert not any(s.get("ports") for s in resolved.values())
