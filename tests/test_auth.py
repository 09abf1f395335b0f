"""Only peers that hold the cluster secret use a node: host links and node links alike prove
it both ways before anything else is accepted; strangers, floods and second hosts are refused
with a reason and leave the node serving the next real render."""

import asyncio
import socket
import struct

import numpy as np
import pytest

from meshnode.service import cli
from meshnode.service.server import NodeService
from meshnode.transport.link import HANDSHAKE_FRAME, LinkClosed, dial
from protocols.errors import AuthFailed
from protocols.framing import FrameDecoder
from protocols.handshake import auth, check_auth, hello, nonce, read_secret
from protocols.messages import Kind, make, parse
from tests.test_node_service import config, host_link, send_objects

SECRET = b"correct horse battery staple, twice as long"


async def serving(secret=SECRET) -> NodeService:
    service = NodeService("127.0.0.1", 0, secret=secret)
    await service.start()
    return service


async def still_serves(service: NodeService, secret=SECRET) -> None:
    """A real host with the secret gets a session (its first heartbeat) after all that."""
    link = await host_link(service.port, secret)
    await link.send(config())
    kind, f = await asyncio.wait_for(link.recv(), 10)
    assert kind is Kind.PROGRESS and f["node"] == 0
    await link.close()


@pytest.mark.parametrize("host_secret", [None, b"wrong secret"])
@pytest.mark.parametrize("role", ["host", "node"])
async def test_a_peer_without_the_secret_is_refused(host_secret, role):
    service = await serving()
    try:
        # the side without a secret says so; with another one, that the secrets differ
        why = "this side has no cluster secret" if host_secret is None else "--secret-file differ"
        with pytest.raises(LinkClosed, match=why):
            await host_link(service.port, host_secret, role, node=1)
        await still_serves(service)
    finally:
        await asyncio.wait_for(service.shutdown(), 10)


async def test_a_node_without_a_secret_cannot_pass_for_one_with_it():
    # The dialler checks the listener's proof first: a host with the secret will not talk
    # to a node (or an impostor) that lacks it.
    service = await serving(secret=None)
    try:
        with pytest.raises(LinkClosed, match="listener does not hold"):
            await host_link(service.port, SECRET)
    finally:
        await asyncio.wait_for(service.shutdown(), 10)


async def test_a_replayed_or_forged_proof_fails():
    dialler = parse(hello("c", "host", -1, nonce()))[1]
    theirs = nonce()
    good = auth(SECRET, "dialler", dialler, theirs)
    check_auth(good, SECRET, "dialler", dialler, theirs)
    with pytest.raises(AuthFailed):  # the same proof against a fresh listener nonce
        check_auth(good, SECRET, "dialler", dialler, nonce())
    with pytest.raises(AuthFailed):  # the listener's own proof played back as the dialler's
        check_auth(auth(SECRET, "listener", dialler, theirs), SECRET, "dialler", dialler, theirs)
    with pytest.raises(AuthFailed):  # a claimed node index changed in between
        check_auth(good, SECRET, "dialler", {**dialler, "node": 0}, theirs)


async def test_floods_before_the_handshake_are_cut_off():
    service = await serving()
    loop = asyncio.get_running_loop()
    try:
        for payload in (
            struct.pack(">I", 64 * 1024 * 1024),  # announces a 64 MiB frame
            struct.pack(">I", HANDSHAKE_FRAME + 1) + b"x" * 100,
            b"\0\0\0\5hello-not-msgpack",
        ):
            s = socket.create_connection(("127.0.0.1", service.port))
            s.setblocking(False)
            await loop.sock_sendall(s, payload)
            reply = await asyncio.wait_for(loop.sock_recv(s, 1 << 16), 10)
            while reply and (more := await asyncio.wait_for(loop.sock_recv(s, 1 << 16), 10)):
                reply += more
            s.close()  # the node hung up (EOF above): at most an ERROR frame came back
            assert all(parse(m)[0] is Kind.ERROR for m in FrameDecoder().feed(reply))
        await still_serves(service)
    finally:
        await asyncio.wait_for(service.shutdown(), 10)


async def test_a_stranger_cannot_register_as_a_neighbour():
    # A peer that claims to be node 0 without the secret never reaches the pending links.
    service = await serving()
    try:
        with pytest.raises(LinkClosed):
            await dial(f"127.0.0.1:{service.port}", "node 1", "meshtrace", b"guess", "node", 0)
        assert service.pending == {}
        await still_serves(service)
    finally:
        await asyncio.wait_for(service.shutdown(), 10)


async def test_a_link_for_another_render_is_refused_as_a_neighbour():
    # A node with the secret that is still busy with a given-up render (or another host's)
    # dials as node 0: refused; the link for this render (CONFIG.render_id) is kept.
    from protocols.render import MeshPlan

    service = await serving()
    try:
        host = await host_link(service.port, SECRET)
        await host.send(config(node=1, plan=MeshPlan(1, 2)))
        kind, _ = await asyncio.wait_for(host.recv(), 10)  # the session's first heartbeat
        assert kind is Kind.PROGRESS
        address = f"127.0.0.1:{service.port}"
        stale, _ = await dial(address, "node 1", "meshtrace", SECRET, "node", 0, render=b"x" * 16)
        with pytest.raises(LinkClosed):
            await asyncio.wait_for(stale.recv(), 10)  # the node hangs up on it
        assert service.pending == {}
        await dial(address, "node 1", "meshtrace", SECRET, "node", 0, render=b"r" * 16)
        await asyncio.wait_for(service.links_ready.wait(), 10)  # set when a link is filed
        assert service.pending[0][0] == b"r" * 16
        await host.close()
    finally:
        await asyncio.wait_for(service.shutdown(), 10)


