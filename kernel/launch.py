"""The ``warden`` executable: the command line, and a Ctrl-C before it has even loaded.

The console script imports this small module first, so that SIGINT during the second or so
the command line takes to import (numpy, MuJoCo, msgspec ...) is one line and exit 130, not a
``KeyboardInterrupt`` traceback from the middle of an import. Once a run has started, SIGINT
and SIGTERM end it in order (:mod:`kernel.app.interrupt`).
"""

from __future__ import annotations

import sys

EXIT_INTERRUPTED = 130


def main() -> int:
    try:
        from kernel.cli import main as cli

        return cli()
    except KeyboardInterrupt:
        print("warden: interrupted (SIGINT)", file=sys.stderr)
        return EXIT_INTERRUPTED


if __name__ == "__main__":
    sys.exit(main())
