"""``python -m reference_impl``: the ``mcp-node`` command line (:mod:`reference_impl.cli`)."""

import sys

from reference_impl.cli import run

if __name__ == "__main__":
    sys.exit(run())
