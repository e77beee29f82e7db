"""captures: MCAP recording of runs (``captures.recorder``), one reader for MCAP, pcap and
pcapng captures (``captures.reader``), and the ``mcp-capture`` tool (``captures.cli``)."""
