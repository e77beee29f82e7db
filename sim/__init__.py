"""The deterministic simulator (issue 38, items 2 and 3): MCP nodes as sans-I/O models, a seeded
link per direction and the trace judges in one process on a virtual clock, in the style of
FoundationDB's simulation and TigerBeetle's VOPR -- every schedule a seed, every failure a
replayable seed (``sim.search.replay``).

Layers: ``sim`` imports ``spec``, ``reference_impl``, ``judge`` and ``traceio``; nothing imports
``sim``. No sockets, threads or ``time`` calls: time is :class:`sim.clock.Clock`'s.
"""
