"""judge: the protocol's rules as one incremental judge of traffic (sans-I/O).

``judge.monitor`` is the trace monitor every consumer shares (the runner of both roles, the
fuzzer, ``mcp-capture check`` and ``replay``), its rules in ``judge._monitor_sender``,
``_monitor_receiver`` and ``_monitor_vehicle``; ``judge.attribution`` ties a reply to the
command it answers; ``judge.run_monitor`` feeds a live run to the monitor; ``judge.judging``
judges a capture read by ``traceio`` with the parameters of ``judge.params``. Imports only ``spec``, ``vehicle`` and ``traceio``."""
