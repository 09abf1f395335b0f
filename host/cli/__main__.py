"""`python -m host.cli`: the same command line as `host` and `meshtrace`."""

import sys

from host.cli import main

if __name__ == "__main__":
    sys.exit(main())
