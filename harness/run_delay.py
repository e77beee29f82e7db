"""How long the host kept a spawned node off the CPU (MCP-RTX-3's evidence of host load).

Linux's ``/proc/<pid>/task/<tid>/schedstat`` gives, per thread, the time it ran, the time it
spent runnable but waiting for a CPU (its run delay) and its timeslices. A correct node that
sends a retransmission late because a loaded host did not run it shows that lateness as run
delay between its copies; ``judge.spacing`` excuses exactly that much of an uneven gap
(MCP-RTX-3), and nothing where the delay is unknown (attach mode, other systems).
"""

from __future__ import annotations

import inspect
import os
from collections.abc import Callable
from typing import Any

from mcp_conform.spec.codec import PREAMBLE, Action, peek_header

__all__ = ["delay_for", "run_delay_ns", "takes_run_delay"]

_ACK = int(Action.ACK)


def run_delay_ns(pid: int, proc: str = "/proc") -> int | None:
    """The cumulative time (ns) process ``pid`` -- all its threads, and its descendant
    processes (a spawn command may be a shell) -- spent runnable but waiting for a CPU;
    None where ``/proc`` does not say (not Linux, no such process). ``proc``: its root."""
    total, found = 0, False
    todo, seen = [pid], set()
    while todo:
        p = todo.pop()
        if p in seen:
            continue
        seen.add(p)
        try:
            tids = os.listdir(f"{proc}/{p}/task")
        except OSError:
            continue
        for tid in tids:
            base = f"{proc}/{p}/task/{tid}"
            try:
                with open(f"{base}/schedstat") as f:
                    total += int(f.read().split()[1])
                found = True
            except (OSError, ValueError, IndexError):
                continue
            try:
                with open(f"{base}/children") as f:
                    todo.extend(int(c) for c in f.read().split())
            except (OSError, ValueError):
                pass
    return total if found else None


def delay_for(msg: Any, read: Callable[[], int | None] | None) -> int | None:
    """``read()`` (the node's run delay now) for a datagram that is a non-ACK MCP message
    (``msg``: decoded, or the raw bytes, judged by their preamble and header), else None: only a node's own messages have copies
    whose spacing MCP-RTX-3 judges."""
    if read is None:
        return None
    if isinstance(msg, (bytes, bytearray)):  # its header is enough: no payload decoded twice
        h = peek_header(bytes(msg)) if msg[:len(PREAMBLE)] == PREAMBLE else None
        action = h[3] if h is not None else None
    else:
        action = msg.action if msg is not None else None
    if action is None or action == _ACK:
        return None
    try:
        return read()
    except Exception:  # noqa: BLE001 - evidence of load is optional, never a failure
        return None


def takes_run_delay(observer: Callable[..., Any]) -> bool:
    """Whether a datagram observer takes the ``run_delay`` keyword (or any keyword): one
    written for the four parameters (direction, data, addr, t_ns) is called without it."""
    try:
        params = inspect.signature(observer).parameters.values()
    except (TypeError, ValueError):
        return False
    return any(p.kind is p.VAR_KEYWORD or (p.name == "run_delay" and p.kind in (p.POSITIONAL_OR_KEYWORD, p.KEYWORD_ONLY))
               for p in params)
