"""``python -m fuzz``: the same as ``mcp-fuzz``."""

import sys

from fuzz.cli import main

sys.exit(main())
