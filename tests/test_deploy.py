"""The Kubernetes manifests in deploy/ are valid (kubernetes-validate, strict, against the
newest schemas it ships) and describe a mesh that can work: the StatefulSet has rows x cols
replicas behind the headless Service the cluster file names, every container command parses
with the real CLIs, nodes and host share the secret, and the image lands on a volume. Every
container is bounded (requests and limits) and locked down (non-root, read-only root, no
capabilities), nodes are probed on the port they serve, a render is created again and again
from a suspended CronJob, and a results pod mounts the claim renders write. The
cluster-file command writes what `--cluster` reads, one stable pod name per node."""

import os
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
    assert sorted(kinds) == [
        "CronJob",
        "Deployment",
        "PersistentVolumeClaim",
        "Service",
        "StatefulSet",
    ]


def test_an_invalid_manifest_is_caught():
    bad = resources()["StatefulSet"]
    bad["spec"]["replicas"] = "four"
    with pytest.raises(kubernetes_validate.ValidationError):
        kubernetes_validate.validate(bad, latest_version(), strict=True)


def _pod(resource) -> dict:
    """The pod spec of a StatefulSet, Deployment or CronJob."""
    spec = resource["spec"]
    if resource["kind"] == "CronJob":
        spec = spec["jobTemplate"]["spec"]
    return spec["template"]["spec"]


def _containers():
    """(pod spec, container) for every container deploy/ runs, init ones too."""
    for kind, resource in resources().items():
        if "template" in resource["spec"] or kind == "CronJob":
            pod = _pod(resource)
            for container in pod.get("initContainers", []) + pod["containers"]:
                yield pod, container


def _secret(container) -> tuple:
    [env] = [e for e in container["env"] if e["name"] == "MESHTRACE_SECRET"]
    ref = env["valueFrom"]["secretKeyRef"]
    return ref["name"], ref["key"]


def test_the_job_renders_on_the_statefulsets_pods_by_their_stable_names():
    r = resources()
    service, nodes, job = r["Service"], r["StatefulSet"], _pod(r["CronJob"])
    assert service["spec"]["clusterIP"] == "None"  # headless: a DNS name per pod
    assert nodes["spec"]["serviceName"] == service["metadata"]["name"]
    assert (
        service["spec"]["selector"].items()
        <= nodes["spec"]["template"]["metadata"]["labels"].items()
    )
    [kernels, init] = job["initContainers"]
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
    assert node["image"] == host["image"] == init["image"] == kernels["image"]


def test_every_container_is_bounded_and_locked_down():
    seen = []
    for pod, container in _containers():
        seen.append(container["name"])
        for bound in ("requests", "limits"):
            assert {"cpu", "memory"} <= container["resources"][bound].keys(), container["name"]
        for what in ("cpu", "memory"):
            assert _quantity(container["resources"]["requests"][what]) <= _quantity(
                container["resources"]["limits"][what]
            )
        context = {**pod.get("securityContext", {}), **container["securityContext"]}
        assert context["runAsNonRoot"] is True and context["runAsUser"] > 0, container["name"]
        assert context["runAsGroup"] > 0
        assert context["readOnlyRootFilesystem"] is True, container["name"]
        assert context["allowPrivilegeEscalation"] is False, container["name"]
        assert context["capabilities"]["drop"] == ["ALL"], container["name"]
        assert "add" not in context["capabilities"]
    assert sorted(seen) == ["cluster-file", "host", "kernels", "kernels", "meshnode", "results"]


def test_every_command_parses_with_the_real_cli_or_is_plain_coreutils():
    for _, container in _containers():
        program, *argv = container["command"]
        if program == "meshtrace":
            _parser().parse_args(argv)  # exits on a bad line
        elif program == "meshnode":
            parse_node(argv)
        else:
            assert container["command"] in (
                ["cp", "-R", "/opt/meshtrace/kernels/.", "/kernels/"],
                ["sleep", "infinity"],
            )


def _quantity(text: str) -> float:
    units = {"m": 1e-3, "Ki": 2**10, "Mi": 2**20, "Gi": 2**30}
    for unit, scale in units.items():
        if text.endswith(unit):
            return float(text[: -len(unit)]) * scale
    return float(text)


def test_the_image_runs_as_the_user_the_pods_name():
    lines = (ROOT / "Dockerfile").read_text().splitlines()
    [user] = [line.split()[1] for line in lines if line.startswith("USER ")]
    uids = {c.get("runAsUser") or p["securityContext"]["runAsUser"] for p, c in _containers()}
    assert uids == {int(user.split(":")[0])}
    warmup = next(i for i, line in enumerate(lines) if "meshnode warmup" in line)
    assert lines.index(f"USER {user}") > warmup  # kernels compiled before the switch


