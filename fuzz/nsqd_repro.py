"""An Nsqd finding's captures: ``repro.mcap`` and ``repro.pcap`` (issue 21 item 3), and its
input files; the finding itself is every protocol's (``fuzz.findings``, issue 37).

The last confirming replay of a finding runs with a :class:`TrafficLog` as its session's
recorder, so both files hold that replay's traffic as it happened: each connection opened,
every write of the fuzzer and every frame of the backend with its time, and each close with
who closed and how (FIN or RST; a backend that died closes too). ``repro.mcap`` is the
project's capture (``/nsqd/tx``, ``/nsqd/rx``, ``/nsqd/conn``, the finding's case marks)
whose ``mcp-conform`` metadata record, recorder ``mcp-fuzz``, holds ``protocol: nsqd`` and
the whole ``finding.json`` under ``finding``: ``fuzz.findings.read_finding`` reads it back
from there as from ``finding-N/``. ``repro.pcap`` is the same traffic as TCP packets
(``traceio.tcp_pcap``: handshake, sequence numbers, FIN/RST), which tshark's "Follow TCP
stream" turns back into the input's bytes. ``mcp-capture replay`` of either (or of the
directory) replays the finding as ``mcp-fuzz --protocol nsqd --replay`` does.
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any

from mcp_conform.fuzz.findings import Finding
from mcp_conform.spec import NSQD
from mcp_conform.spec.profiles import NSQD_PROFILE
from mcp_conform.traceio.reader import StreamEvent, StreamFrame
from mcp_conform.traceio.recorder import FUZZ_RECORDER, McapRecorder, run_metadata
from mcp_conform.traceio.tcp_pcap import write_tcp_pcap

__all__ = ["TrafficLog", "write_finding_files", "write_stream_repro"]


def _addr(a: Any) -> tuple[str, int] | None:
    return (str(a[0]), int(a[1])) if isinstance(a, (tuple, list)) and len(a) >= 2 else None


class TrafficLog:
    """A session recorder (``Conn.recorder``) that keeps the stream records in memory."""

    def __init__(self) -> None:
        self.records: list[Any] = []
        self.peers: dict[int, Any] = {}
        self.done = False

    def stream_frame(self, direction: str, raw: bytes, *, conn: int, peer: Any = None, problem: str | None = None,
                     name: str | None = None, t_ns: int | None = None, **_: Any) -> None:
        if not self.done:
            self.records.append(StreamFrame(len(self.records), t_ns or time.time_ns(), direction, conn, name,
                                            problem, bytes(raw)))

    def stream_event(self, event: str, *, conn: int, peer: Any = None, local: Any = None, by: str | None = None,
                     how: str | None = None, t_ns: int | None = None, **_: Any) -> None:
        if not self.done:
            self.records.append(StreamEvent(t_ns or time.time_ns(), event, conn, _addr(local), _addr(peer), by, how))

    def case_mark(self, *a: Any, **kw: Any) -> None:
        """(The session's case marks are not this log's: the finding writes its own.)"""


def write_stream_repro(d: Path, doc: dict[str, Any], records: list[Any]) -> None:
    """``d/repro.mcap`` and ``d/repro.pcap`` of a finding (``doc``: its finding.json)."""
    rule = str(doc.get("rule", ""))
    order: dict[int, int] = {}  # the session's connection numbers, 1, 2, ... as they appear here
    records = [r._replace(conn=order.setdefault(r.conn, len(order) + 1)) for r in records]
    meta = run_metadata(FUZZ_RECORDER, protocol=NSQD_PROFILE.name, role=NSQD_PROFILE.default_role.name, rule=rule,
                        description=doc.get("description"), finding=doc)
    t0 = (records[0].t_ns - 1) if records else time.time_ns()
    t_end = (max(r.t_ns for r in records) + 1) if records else t0 + 1
    case = f"finding:{rule}"
    with McapRecorder(d / "repro.mcap", library=FUZZ_RECORDER, metadata=meta) as rec:
        rec.case_mark(case, "start", t0, rules=(rule,))
        for r in records:
            if type(r) is StreamEvent:
                rec.stream_event(r.event, protocol=NSQD_PROFILE.name, conn=r.conn, peer=r.backend, local=r.client, by=r.by, how=r.how,
                                 t_ns=r.t_ns)
            else:
                rec.stream_frame(r.direction, r.raw, protocol=NSQD_PROFILE.name, conn=r.conn, peer=None, name=r.name, problem=r.problem,
                                 msg_id=r.raw[4] if len(r.raw) > 4 and not r.problem else None, t_ns=r.t_ns)
        rec.case_mark(case, "end", t_end, outcome="failed", rules=(rule,), evidence=doc.get("detail"))
    write_tcp_pcap(d / "repro.pcap", records, NSQD.port(NSQD_PROFILE.default_role.name))


def write_finding_files(d: Path, f: Finding) -> None:
    """An Nsqd finding's own files in ``d`` (``fuzz.findings.FindingStore``'s ``repro``):
    repro.mcap and repro.pcap of its confirming replay's traffic, its input as hex and as a
    Python bytes literal, its stderr excerpt."""
    write_stream_repro(d, f.to_json(), f.traffic)
    data = b"".join(bytes.fromhex(w["hex"]) for w in f.doc.get("writes", []))
    (d / "input.hex").write_text(data.hex(" ") + "\n")
    (d / "input.py").write_text(f"# {f.signature.describe() if f.signature else f.shape}\nINPUT = {data!r}\n")
    (d / "stderr.txt").write_text("\n".join(f.evidence) + "\n")
