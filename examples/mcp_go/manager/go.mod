module mcpconform.example/mcp_go/manager

go 1.22
