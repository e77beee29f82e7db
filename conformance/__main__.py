"""``python -m conformance``: the same as the ``mcp-conform`` command."""

import sys

from conformance.cli import main

sys.exit(main())
