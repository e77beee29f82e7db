"""``python -m mcp_conform.fuzz``: the same as ``mcp-fuzz``."""

import sys

from mcp_conform.fuzz.cli import main

sys.exit(main())
