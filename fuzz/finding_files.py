"""A finding on disk, whatever its protocol (issue 37 item 2: one findings store).

Every campaign writes a confirmed finding as ``finding-N/`` under ``--out``: its
``finding.json`` (the protocol's document: ``fuzz.findings`` for MCP, ``fuzz.nsqd_triage``
for Nsqd), its ``replay.txt`` (the one command that replays it, ``mcp-fuzz [--protocol P]
--replay DIR ...``) and its captures (the protocol's rendering: ``repro.mcap``, and for a
stream protocol ``repro.pcap``). A finding is read back by :func:`read_finding_doc` from the
directory, its finding.json, its repro.mcap (the ``finding`` value of the ``mcp-fuzz``
metadata record, ``traceio.recorder.FUZZ_RECORDER``) or its repro.pcap (the finding.json
beside it). What the document's fields mean is the protocol's.
"""

from __future__ import annotations

import json
import shlex
import time
from collections.abc import Callable, Iterable
from pathlib import Path
from typing import Any

__all__ = ["TrafficLog", "finding_dir", "read_finding_doc", "write_finding_doc", "write_packets_repro",
           "write_repro_mcap"]

_PCAP_MAGICS = (b"\xd4\xc3\xb2\xa1", b"\xa1\xb2\xc3\xd4", b"\x4d\x3c\xb2\xa1", b"\xa1\xb2\x3c\x4d")


def finding_dir(out: Path, n: int) -> Path:
    """``out/finding-N``, created."""
    d = out / f"finding-{n}"
    d.mkdir(parents=True, exist_ok=True)
    return d


def write_finding_doc(d: Path, doc: dict[str, Any], replay: list[str]) -> None:
    """``d/finding.json`` (``doc``) and ``d/replay.txt``: ``mcp-fuzz`` with ``replay``'s words,
    ``{dir}`` standing for the directory's absolute path."""
    (d / "finding.json").write_text(json.dumps(doc, indent=2) + "\n")
    where = str(d.resolve())
    (d / "replay.txt").write_text(shlex.join(["mcp-fuzz", *(where if w == "{dir}" else w for w in replay)]) + "\n")


def read_finding_doc(path: str | Path, *, mcap: bool = True) -> dict[str, Any]:
    """A finding's JSON document from ``finding-N/``, its finding.json, its repro.pcap (the
    finding.json beside it) or, with ``mcap``, its repro.mcap (the metadata record); ValueError
    (one line) when it is none of those. Which protocol's it is, the caller checks."""
    p = Path(path)
    if p.is_dir():
        p = p / "finding.json"
    try:
        with open(p, "rb") as f:
            head = f.read(8)
    except OSError as exc:
        raise ValueError(f"cannot read {str(p)!r}: {exc.strerror}") from None
    if head[:4] in _PCAP_MAGICS and (p.parent / "finding.json").is_file():
        p, head = p.parent / "finding.json", b"{"
    if mcap and head.startswith(b"\x89MCAP"):
        from mcp_conform.traceio.reader import CaptureError, Metadata, open_capture
        from mcp_conform.traceio.recorder import FUZZ_RECORDER

        try:
            meta = next((r.data for r in open_capture(p) if type(r) is Metadata
                         and r.data.get("recorder") == FUZZ_RECORDER), None)
        except CaptureError as exc:
            raise ValueError(str(exc)) from None
        if meta is None or "finding" not in meta:
            raise ValueError(f"{str(p)!r} is not a finding's repro.mcap")
        text = meta["finding"]
    else:
        try:
            text = p.read_text(errors="replace")
        except OSError as exc:
            raise ValueError(f"cannot read {str(p)!r}: {exc.strerror}") from None
    try:
        doc = json.loads(text)
    except (json.JSONDecodeError, RecursionError) as exc:
        raise ValueError(f"{str(p)!r} is not JSON: {getattr(exc, 'msg', exc)}") from None
    if not isinstance(doc, dict):
        raise ValueError(f"{str(p)!r} is not a finding: not a JSON object")
    return doc


