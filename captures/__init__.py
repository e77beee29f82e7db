"""captures: reserved package of mcp-conform (see DESIGN.md); not implemented yet."""
