"""traceio: trace I/O, the floor above ``spec`` and ``vehicle`` and below the judge.

Reading and writing captures, and nothing that judges them: one reader for our MCAP files,
pcap and pcapng (``traceio.reader``, its typed records in ``traceio.records``), the MCAP
recorder every producer writes through (``traceio.recorder``, its channels and their schemas
in ``traceio.channels``, its writer process in ``traceio.background``), the merge of
pytest-xdist workers' parts (``traceio.merge``), a capture's datagrams as a conversation
(``traceio.trace``), and output files with their one-line errors (``traceio.files``)."""
