"""``mcp-capture check|show|diff|export|replay`` on an Nsqd capture (``--protocol nsqd``, issue 21
item 4): the capture tools Nsqd's profile names (``spec.profiles``), which
``captures.cli.capture_tools`` hands each subcommand (``captures.cli.CaptureTools``), as
MCP's are ``captures.mcp``. :func:`is_capture` is how the profile recognises its captures.

The capture is our MCAP (``mcp-conform --protocol nsqd --capture``, a fuzz finding's
repro.mcap) or a pcap/pcapng of the TCP traffic (tcpdump, Wireshark, a finding's repro.pcap),
read through ``traceio.nsqd`` (pcaps reassembled by ``traceio.tcp``: out-of-order and
retransmitted segments, both directions, any number of connections, bounded in memory).

- ``check``: every backend's frames judged by ``judge.nsqd_monitor`` — the judgement the
  runner's connections and the fuzzer make live (NSQD-FRM-1: lengths; NSQD-MSG-2: ids,
  layouts, UPDATE.state). Exit 0 no rule broken, 1 broken, 2 unreadable. The rules the
  runner's cases judge by what they send (effects, closes, timing) need the cases; a capture
  shows only what the backends sent. A connection with bytes missing from the capture is
  judged up to the gap, and the output says so.
- ``show``: the connections and their traffic, one line per write, frame and event.
- ``diff``: per connection (in order), the client's writes and the backend's answers —
  frames, with repeated identical ones folded (UPDATE's period differs run to run), and how
  the connection ended. Exit 0 same, 1 different.
- ``export``: the conversations as a pcap/pcapng tshark follows (``traceio.tcp_pcap``; the
  command, its errors and its output are ``captures.export``'s, as for MCP).
- ``replay``: an Nsqd fuzz finding (``finding-N/``, its finding.json, repro.mcap or
  repro.pcap), replayed as ``mcp-fuzz --protocol nsqd --replay`` does.
"""

from __future__ import annotations

import sys
from collections.abc import Iterator
from pathlib import Path
from typing import Any, TextIO

from mcp_conform.captures import stream_tools, trace_tools
from mcp_conform.judge.nsqd_monitor import StreamMonitor
from mcp_conform.spec import NSQD
from mcp_conform.spec.nsqd_codec import Deframer, Frame, decode_body
from mcp_conform.traceio.nsqd import BACKEND_PORT, is_stream_capture, stream_records
from mcp_conform.traceio.reader import StreamFrame

__all__ = ["PLUGIN", "is_capture", "is_finding"]


def is_finding(path: str | Path) -> bool:
    """``path`` is an Nsqd fuzz finding: its directory, finding.json, repro.mcap or repro.pcap."""
    from mcp_conform.fuzz.findings import read_finding

    try:
        read_finding(path, "nsqd")
    except (ValueError, OSError):
        return False
    return True



class _Nsqd(stream_tools.StreamPlugin):
    name, spec, a_capture, html_instead, title = "nsqd", NSQD, "an Nsqd capture", "use show --svg", "Nsqd capture"
    monitor, port, EXPORTED = StreamMonitor, BACKEND_PORT, "TCP packets"
    unreplayed = "an Nsqd capture is replayed as a fuzz finding only (its directory, finding.json, repro.mcap or repro.pcap)"

    def records(self, path: str) -> Iterator[Any]:
        return stream_records(path)

    def deframer(self) -> Deframer:
        return Deframer(NSQD)

    def client_step(self, item: Any) -> str:
        return str(item.raw.hex()) if isinstance(item, Frame) else f"unframed: {item.reason}"

    def answer(self, rec: StreamFrame) -> tuple[str, str]:
        """The backend's frame as the diff compares it: UPDATE by its state (its period differs
        run to run, and repeated identical ones are folded)."""
        if rec.problem:
            return "frame", f"refused: {rec.problem}"
        if rec.name != "UPDATE":
            return "frame", rec.name or f"id {rec.raw[4] if len(rec.raw) > 4 else '?'}"
        item = Deframer(NSQD).feed(rec.raw)
        state = None
        if item and isinstance(item[0], Frame):
            try:
                state = decode_body(NSQD, item[0].msg_id, item[0].body, check_text=False).as_dict().get("state")
            except ValueError:
                state = None
        return "frame", f"UPDATE state {NSQD.state_name(state) if state is not None else '?'}"

    def chart(self, frames: list[StreamFrame], title: str) -> str:
        from mcp_conform.reports.nsqd_chart import stream_svg

        return stream_svg(frames, title=title)

    def run_replay(self, args: Any, out: TextIO | None = None, err: TextIO | None = None) -> int:
        """Replay an Nsqd finding as ``mcp-fuzz --protocol nsqd --replay`` does (exit 1: it
        reproduced, 0: it did not, 2: unreadable, no finding or no backend)."""
        from mcp_conform.fuzz.nsqd_replay import replay_stream_finding
        from mcp_conform.harness.errors import SetupError

        if not is_finding(args.capture):
            return trace_tools.not_replayed(err, args.capture, self.unreplayed)
        try:
            return replay_stream_finding(str(args.capture), args.target, args.spawn, prog="mcp-capture replay")
        except SetupError as exc:
            (err or sys.stderr).write(f"mcp-capture: error: replay: {exc}\n")
            return 2


def is_capture(path: str | Path) -> bool:
    """Nsqd's ``capture_detect``: an Nsqd capture (``traceio.nsqd.is_stream_capture``), or a
    finding's directory or finding.json (what ``replay`` takes besides its captures)."""
    if Path(path).is_dir() or Path(path).name == "finding.json":
        return is_finding(path)
    return is_stream_capture(path)


PLUGIN = _Nsqd()
