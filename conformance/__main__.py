"""``python -m conformance``: the same as the ``mcp-conform`` command."""

import sys

from conformance._entry import main

sys.exit(main())
