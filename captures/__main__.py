"""``python -m captures``: the same as the ``mcp-capture`` command."""

import sys

from captures.cli import main

sys.exit(main())
