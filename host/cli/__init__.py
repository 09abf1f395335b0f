"""`host` / `meshtrace` command line: parsing and wiring only.

Every render option is one field of a record of `protocols.render` (or `protocols.camera`,
`host.camera.setup`); the option's default and its checks are the field's, shown in --help.
The parser is `parser` (its option helpers `options`); each command is a module: `render`,
`camera` and `clusterfile`.
"""

import importlib
import os
import sys

from host.cli.parser import _parser, prog

# Each command's module, imported only when that command runs: a render never loads the
# camera command's lens code, nor `cluster-file` the renderer.
COMMANDS = {"camera": "camera", "cluster-file": "clusterfile", "render": "render"}


def main(argv=None) -> int:
    """Run the command `argv` (default: the process's arguments) names; its exit status."""
    args = _parser().parse_args(argv)
    try:
        command = importlib.import_module(f"host.cli.{COMMANDS[args.command]}").command
        code = command(args)
        sys.stdout.flush()  # a closed pipe shows here, not in the interpreter's last flush
        return code
    except BrokenPipeError:  # `host camera ... | head`: the reader left; not an error here
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 0
    except KeyboardInterrupt:  # Ctrl-C: every node is already stopped (LocalMesh's exit)
        print(f"\n{prog()}: interrupted", file=sys.stderr)
        return 130
