"""``mcp-vehicle``: serve the simulated vehicle until Ctrl-C."""

from .cli import main

raise SystemExit(main())
