"""What the runner shows as it works (conformance.run_display): -v traffic lines in time order, the
progress of the wait for the node's first datagram."""

from __future__ import annotations

import io
import threading

from rich.console import Console

from mcp_conform.conformance.run_display import FirstDatagram, TrafficPrinter, WaitStatus
from mcp_conform.spec.codec import Action, Message, encode

PEER = ("127.0.0.1", 7890)


def _printer() -> tuple[TrafficPrinter, io.StringIO]:
    out = io.StringIO()
    return TrafficPrinter(Console(file=out, highlight=False, no_color=True, width=200), t0_ns=0), out


def test_verbose_prints_a_reply_after_the_datagram_it_answers():
    """Issue 18 item 16: the receiving thread reports the node's ACK before the sending
    thread reports the command it answers; the lines come out in time order all the same."""
    printer, out = _printer()
    command, ack = encode(Message(1, 0, 1311, Action.WP_OFF)), encode(Message(0, 1, 40, Action.ACK, 1311))
    printer("rx", ack, PEER, 2_163_000_000)  # reported first, stamped later
    printer("tx", command, PEER, 2_162_000_000)
    printer.close()
    lines = out.getvalue().splitlines()
    assert [ln.split()[2] for ln in lines] == ["tx", "rx"], lines
    assert lines[0].startswith("    2.162 s  tx → 127.0.0.1:7890") and "WP_OFF" in lines[0]
    assert "ACK 1311" in lines[1]


def test_off_a_terminal_the_first_datagram_wait_is_a_plain_line_saying_what_and_where():
    out = io.StringIO()
    watch = FirstDatagram()
    watch.local = ("", 7889)
    status = WaitStatus(Console(file=out, highlight=False, no_color=True, width=200))
    assert not status.enabled  # no spinner in a log
    status.begin(watch.waiting_text, total=60, plain=True, until=watch.seen, then="startup phase")
    done = threading.Event()
    for _ in range(40):  # the first line comes at the status thread's first tick
        if out.getvalue():
            break
        done.wait(0.05)
    status.close()
    assert out.getvalue().splitlines()[0] == ("waiting for the node's first datagram (its Mission_Ready, "
                                              "or an ACK of a probe) on 0.0.0.0:7889 (up to 60 s)")
