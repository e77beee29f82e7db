import sys

from mcp_conform.soak.cli import main

sys.exit(main())
