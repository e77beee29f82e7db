"""``mcp-fuzz``: reserved entry point; fuzz campaigns arrive in a later release."""

import sys


def main(argv: list[str] | None = None) -> int:
    print("mcp-fuzz: fuzz campaigns are not implemented in this version", file=sys.stderr)
    return 2


if __name__ == "__main__":
    sys.exit(main())
