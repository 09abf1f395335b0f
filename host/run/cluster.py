"""Where a mesh's nodes are: `--mesh ROWSxCOLS` for a local mesh, or a cluster file listing
running nodes one per line as `ROW COL HOST:PORT` (errors name the file and line), which
`statefulset_cluster` writes for a Kubernetes StatefulSet of nodes."""

import re
from pathlib import Path

MAX_LOCAL_NODES = 64  # node processes `--mesh` starts on this one machine
DNS_LABEL = re.compile(r"[a-z0-9]([-a-z0-9]{0,61}[a-z0-9])?")


def parse_mesh(text: str) -> tuple[int, int]:
    """'2x3' -> (2, 3); 'auto' -> 1x1: on one machine, one process tracing on every core."""
    if text == "auto":
        return 1, 1
    try:
        rows, cols = (int(v) for v in text.lower().split("x"))
    except ValueError:
        raise ValueError(f"--mesh wants ROWSxCOLS, like 2x2, not {text!r}") from None
    if rows < 1 or cols < 1:
        raise ValueError(f"--mesh {text}: rows and columns must be at least 1")
    if rows * cols > MAX_LOCAL_NODES:
        raise ValueError(
            f"--mesh {text}: a local mesh starts at most {MAX_LOCAL_NODES} node "
            "processes on this machine (each holds its own engine and kernels, "
            "~0.2 GB); a larger mesh runs on a --cluster"
        )
    return rows, cols


def read_cluster(path) -> tuple[int, int, list[str]]:
    """Cluster file: one `ROW COL HOST:PORT` per node, `#` comments; every cell once."""
    cells = {}
    for number, line in enumerate(Path(path).read_text().splitlines(), 1):
        words = line.split("#", 1)[0].split()
        if not words:
            continue
        ok = len(words) == 3 and words[0].isdigit() and words[1].isdigit() and ":" in words[2]
        if not ok:
            raise ValueError(f"{path}:{number}: expected ROW COL HOST:PORT")
        key = (int(words[0]), int(words[1]))
        if key in cells:
            raise ValueError(f"{path}:{number}: node {key} listed twice")
        cells[key] = words[2]
    if not cells:
        raise ValueError(f"{path}: no nodes listed")
    rows = max(r for r, _ in cells) + 1
    cols = max(c for _, c in cells) + 1
    missing = [(r, c) for r in range(rows) for c in range(cols) if (r, c) not in cells]
    if missing:
        raise ValueError(f"{path}: no address for node(s) {missing}")
    return rows, cols, [cells[(r, c)] for r in range(rows) for c in range(cols)]


def statefulset_cluster(
    statefulset: str,
    service: str,
    rows: int,
    cols: int,
    port: int = 7700,
    namespace: str | None = None,
) -> str:
    """The cluster file of a StatefulSet's pods behind a headless Service: pod i (stable DNS
    name STATEFULSET-i.SERVICE, or its full name in `namespace`) is node (i // cols, i % cols),
    so the StatefulSet needs rows * cols replicas."""
    for flag, name in (
        ("--statefulset", statefulset),
        ("--service", service),
        ("--namespace", namespace),
    ):
        if name is not None and not DNS_LABEL.fullmatch(name):
            raise ValueError(
                f"{flag} {name!r}: not a Kubernetes name (lower-case letters, "
                "digits and '-', at most 63)"
            )
    if rows < 1 or cols < 1:
        raise ValueError(f"--rows {rows} --cols {cols}: both must be at least 1")
    if not 0 < port < 65536:
        raise ValueError(f"--port {port}: not a TCP port")
    domain = f"{service}.{namespace}.svc.cluster.local" if namespace else service
    lines = [
        f"# {rows}x{cols} mesh: StatefulSet {statefulset} ({rows * cols} replicas) behind "
        f"headless Service {service}"
    ]
    for i in range(rows * cols):
        lines.append(f"{i // cols} {i % cols} {statefulset}-{i}.{domain}:{port}")
    return "\n".join(lines) + "\n"
