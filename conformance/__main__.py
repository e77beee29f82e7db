"""``python -m mcp_conform.conformance``: the same as the ``mcp-conform`` command."""

import sys

from mcp_conform.conformance._entry import main

sys.exit(main())
