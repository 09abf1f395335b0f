"""The Kubernetes manifests in deploy/ are valid (kubernetes-validate, strict, against the
newest schemas it ships) and describe a mesh that can work: the StatefulSet has rows x cols
replicas behind the headless Service the cluster file names, every container command parses
with the real CLIs, nodes and host share the secret, and the image lands on a volume. The
cluster-file command writes what `--cluster` reads, one stable pod name per node."""

from pathlib import Path

import kubernetes_validate
import pytest
import yaml
from kubernetes_validate.utils import latest_version

from host.cli import _parser, main
from host.run.cluster import read_cluster
from meshnode.service.cli import parse as parse_node

ROOT = Path(__file__).resolve().parents[1]
DEPLOY = ROOT / "deploy"


def resources() -> dict[str, dict]:
    """Every resource the kustomization applies, by kind."""
    listed = yaml.safe_load((DEPLOY / "kustomization.yaml").read_text())["resources"]
    docs = [d for name in listed for d in yaml.safe_load_all((DEPLOY / name).read_text()) if d]
    return {d["kind"]: d for d in docs}


def test_every_manifest_is_applied_and_valid():
    listed = yaml.safe_load((DEPLOY / "kustomization.yaml").read_text())["resources"]
    on_disk = {p.name for p in DEPLOY.glob("*.yaml")} - {"kustomization.yaml"}
    assert set(listed) == on_disk
    kinds = []
    for name in listed:
        for doc in yaml.safe_load_all((DEPLOY / name).read_text()):
            kubernetes_validate.validate(doc, latest_version(), strict=True)  # raises if not
            kinds.append(doc["kind"])
    assert sorted(kinds) == ["Job", "PersistentVolumeClaim", "Service", "StatefulSet"]


def test_an_invalid_manifest_is_caught():
    bad = resources()["StatefulSet"]
    bad["spec"]["replicas"] = "four"
    with pytest.raises(kubernetes_validate.ValidationError):
        kubernetes_validate.validate(bad, latest_version(), strict=True)


def _secret(container) -> tuple:
    [env] = [e for e in container["env"] if e["name"] == "MESHTRACE_SECRET"]
    ref = env["valueFrom"]["secretKeyRef"]
    return ref["name"], ref["key"]


def test_the_job_renders_on_the_statefulsets_pods_by_their_stable_names():
    r = resources()
    service, nodes, job = r["Service"], r["StatefulSet"], r["Job"]["spec"]["template"]["spec"]
    assert service["spec"]["clusterIP"] == "None"  # headless: a DNS name per pod
    assert nodes["spec"]["serviceName"] == service["metadata"]["name"]
    assert (
        service["spec"]["selector"].items()
        <= nodes["spec"]["template"]["metadata"]["labels"].items()
    )
    [init] = job["initContainers"]
    made = _parser().parse_args(init["command"][1:])
    assert made.command == "cluster-file"
    assert (made.statefulset, made.service) == (
        nodes["metadata"]["name"],
        service["metadata"]["name"],
    )
    assert made.rows * made.cols == nodes["spec"]["replicas"]
    [node] = nodes["spec"]["template"]["spec"]["containers"]
    served = parse_node(node["command"][1:])
    assert served.command == "serve" and served.listen == f"0.0.0.0:{made.port}"
    assert [p["containerPort"] for p in node["ports"]] == [made.port]
    [host] = job["containers"]
    render = _parser().parse_args(host["command"][1:])
    assert render.command == "render" and (ROOT / render.scene).is_file()
    assert render.cluster == made.output and render.wait >= 60
    assert _secret(host) == _secret(node)
    mounts = {m["name"]: m["mountPath"] for m in host["volumeMounts"]}
    init_mounts = {m["name"]: m["mountPath"] for m in init["volumeMounts"]}
    assert Path(made.output).parent == Path(init_mounts["config"]) == Path(mounts["config"])
    claim = [v for v in job["volumes"] if "persistentVolumeClaim" in v]
    assert [v["name"] for v in claim] == ["out"]
    assert (
        claim[0]["persistentVolumeClaim"]["claimName"]
        == r["PersistentVolumeClaim"]["metadata"]["name"]
    )
    assert Path(render.output).parent == Path(mounts["out"])
    assert node["image"] == host["image"] == init["image"]


def test_cluster_file_lists_each_pod_as_its_node(tmp_path, capsys):
    out = tmp_path / "cluster.txt"
    assert (
        main(
            [
                "cluster-file",
                "--statefulset",
                "meshnode",
                "--service",
                "mesh",
                "--rows",
                "2",
                "--cols",
                "3",
                "--port",
                "7701",
                "-o",
                str(out),
            ]
        )
        == 0
    )
    rows, cols, addresses = read_cluster(out)
    assert (rows, cols) == (2, 3)
    assert addresses == [f"meshnode-{i}.mesh:7701" for i in range(6)]
    assert (
        main(
            [
                "cluster-file",
                "--statefulset",
                "meshnode",
                "--service",
                "mesh",
                "--rows",
                "1",
                "--cols",
                "2",
                "--namespace",
                "render",
            ]
        )
        == 0
    )
    assert "1 meshnode-1.mesh.render.svc.cluster.local:7700" in capsys.readouterr().out


@pytest.mark.parametrize(
    "flags,what",
    [
        (["--statefulset", "Mesh_Node"], "not a Kubernetes name"),
        (["--rows", "0"], "must be at least 1"),
        (["--port", "70000"], "not a TCP port"),
    ],
)
def test_cluster_file_refuses_bad_input_in_one_line(flags, what, capsys):
    argv = [
        "cluster-file",
        "--statefulset",
        "meshnode",
        "--service",
        "mesh",
        "--rows",
        "2",
        "--cols",
        "2",
    ]
    assert main(argv + flags) == 2
    err = capsys.readouterr().err
    assert what in err and len(err.splitlines()) == 1
