"""How long the host kept a spawned node off the CPU (MCP-RTX-3's evidence of host load, D-7).

Linux's ``/proc/<pid>/task/<tid>/schedstat`` gives, per thread, the time it ran, the time it
spent runnable but waiting for a CPU (its run delay) and its timeslices. A correct node that
sends a retransmission late because a loaded host did not run it shows that lateness as run
delay between its copies; ``judge.spacing`` excuses exactly that much of an uneven gap
(MCP-RTX-3), ``judge.explain`` and ``judge.veto`` judge a silence in the time the node could run
(MCP-RTX-1/2), and nothing is excused where the delay is unknown (attach mode, other systems).

Why the sum over the node's threads (and descendant processes), not the sending thread's nor
the most delayed thread's: the copy is late by the waits of every thread it waited on, one
after another -- a Python node's timer thread that wakes to retransmit waits for the GIL while
the thread holding it waits for a CPU, then for a CPU itself -- so its lateness can be the sum
of several threads' run delays, and the sending thread's own reading, or the largest one, would
leave a correct node's late copy unexcused: a false verdict. The sum overstates it where the
threads wait at the same time (measured: three threads hashing on a loaded 2-core host, 5.2 s
of summed run delay in 2.0 s), which can excuse a silence of a faulty node; it cannot be capped
at the time between two readings either, since the kernel adds a wait to a thread's count only
when the thread gets the CPU (a wait read late, that belongs to the span before). Which thread
sent a datagram is not visible from outside the process. So the reading is the least bound
that holds for every explanation, its overstatement the price of never failing a correct node.

The reading never goes down (:func:`run_delay_ns`): a thread or descendant that ended keeps the
count it had when last read. Summed over the live threads only, it fell when one ended -- a
node's worker that had waited 0.70 s on a loaded host ended and the reading fell to 0.01 s --
and a node that sends each message from a thread of its own (``threading.Timer``, a thread per
unicast as ``tests/conformance/nodes/sample_manager.py`` does) lost the very waits that made its
copies late (the judges take the growth between readings, never below zero).
"""

from __future__ import annotations

import inspect
import os
import threading
from collections.abc import Callable
from typing import Any

from mcp_conform.spec.codec import PREAMBLE, Action, peek_header

__all__ = ["delay_for", "run_delay_ns", "takes_run_delay"]

_ACK = int(Action.ACK)


#: per process read (/proc root, pid, its start time): {(process, thread): its run delay when
#: last read}, and the counts of threads whose IDs came back with a smaller count (a new thread
#: under an old ID): what each reading sums, so that it never goes down (module docstring)
_SEEN: dict[tuple[str, int, str | None], tuple[dict[tuple[int, int], int], list[int]]] = {}
_LOCK = threading.Lock()  # the driver's receive thread and the session read it
#: past this many processes kept, those gone from /proc are forgotten (a soak's many nodes)
_KEPT = 64


def _started(proc: str, pid: int) -> str | None:
    """Process ``pid``'s start time (``/proc/<pid>/stat`` field 22, clock ticks since boot):
    with its ID, which process it is (an ID is reused once its process is gone)."""
    try:
        with open(f"{proc}/{pid}/stat") as f:
            return f.read().rpartition(")")[2].split()[19]
    except (OSError, IndexError):
        return None


def run_delay_ns(pid: int, proc: str = "/proc") -> int | None:
    """The cumulative time (ns) process ``pid`` -- all its threads, and its descendant
    processes (a spawn command may be a shell) -- spent runnable but waiting for a CPU,
    summed (see the module docstring), a thread or process that ended still counting what it
    had when last read, so the reading never goes down; None where ``/proc`` does not say (not
    Linux, no such process: what was kept of it is forgotten). ``proc``: its root."""
    found: dict[tuple[int, int], int] = {}
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
                    found[(p, int(tid))] = int(f.read().split()[1])
            except (OSError, ValueError, IndexError):
                continue
            try:
                with open(f"{base}/children") as f:
                    todo.extend(int(c) for c in f.read().split())
            except (OSError, ValueError):
                pass
    key = (proc, pid, _started(proc, pid))
    with _LOCK:
        if not found:
            _SEEN.pop(key, None)
            return None
        if key not in _SEEN and len(_SEEN) >= _KEPT:
            for k in [k for k in _SEEN if not os.path.exists(f"{k[0]}/{k[1]}")]:
                del _SEEN[k]
        last, gone = _SEEN.setdefault(key, ({}, [0]))
        for task, rd in found.items():
            old = last.get(task)
            if old is not None and rd < old:
                gone[0] += old  # its ID taken by a new thread: the old one's count stays
            last[task] = rd
        return gone[0] + sum(last.values())


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