def write_repro_mcap(d: Path, doc: dict[str, Any], role: str, times: Iterable[int], write: Callable[[Any], None],
                     *, evidence: Any = None, name: str = "repro.mcap", **meta: Any) -> None:
    """``d/repro.mcap`` (``name``) of a finding (``doc``: its finding.json, whole in the
    ``mcp-fuzz`` metadata record, which :func:`read_finding_doc` reads back; ``meta``: that
    record's other keys, the protocol among them): the traffic of its last confirming replay,
    written by ``write(recorder)`` at ``times`` (ns), between the finding's case marks (its
    ``rule``; ``evidence``: the end mark's)."""
    from mcp_conform.traceio.recorder import FUZZ_RECORDER, McapRecorder, run_metadata

    rule = str(doc.get("rule", ""))
    ts = list(times)
    t0 = (min(ts) - 1) if ts else time.time_ns()
    t_end = (max(ts) + 1) if ts else t0 + 1
    with McapRecorder(d / name, library=FUZZ_RECORDER,
                      metadata=run_metadata(FUZZ_RECORDER, role=role, rule=rule, finding=doc, **meta)) as rec:
        rec.case_mark(f"finding:{rule}", "start", t0, rules=(rule,))
        write(rec)
        rec.case_mark(f"finding:{rule}", "end", t_end, outcome="failed", rules=(rule,), evidence=evidence)


def write_packets_repro(path: Path, f: Any, role: str, traffic: list[Any] | None, sent: str,
                        write: Callable[[Any, tuple[Any, ...]], None], **meta: Any) -> None:
    """``path`` (a ``repro.mcap``, :func:`write_repro_mcap`) of a finding ``f`` of a datagram or
    packet protocol (MCP's, MAVLink's): the records (direction, t_ns, data, ...) of its
    confirming replay's ``traffic``, else its input (``f.datagrams``, hex) as the fuzzer sent it
    (direction ``sent``, a microsecond apart), each written by ``write(recorder, record)``."""
    t0 = time.time_ns()
    records = traffic or [(sent, t0 + i * 1000, bytes.fromhex(h)) for i, h in enumerate(f.datagrams)]

    def write_all(rec: Any) -> None:
        for r in records:
            write(rec, r)

    write_repro_mcap(path.parent, f.to_json(), role, (r[1] for r in records), write_all, name=path.name, **meta)


def _addr(a: Any) -> tuple[str, int] | None:
    return (str(a[0]), int(a[1])) if isinstance(a, (tuple, list)) and len(a) >= 2 else None


class TrafficLog:
    """A stream session's recorder (``Conn.recorder``) that keeps its records in memory: the
    traffic of a stream protocol's confirming replay, for its finding's repro files."""

    def __init__(self) -> None:
        self.records: list[Any] = []
        self.peers: dict[int, Any] = {}
        self.done = False

    def stream_frame(self, direction: str, raw: bytes, *, conn: int, peer: Any = None, problem: str | None = None,
                     name: str | None = None, t_ns: int | None = None, **_: Any) -> None:
        from mcp_conform.traceio.reader import StreamFrame

        if not self.done:
            self.records.append(StreamFrame(len(self.records), t_ns or time.time_ns(), direction, conn, name,
                                            problem, bytes(raw)))

    def stream_event(self, event: str, *, conn: int, peer: Any = None, local: Any = None, by: str | None = None,
                     how: str | None = None, t_ns: int | None = None, **_: Any) -> None:
        from mcp_conform.traceio.reader import StreamEvent

        if not self.done:
            self.records.append(StreamEvent(t_ns or time.time_ns(), event, conn, _addr(local), _addr(peer), by, how))

    def case_mark(self, *a: Any, **kw: Any) -> None:
        """(The session's case marks are not this log's: the finding writes its own.)"""
