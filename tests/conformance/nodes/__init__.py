"""Independent MCP nodes for testing the conformance runner (they never import reference_impl)."""
