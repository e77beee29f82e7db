"""``python -m mcp_conform.captures``: the same as the ``mcp-capture`` command."""

import sys

from mcp_conform.captures.cli import main

sys.exit(main())
