"""`host` / `meshtrace` command line: parsing and wiring only.

Every render option is one field of a record of `protocols.render` (or `protocols.camera`,
`host.camera.setup`); the option's default and its checks are the field's, shown in --help.
The parser is `parser` (its option helpers `options`); each command is a module: `render`,
`camera` and `clusterfile`.
"""

import atexit
import gc
import importlib
import os
import sys

from host.cli.parser import _parser, prog

# At exit Python's last collections walk every object still alive, and numba leaves some
# hundred thousand: 0.15 s of a render's exit, for memory the system takes back anyway.
# Frozen, they are left alone (files are closed by then; nothing is left to flush).
atexit.register(gc.freeze)

# Each command's module, imported only when that command runs: a render never loads the
# camera command's lens code, nor `cluster-file` the renderer.
COMMANDS = {"camera": "camera", "cluster-file": "clusterfile", "render": "render"}


def main(argv=None) -> int:
    """Run the command `argv` (default: the process's arguments) names; its exit status."""
    if argv is None:
        # The process's own command (the `meshtrace` script): what is imported by now lives
        # until the process ends, so the collector need not walk it again (numba's objects
        # made each full collection of a render 30 ms).
        gc.freeze()
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
