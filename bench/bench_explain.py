"""How fast judge.explain decides a trace of 500 copies (issue 38 item 1): a correct receiver
and a correct sender simulated as in tests/judge/test_explain.py, delays up to several
``--rto``; prints traces decided per second per side. ``python bench/bench_explain.py``."""

from __future__ import annotations

import random
import time

from mcp_conform.judge.explain import Ack, Bounds, Copy, Trace, decide_receiver, decide_sender
from tests.judge.test_explain import Link, _receiver_run, _sender_run


def main() -> None:
    d = Link(link=0.4, react=0.1, backlog=0.3, rto=0.3)
    n = 250
    while True:  # the number of messages that makes about 500 copies
        rtrace, rb, _ = _receiver_run(random.Random(n), d, n, "correct", True)
        if abs(len(rtrace.copies) - 500) <= 10:
            break
        n = max(1, n * 500 // len(rtrace.copies) - (n % 3 == 0))
    n = 250
    while True:
        strace, sb = _sender_run(random.Random(n), d, n, "correct", 6, True)
        if abs(len(strace.copies) - 500) <= 10:
            break
        n = max(1, n * 500 // len(strace.copies) - (n % 3 == 0))
    # dense: 500 copies of 100 messages within 1 s, every ACK a candidate of nearly every copy
    rng = random.Random(1)
    cs = [Copy(1000 + i // 5, i // 5, rng.uniform(0, 1.0)) for i in range(500)]
    dense = Trace(cs, sorted([Ack(c.t + rng.uniform(0, 1.9), c.seq) for c in cs],
                             key=lambda a: a.t), 5.0)
    db = Bounds(ack_window=2.0, ack_early=0.5)
    for name, fn, trace, b in (("receiver", decide_receiver, rtrace, rb),
                               ("receiver, dense", decide_receiver, dense, db),
                               ("sender", decide_sender, strace, sb)):
        n, t0 = 0, time.perf_counter()
        while time.perf_counter() - t0 < 5.0:
            verdicts = fn(trace, b)
            n += 1
        dt = time.perf_counter() - t0
        print(f"{name}: {len(trace.copies)} copies, {len(trace.acks)} ACKs: "
              f"{n / dt:.1f} traces decided/s ({1000 * dt / n:.1f} ms each); "
              + ", ".join(f"{r} {v.status}" for r, v in verdicts.items()))


if __name__ == "__main__":
    main()
