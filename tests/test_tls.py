"""TLS on every link (meshnode.transport.tls): a 1x2 cluster whose nodes listen with
certificates from one CA and demand client certificates renders the single node's image over
TLS, node to node and host to node; a plain host, a host that trusts another CA and a host
without a client certificate are each refused with the reason, and the nodes go on serving."""

import asyncio

import numpy as np
import pytest
import trustme

from host.cli import main
from host.planning.request import Request
from host.run.connections import Nodes
from host.run.errors import MeshError
from host.run.localmesh import LocalMesh
from host.run.meshclient import render_on_mesh
from host.run.oneprocess import render
from host.scene.nff import read_nff
from meshnode.transport.tls import TlsFiles
from protocols.render import MeshPlan
from tests.conftest import records, spd_scene

SECRET = b"tls test secret, long enough for a cluster"


@pytest.fixture(scope="module")
def pki(tmp_path_factory):
    """A cluster CA, a node certificate naming 127.0.0.1 and a client one, and a rogue CA."""
    d = tmp_path_factory.mktemp("pki")
    ca, rogue = trustme.CA(), trustme.CA()
    files = {}
    for name, pem in (("ca", ca.cert_pem), ("rogue", rogue.cert_pem)):
        pem.write_to_path(d / f"{name}.pem")
        files[name] = str(d / f"{name}.pem")
    for name, cert in (
        ("node", ca.issue_cert("127.0.0.1", "localhost")),
        ("client", ca.issue_cert("meshtrace-host")),
    ):
        cert.private_key_pem.write_to_path(d / f"{name}.key")
        for i, blob in enumerate(cert.cert_chain_pems):
            blob.write_to_path(d / f"{name}.pem", append=i > 0)
        files[name] = (str(d / f"{name}.pem"), str(d / f"{name}.key"))
    return files


def tls_mesh(pki, n=2) -> LocalMesh:
    cert, key = pki["node"]
    return LocalMesh(
        n, secret=SECRET, options=["--tls-cert", cert, "--tls-key", key, "--tls-ca", pki["ca"]]
    )


def test_a_tls_cluster_renders_the_single_node_image_and_refuses_other_hosts(pki):
    scene = read_nff(spd_scene("balls_s1.nff"))
    rs = records(width=32, height=32, threads=1)
    ref, _ = render(Request(scene, *rs))
    good = TlsFiles(*pki["client"], pki["ca"]).client()

    def on_mesh(addresses, tls):
        coro = render_on_mesh(
            Request(scene, rs.image, rs.engine, plan=MeshPlan(1, 2, 1)),
            Nodes(addresses, secret=SECRET, tls=tls),
            on_node_loss="fail",
        )
        return asyncio.run(asyncio.wait_for(coro, 120))

    with tls_mesh(pki) as addresses:
        for tls, why in [
            (None, "closes plain connections"),
            (TlsFiles(*pki["client"], pki["rogue"]).client(), "CERTIFICATE_VERIFY"),
            (TlsFiles(ca=pki["ca"]).client(), "handshake failed"),
        ]:
            with pytest.raises(MeshError, match=why):
                on_mesh(addresses, tls)
        img, stats = on_mesh(addresses, good)
    np.testing.assert_allclose(img, ref, rtol=0, atol=1e-5)
    links = [link for node in stats["nodes"] for link in node["links"].values()]
    assert links and all(link["tls"] in ("TLSv1.2", "TLSv1.3") for link in links)
    assert sum(link["rays_sent"] for link in links) > 0  # the TLS links carried rays


def test_tls_options_are_checked_before_work(pki, tmp_path, capsys):
    scene = str(spd_scene("tetra_s1.nff"))
    cluster = tmp_path / "c.txt"
    cluster.write_text("0 0 127.0.0.1:1\n")
    out = str(tmp_path / "x.png")
    assert (
        main(
            ["render", scene, "-o", out, "--cluster", str(cluster), "--tls-cert", pki["client"][0]]
        )
        == 2
    )
    assert "--tls-cert and --tls-key go together" in capsys.readouterr().err
    assert (
        main(
            [
                "render",
                scene,
                "-o",
                out,
                "--cluster",
                str(cluster),
                "--tls-ca",
                str(tmp_path / "missing.pem"),
            ]
        )
        == 2
    )
    assert f"--tls-ca {tmp_path / 'missing.pem'}: no such file" in capsys.readouterr().err
    assert main(["render", scene, "-o", out, "--mesh", "1x2", "--tls-ca", pki["ca"]]) == 2
    assert "are for nodes of a --cluster" in capsys.readouterr().err
