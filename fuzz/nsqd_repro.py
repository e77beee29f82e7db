"""An Nsqd finding's captures: ``repro.mcap`` and ``repro.pcap`` (issue 21 item 3), and its
input files; the finding itself is every protocol's (``fuzz.findings``, issue 37).

The last confirming replay of a finding runs with a ``fuzz.finding_files.TrafficLog`` as its session's
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

from pathlib import Path
from typing import Any

from mcp_conform.fuzz.finding_files import TrafficLog, write_repro_mcap
from mcp_conform.fuzz.findings import Finding
from mcp_conform.spec import NSQD
from mcp_conform.spec.profiles import NSQD_PROFILE
from mcp_conform.traceio.reader import StreamEvent
from mcp_conform.traceio.tcp_pcap import write_tcp_pcap

__all__ = ["TrafficLog", "write_finding_files", "write_stream_repro"]


def write_stream_repro(d: Path, doc: dict[str, Any], records: list[Any]) -> None:
    """``d/repro.mcap`` and ``d/repro.pcap`` of a finding (``doc``: its finding.json)."""
    order: dict[int, int] = {}  # the session's connection numbers, 1, 2, ... as they appear here
    records = [r._replace(conn=order.setdefault(r.conn, len(order) + 1)) for r in records]
    name = NSQD_PROFILE.name

    def write(rec: Any) -> None:
        for r in records:
            if type(r) is StreamEvent:
                rec.stream_event(r.event, protocol=name, conn=r.conn, peer=r.backend, local=r.client, by=r.by,
                                 how=r.how, t_ns=r.t_ns)
            else:
                rec.stream_frame(r.direction, r.raw, protocol=name, conn=r.conn, peer=None, name=r.name,
                                 problem=r.problem, msg_id=r.raw[4] if len(r.raw) > 4 and not r.problem else None,
                                 t_ns=r.t_ns)

    write_repro_mcap(d, doc, NSQD_PROFILE.default_role.name, (r.t_ns for r in records), write,
                     evidence=doc.get("detail"), protocol=name, description=doc.get("description"))
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
