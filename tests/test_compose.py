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


def compose() -> dict:
    return yaml.safe_load((ROOT / "docker-compose.yml").read_text())


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
    dockerfile = (ROOT / "Dockerfile").read_text()
    assert f"COPY {args.scene.split('/')[0]} " in dockerfile  # the scene's folder is copied
    mounts = {m.split(":")[1] for m in host["volumes"]}
    assert str(Path(args.output).parent) in mounts
    assert f"/app/{args.cluster}" in mounts


def test_dockerfile_compiles_every_kernel_variant_and_serves_by_default():
    lines = (ROOT / "Dockerfile").read_text().splitlines()
    run = [line for line in lines if line.startswith("RUN ")]
    warmup = [line.split("meshnode warmup", 1)[1] for line in run if "meshnode warmup" in line]
    assert warmup and "--common" not in warmup[0]  # every variant, not the common one only
    assert "ENV NUMBA_CACHE_DIR=" in "\n".join(lines)  # found whatever user runs it
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
