"""docker-compose.yml stays honest: its services, port and commands are the ones the tests
run without Docker, and its cluster file parses to the 2x2 mesh it starts."""

from pathlib import Path

from host.cli import _parser, read_cluster
from meshnode.cli import main as meshnode_main

ROOT = Path(__file__).resolve().parents[1]


def test_compose_matches_cluster_file_and_commands():
    text = (ROOT / "docker-compose.yml").read_text()
    rows, cols, addresses = read_cluster(ROOT / "cluster-2x2.txt")
    assert (rows, cols) == (2, 2)
    for address in addresses:
        name, port = address.split(":")
        assert f"  {name}: *node" in text
        assert port == "7700"
    assert '"meshnode", "serve", "--listen", "0.0.0.0:7700"' in text
    # The host command parses with the real CLI.
    line = text[text.index('command: ["host"') :].split("\n")
    words = " ".join(line[:2]).split("[", 1)[1].rsplit("]", 1)[0]
    argv = [w.strip().strip('"') for w in words.split(",") if w.strip()]
    args = _parser().parse_args(argv[1:])
    assert args.cluster == "cluster-2x2.txt" and (ROOT / args.scene).exists()
    docker = (ROOT / "Dockerfile").read_text()
    assert "meshnode warmup" in docker and 'CMD ["meshnode", "serve"' in docker
    assert callable(meshnode_main)
