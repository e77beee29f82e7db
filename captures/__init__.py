"""captures: the ``mcp-capture`` tool (``captures.cli``): check, show, diff, replay, export
and the Wireshark dissector, combining the floors below it (``traceio`` reads and writes
captures, ``judge`` judges them, ``harness`` drives a live node for ``replay``, ``fuzz``
reproduces a finding). The golden captures live in ``captures/golden/``."""
