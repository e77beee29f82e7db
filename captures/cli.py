"""``mcp-capture``: reserved entry point; golden diff, replay and pcap export arrive later.

Recording a run is available now through ``mcp-conform --capture FILE.mcap``.
"""

import sys


def main(argv: list[str] | None = None) -> int:
    print("mcp-capture: not implemented in this version (record with mcp-conform --capture)", file=sys.stderr)
    return 2


if __name__ == "__main__":
    sys.exit(main())
