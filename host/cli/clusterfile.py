"""`host cluster-file`: the cluster file of a Kubernetes StatefulSet of nodes, written by
`host.run.cluster.statefulset_cluster`.
"""

import sys
from pathlib import Path

from host.cli.parser import prog
from host.run.cluster import statefulset_cluster


def command(args) -> int:
    """Write the cluster file (to --output or standard output); 2 on a bad option or path."""
    try:
        text = statefulset_cluster(
            args.statefulset, args.service, args.rows, args.cols, args.port, args.namespace
        )
        if args.output:
            Path(args.output).write_text(text)
        else:
            sys.stdout.write(text)
    except (ValueError, OSError) as e:
        print(f"{prog()}: {e}", file=sys.stderr)
        return 2
    return 0
