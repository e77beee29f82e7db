"""A simulated party's view written as its own capture, as ``mcp-soak``'s writer writes a
node's (the simulator's views are what each party's capture would hold): the tests that judge
a regression seed through ``mcp-capture check``'s judge (``judge.judging``) write it here."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from mcp_conform.traceio.recorder import (
    RUN_DELAY_METADATA,
    McapRecorder,
    run_delay_metadata,
    run_metadata,
)


def write_view(path: Path, outcome: Any, node: int, *, end_run_delay: bool = False) -> Path:
    """Party ``node``'s view of a replayed seed (``sim.search.replay``'s outcome) as a capture
    of its own, declared complete, with the schedule's timings; ``end_run_delay``: with the
    party's run delay at its view's end, as the runner records it when it stops a node."""
    w, s = outcome.world, outcome.schedule
    meta = run_metadata("mcp-soak", node_id=node, complete="true",
                        parameters={"rto": s.rto, "ack_window": max(0.5, 2 * s.rto)})
    with McapRecorder(path, library="mcp-soak", metadata=meta) as rec:
        for r in w.views[node]:
            if r.tx:
                rec.datagram("tx", r.data, r.dst_addr, r.t_ns, local=r.src_addr, run_delay=r.run_delay)
            else:
                rec.datagram("rx", r.data, r.src_addr, r.t_ns, local=r.dst_addr)
        if end_run_delay:
            end = int(w.view_end(node) * 1e9)
            rec.add_metadata(RUN_DELAY_METADATA, run_delay_metadata(node, w.run_delay_ns[node], end))
    return path
