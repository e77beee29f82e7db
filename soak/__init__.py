"""``mcp-soak``: whole missions on a bad link, judged by the monitor and checked exactly-once
(issue 22 item 4). A tool: runs nodes as subprocesses, never imports ``reference_impl``."""
