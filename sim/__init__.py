"""The deterministic simulator (issue 38, items 2 and 3): MCP nodes as sans-I/O models, the runner's
own seeded link per direction (``harness.impair``, :mod:`sim.link`) and the trace judges in one process on a virtual clock, in the style of
FoundationDB's simulation and TigerBeetle's VOPR -- every schedule a seed, every failure a
replayable seed (``sim.search.replay``).

Layers: ``sim`` imports ``spec``, ``reference_impl``, ``judge``, ``traceio`` and ``harness``'s
link (``harness.impair``); nothing imports ``sim``. No sockets, threads or ``time`` calls: time is :class:`sim.clock.Clock`'s.
"""
