"""``python -m mcp_conform.reference_impl``: the ``mcp-node`` command line (:mod:`reference_impl.cli`)."""

import sys

from mcp_conform.reference_impl.cli import run

if __name__ == "__main__":
    sys.exit(run())
