"""``mcp-capture export CAPTURE --pcap OUT``: a capture as a pcap or pcapng file.

Every datagram of the capture (a burst expanded datagram by datagram) becomes one
Ethernet/IPv4/UDP packet with the capture's addresses, ports and timestamps, built and
written with dpkt (``traceio.pcap_out``): a pcapng (OUT ending in ``.pcapng``; the time cut
to the microsecond) or a pcap (anything else; rounded to the nearest microsecond), both
computed from the capture's integer nanoseconds. Where the capture does not name an address
(a pcap of one side, a wildcard bind) the loopback address stands in, and a missing port is
the spec's conventional port of the sender's role (MCP-TRN-1: the manager on 7889, drones on
7890); an address that is not an IPv4 literal (never looked up), a port past 65535, a
datagram longer than UDP carries or a time the file cannot hold is an error naming the
datagram. Open the result in
Wireshark with ``mcp-capture dissector --install``. :func:`export_pcap` is MCP's (its capture
tools, ``captures.mcp``); each protocol's capture tools write its captures (Nsqd's as TCP
conversations, ``captures.nsqd.export_pcap``), and for every one a capture unreadable
part-way leaves no output, and every error is one line (exit 2).
"""

from __future__ import annotations

import contextlib
import sys
from collections.abc import Iterator
from pathlib import Path
from typing import Any, TextIO

from mcp_conform.spec import SPEC
from mcp_conform.spec.codec import peek_header
from mcp_conform.spec.profiles import MCP

__all__ = ["export_pcap", "register", "run", "whole_or_none"]

_LOOPBACK = "127.0.0.1"


def _fill(addr: Any, mcp_id: int | None) -> tuple[str, int]:
    host, port = (addr[0], addr[1]) if addr else (None, None)
    if not host or host == "0.0.0.0":
        host = _LOOPBACK
    if not port:
        port = SPEC.port(MCP.role_of_id(mcp_id).name)
    return str(host), int(port)


class _Output:
    """The file being written: ``opened`` once its writer has created it."""

    def __init__(self, path: Path) -> None:
        self.path, self.opened = path, False


@contextlib.contextmanager
def whole_or_none(path: Path) -> Iterator[_Output]:
    """``path`` is written whole or not at all: where the input fails part-way (CaptureError)
    or anything else stops the export after the file was opened, the half-written file is
    removed (a file that could not be opened is left as it was)."""
    out = _Output(path)
    done = False
    try:
        yield out
        done = True
    finally:
        if not done and out.opened:
            path.unlink(missing_ok=True)


def export_pcap(capture: str | Path, out: str | Path) -> tuple[int, str | None]:
    """Write ``out``; return (packets written, the capture's truncation reason or None).
    Raises ``traceio.reader.CaptureError`` for unreadable input (a datagram the file cannot
    hold included), OSError for ``out``."""
    from mcp_conform.traceio.pcap_out import FrameError, PacketFile, udp_frame
    from mcp_conform.traceio.reader import CaptureError, Datagram, Truncated, open_capture

    cap = open_capture(capture)
    out = Path(out)
    n = 0
    truncated: str | None = None
    with whole_or_none(out) as output, PacketFile(out) as pcap:
        output.opened = True
        # what the output's timestamp fields hold: pcap 32-bit seconds, pcapng 64-bit microseconds
        ng, t_max_ns = pcap.pcapng, pcap.max_ns
        for rec in cap:
            if type(rec) is Truncated:
                truncated = rec.reason
                continue
            if type(rec) is not Datagram:
                continue
            header = peek_header(rec.data, require_preamble=False)
            dst_id, src_id = (header[0], header[1]) if header else (None, None)
            src, dst = _fill(rec.src_addr, src_id), _fill(rec.dst_addr, dst_id)
            try:
                frame = udp_frame(src, dst, bytes(rec.data))
            except FrameError as exc:
                raise CaptureError(f"{capture}: datagram #{rec.index}: {exc}") from None
            if not 0 <= rec.t_ns <= t_max_ns:
                raise CaptureError(f"{capture}: datagram #{rec.index} is stamped {rec.t_ns / 1e9:.0f} s, "
                                   f"outside what a {'pcapng' if ng else 'pcap'} file's timestamp holds"
                                   + ("" if ng else " (0 to 2^32 s; .pcapng holds more)"))
            pcap.write(frame, rec.t_ns)
            n += 1
    return n, truncated or getattr(cap, "truncated", None)


def register(sub: Any) -> None:
    from mcp_conform.captures.cli import add_protocol_option

    p = sub.add_parser("export", help="write a capture as pcap or pcapng (for Wireshark, tshark)",
                       description="Write every datagram of CAPTURE, with its addresses and "
                                   "timestamps, as a pcapng (OUT.pcapng) or pcap file.")
    p.add_argument("capture", metavar="CAPTURE", help="MCAP, pcap or pcapng capture")
    p.add_argument("--pcap", required=True, metavar="OUT", help="the file to write (.pcapng: pcapng)")
    add_protocol_option(p)
    p.set_defaults(run=run)


def run(args: Any, out: TextIO | None = None, err: TextIO | None = None) -> int:
    """``mcp-capture export``: the capture's protocol's ``export_pcap``; its errors and
    closing line are the same for every protocol."""
    from mcp_conform.captures.cli import capture_tools
    from mcp_conform.traceio.reader import CaptureError

    out = out or sys.stdout
    err = err or sys.stderr
    try:
        tools = capture_tools(args, args.capture)
        n, truncated = tools.export_pcap(args.capture, args.pcap)
    except CaptureError as exc:
        err.write(f"mcp-capture: error: export: {exc}\n")
        return 2
    except OSError as exc:
        err.write(f"mcp-capture: error: export: cannot write {args.pcap}: {exc.strerror}\n")
        return 2
    note = f" (the capture is TRUNCATED: {truncated}; exported up to its last whole record)" if truncated else ""
    out.write(f"wrote {n} {tools.EXPORTED} to {args.pcap}{note}\n")
    return 0