def test_code_of_the_project_runs_with_the_build_kernels_in_a_writable_folder():
    """numba loads a cache only from a folder it may write to: with a read-only root, every
    container running the project gets the image's kernels copied into an emptyDir first."""
    for pod, container in _containers():
        if container["command"][0] not in ("meshtrace", "meshnode"):
            continue
        [kernels] = [i for i in pod["initContainers"] if i["name"] == "kernels"]
        assert kernels["command"][:2] == ["cp", "-R"]
        assert kernels["command"][2] == "/opt/meshtrace/kernels/."  # the Dockerfile's
        env = {e["name"]: e.get("value") for e in container.get("env", [])}
        mounts = {m["mountPath"]: m["name"] for m in container["volumeMounts"]}
        copied = {m["mountPath"]: m["name"] for m in kernels["volumeMounts"]}
        target = kernels["command"][3].rstrip("/")
        assert mounts[env["NUMBA_CACHE_DIR"]] == copied[target]
        volumes = {v["name"]: v for v in pod["volumes"]}
        assert "emptyDir" in volumes[copied[target]]
        assert pod["initContainers"].index(kernels) == 0  # before anything imports numba
        assert "ENV NUMBA_CACHE_DIR=/opt/meshtrace/kernels" in (ROOT / "Dockerfile").read_text()


def test_the_image_runs_its_nodes_as_a_local_mesh_starts_them():
    """Every variable of the nodes' environment (`host.run.localmesh.NODE_ENVIRONMENT`) is set
    in the image to the same value, and a local mesh's node gets it unless told otherwise."""
    from host.run.localmesh import NODE_ENVIRONMENT, LocalMesh

    env = {}
    for line in (ROOT / "Dockerfile").read_text().splitlines():
        if line.startswith("ENV "):
            env.update(pair.split("=", 1) for pair in line.split()[1:] if "=" in pair)
    assert NODE_ENVIRONMENT and all(env.get(k) == v for k, v in NODE_ENVIRONMENT.items())
    mesh = LocalMesh(1, env={"NUMPY_MADVISE_HUGEPAGE": "1"})
    started = mesh._environment()
    assert started["NUMPY_MADVISE_HUGEPAGE"] == "1"  # the caller's word stands
    others = {k: v for k, v in NODE_ENVIRONMENT.items() if k != "NUMPY_MADVISE_HUGEPAGE"}
    assert all(started[k] == os.environ.get(k, v) for k, v in others.items())


def test_nodes_are_probed_on_the_port_they_serve():
    [node] = _pod(resources()["StatefulSet"])["containers"]
    served = parse_node(node["command"][1:])
    port = int(served.listen.rsplit(":", 1)[1])
    named = {p["name"]: p["containerPort"] for p in node["ports"]}
    for probe in ("readinessProbe", "livenessProbe"):
        target = node[probe]["tcpSocket"]["port"]
        assert named.get(target, target) == port, probe
        assert node[probe]["periodSeconds"] >= 5 and node[probe]["failureThreshold"] >= 2
    assert (
        node["livenessProbe"]["initialDelaySeconds"]
        >= node["readinessProbe"]["initialDelaySeconds"]
    )
    assert served.threads == _quantity(node["resources"]["limits"]["cpu"])


def test_a_render_is_created_again_from_a_suspended_cronjob():
    render = resources()["CronJob"]
    assert render["spec"]["suspend"] is True  # never on its schedule: only `kubectl create job`
    job = render["spec"]["jobTemplate"]["spec"]
    assert (
        job["ttlSecondsAfterFinished"] > 0 and job["template"]["spec"]["restartPolicy"] == "Never"
    )
    docs = (ROOT / "docs" / "cluster.md").read_text()
    command = f"kubectl create job render-$(date +%s) --from=cronjob/{render['metadata']['name']}"
    assert command in docs
    assert command in (DEPLOY / "render.yaml").read_text()


def test_the_results_pod_mounts_the_claim_the_render_writes_read_only():
    r = resources()
    results, render = _pod(r["Deployment"]), _pod(r["CronJob"])
    claim = r["PersistentVolumeClaim"]["metadata"]["name"]
    [container] = results["containers"]
    assert container["command"] == ["sleep", "infinity"]  # coreutils, in python:3.11-slim
    [volume] = results["volumes"]
    assert volume["persistentVolumeClaim"] == {"claimName": claim, "readOnly": True}
    [mount] = container["volumeMounts"]
    assert mount["name"] == volume["name"] and mount["readOnly"] is True
    [host] = render["containers"]
    args = _parser().parse_args(host["command"][1:])
    writes = {m["mountPath"]: m["name"] for m in host["volumeMounts"]}[
        str(Path(args.output).parent)
    ]
    [written] = [v for v in render["volumes"] if v["name"] == writes]
    assert written["persistentVolumeClaim"]["claimName"] == claim
    assert mount["mountPath"] == str(Path(args.output).parent)
    docs = (ROOT / "docs" / "cluster.md").read_text()
    assert f":{args.output} {Path(args.output).name}" in docs  # the kubectl cp line
    # ReadWriteOnce serves both only on one node: the render follows the results pod there.
    assert r["PersistentVolumeClaim"]["spec"]["accessModes"] == ["ReadWriteOnce"]
    [term] = render["affinity"]["podAffinity"]["requiredDuringSchedulingIgnoredDuringExecution"]
    assert term["topologyKey"] == "kubernetes.io/hostname"
    labels = r["Deployment"]["spec"]["template"]["metadata"]["labels"]
    assert term["labelSelector"]["matchLabels"].items() <= labels.items()


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