async def test_a_neighbour_dialled_before_its_config_keeps_the_link_for_that_render():
    # Node 0 is configured and dials node 1 before node 1's CONFIG has come (a busy machine):
    # node 1 cannot say which node it is yet; the link is kept for its session all the same
    # (it failed the render: "it says it is node -1, not node 1").
    from protocols.render import MeshPlan

    dialler, listener = await serving(), await serving()
    try:
        host = await host_link(dialler.port, SECRET)
        await host.send(config(node=0, plan=MeshPlan(1, 2)))
        kind, _ = await asyncio.wait_for(host.recv(), 10)  # node 0's session has begun
        assert kind is Kind.PROGRESS and listener.session is None
        link = await asyncio.wait_for(dialler.dial(1, f"127.0.0.1:{listener.port}"), 10)
        await asyncio.wait_for(listener.links_ready.wait(), 10)  # filed for node 1's session
        assert listener.pending[0][0] == dialler.session.config.render_id
        await link.close()
        await host.close()
    finally:
        await asyncio.wait_for(dialler.shutdown(), 10)
        await asyncio.wait_for(listener.shutdown(), 10)


async def test_a_neighbour_address_that_is_no_node_fails_the_render_and_the_node_serves_on():
    # An authenticated host names a neighbour address where a stranger listens: the node
    # dials it, the stranger cannot prove the secret, the render fails naming that address,
    # and the node takes the next render (ABORT, then a new CONFIG on the same link).
    from meshnode.service.warmup import ALL_KINDS, variant_scene
    from protocols.render import MeshPlan

    async def stranger(reader, writer):
        writer.write(b"\0\0\0\5hello")
        await writer.drain()
        writer.close()

    foreign = await asyncio.start_server(stranger, "127.0.0.1", 0)
    address = f"127.0.0.1:{foreign.sockets[0].getsockname()[1]}"
    service = await serving()
    try:
        host = await host_link(service.port, SECRET)
        message = config(node=0, plan=MeshPlan(1, 2))
        message["neighbours"]["1"] = address
        await host.send(message)
        scene = variant_scene(ALL_KINDS)
        await send_objects(host, scene)
        while (answer := await asyncio.wait_for(host.recv(), 30))[0] is not Kind.ERROR:
            pass  # heartbeats while it builds and dials
        assert address in answer[1]["reason"] and "handshake failed" in answer[1]["reason"]
        await host.send(make(Kind.ABORT, reason="its neighbour is no node"))
        while (await asyncio.wait_for(host.recv(), 10))[0] is not Kind.ABORTED:
            pass
        await host.send(config())  # the next render
        kind, f = await asyncio.wait_for(host.recv(), 10)
        assert kind is Kind.PROGRESS and f["node"] == 0
        await host.close()
    finally:
        await asyncio.wait_for(service.shutdown(), 10)
        foreign.close()


def test_only_loopback_may_listen_without_a_secret(tmp_path, monkeypatch):
    monkeypatch.delenv("MESHTRACE_SECRET", raising=False)
    args = cli.parse(["serve", "--listen", "0.0.0.0:7700"])
    with pytest.raises(ValueError, match="beyond this machine"):
        cli.serving_secret(args)
    assert (
        cli.serving_secret(cli.parse(["serve", "--listen", "0.0.0.0:7700", "--insecure"])) is None
    )
    assert cli.serving_secret(cli.parse(["serve"])) is None  # the default: loopback
    f = tmp_path / "secret"
    f.write_text("  " + "s3cret" * 6 + "\n")
    args = cli.parse(["serve", "--listen", "0.0.0.0:7700", "--secret-file", str(f)])
    assert cli.serving_secret(args) == b"s3cret" * 6
    monkeypatch.setenv("MESHTRACE_SECRET", "from-env" * 4)
    assert read_secret() == b"from-env" * 4
    monkeypatch.setenv("MESHTRACE_SECRET", "abc")  # what compose would pass on as it is
    with pytest.raises(ValueError, match="MESHTRACE_SECRET: the cluster secret has 3 char"):
        read_secret()
    f.write_text("x" * 31)
    with pytest.raises(ValueError, match="has 31 characters, at least 32"):
        read_secret(f)
    f.write_text("\n")
    with pytest.raises(ValueError, match="empty"):
        read_secret(f)


def test_a_busy_port_is_one_clear_line(capsys):
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        s.listen()
        port = s.getsockname()[1]
        assert cli.main(["serve", "--listen", f"127.0.0.1:{port}", "--once"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and f"cannot listen on 127.0.0.1:{port}" in err[0]


def test_a_local_mesh_renders_with_its_own_secret(tmp_path):
    # The CLI's local mesh makes a secret, gives it to its nodes in their environment and
    # proves it itself: the image equals one node's.
    from host.cli import main
    from host.run.framebuffer import read_pfm
    from tests.conftest import spd_scene

    scene = spd_scene("tetra_s1.nff")
    one, two = tmp_path / "one.png", tmp_path / "two.png"
    common = ["--width", "24", "--height", "24", "--quiet"]
    assert main(["render", str(scene), "-o", str(one), "--mesh", "1x1", *common]) == 0
    assert main(["render", str(scene), "-o", str(two), "--mesh", "1x2", *common]) == 0
    np.testing.assert_allclose(
        read_pfm(two.with_suffix(".pfm")), read_pfm(one.with_suffix(".pfm")), atol=1e-5
    )
