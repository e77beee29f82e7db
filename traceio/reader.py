"""One reader for every capture ``mcp-capture`` takes: our MCAP files, pcap and pcapng.

``open_capture(path)`` returns a :class:`Capture`; iterating it yields, in file order, one
stream of typed records:

- :class:`Datagram` — one UDP datagram that is (or may be) MCP: ``index`` (0, 1, 2, ... over
  the datagrams of the capture, the index the monitor's evidence uses), ``t_ns``, ``src_addr``
  and ``dst_addr`` (``(host, port)`` or ``None`` where the capture does not say), ``data``,
  ``direction`` (``"tx"`` sent by the recording host, ``"rx"`` received by it, ``None``
  unknown) and ``recorder`` (the MCAP writer's library, the pcapng interface name, or None);
- :class:`MavlinkFrame` — a frame on the autopilot link (our MCAP ``/mavlink``);
- :class:`CaseMark` — a conformance case's start or end (``/conformance/case``);
- :class:`Metadata` — an MCAP metadata record (tool and spec versions, target, seed);
- :class:`Truncated` — last, and only when the file ends early (a run killed by SIGKILL, a
  full disk, a copy cut short) or holds garbage after its last whole record: the records
  before it are all there is. ``Capture.truncated`` holds the same reason after iteration.

The record types are ``traceio.records``' (imported here too, so ``traceio.reader`` names
them as before).

Formats:

- MCAP as ``traceio.recorder`` writes it, read sequentially with ``mcap``'s StreamReader
  (CRCs validated), so a file without its summary and footer is read up to its last whole
  chunk.
- pcap (micro- and nanosecond, either byte order, gzip'd too) and pcapng, through dpkt's
  readers and block classes (``traceio.packets``: bytes and metadata, no dissection). Link types: Ethernet (802.1Q tags too),
  Linux cooked SLL and SLL2, raw IP, BSD loopback (null) and OpenBSD loop. IPv4 UDP only;
  IP fragments are reassembled (``Capture.notes`` says how many, and how many stayed
  incomplete). A datagram is MCP when it starts with the spec's 9-byte preamble, on any
  port; a datagram without it is kept too (for MCP-ROB-*) when it goes to or comes from an
  address that has carried MCP, or to one of the spec's conventional ports (MCP-TRN-1).
  Datagrams cut by the capture's snap length are dropped and counted.

Unreadable input raises :class:`CaptureError` with a one-line reason naming the file, and so
does a count read from the file that the file cannot stand for (a ``/mcp/burst`` record
claiming more than :data:`MAX_BURST` datagrams, or all of them more than
:data:`MAX_BURST_TOTAL`), checked before anything is expanded.
"""

from __future__ import annotations

import gzip
import heapq
import json
import os
import zlib
from binascii import a2b_base64
from collections import Counter
from collections.abc import Iterator
from functools import lru_cache
from pathlib import Path
from typing import IO, Any

from orjson import JSONDecodeError
from orjson import loads as _fast_loads

from mcp_conform.spec import SPEC
from mcp_conform.spec.codec import PREAMBLE
from mcp_conform.traceio.channels import STREAM_CHANNELS
from mcp_conform.traceio.packets import (
    FRAGMENT,
    LINKS,
    DecompressionBomb,
    GuardedStream,
    HeaderError,
    Reassembly,
    open_packets,
)
from mcp_conform.traceio.records import (
    CaptureError,
    CaseMark,
    Datagram,
    MavlinkFrame,
    Metadata,
    Record,
    StreamEvent,
    StreamFrame,
    Truncated,
    VehicleMark,
)

__all__ = [
    "Capture",
    "CaptureError",
    "CaseMark",
    "Datagram",
    "MavlinkFrame",
    "Metadata",
    "Record",
    "StreamEvent",
    "StreamFrame",
    "Truncated",
    "VehicleMark",
    "head_of",
    "is_mcap_head",
    "open_capture",
]


#: every stream protocol's frame topics (-> "tx"/"rx") and connection topics, as
#: ``traceio.channels.stream_topics`` names them after the protocol
_STREAM_FRAMES = {t: d for t in STREAM_CHANNELS for d in ("tx", "rx") if t.endswith("/" + d)}
_STREAM_CONNS = frozenset(t for t in STREAM_CHANNELS if t.endswith("/conn"))
_MCAP_MAGIC = b"\x89MCAP0\r\n"
_PCAPNG_MAGIC = b"\x0a\x0d\x0d\x0a"
_PCAP_MAGICS = {b"\xa1\xb2\xc3\xd4", b"\xd4\xc3\xb2\xa1", b"\xa1\xb2\x3c\x4d", b"\x4d\x3c\xb2\xa1"}
_GZIP_MAGIC = b"\x1f\x8b"
MCP_PORTS: frozenset[int] = frozenset(SPEC.protocol["ports"].values())
#: How far (ns) an MCAP record may be written after a later one and still come out in order.
REORDER_NS = 1_000_000_000
#: where a raw record's fields hold its session (segment), by kind (``_mcap_raw``)
_SEGMENT_FIELD = {"d": 6, "m": 3, "v": 3, "c": 4}
#: The most datagrams one ``/mcp/burst`` record may stand for: a burst is a flood the runner
#: really sent (MCP-ROB-7's ``flood_count``, 10,000), so ten times that is generous; a file
#: claiming more is rejected before anything is expanded (issue 19 item 2: a 1.2 KB file
#: claiming 10^12 grew without end in every tool that read it).
MAX_BURST = 10 * int(SPEC.params["flood_count"])
#: The most datagrams all the bursts of one file may stand for together.
MAX_BURST_TOTAL = 100 * int(SPEC.params["flood_count"])


def head_of(path: str | Path, n: int, what: str) -> tuple[int, bytes]:
    """(size, first ``n`` bytes) of a file read as ``what`` (a capture; a protocol's own trace
    file, ``traceio.mavlink``'s tlog); CaptureError (one line naming the file) when it cannot
    be read or is empty."""
    try:
        size = os.path.getsize(path)
        with open(path, "rb") as f:
            head = f.read(n)
    except OSError as exc:
        raise CaptureError(f"{path}: cannot read: {exc.strerror or exc}") from None
    if size == 0:
        raise CaptureError(f"{path}: empty file, not {what}")
    return size, head


def is_mcap_head(head: bytes) -> bool:
    """A file's first bytes are an MCAP's magic (or all there is of it)."""
    return head[:8] == _MCAP_MAGIC or (len(head) < 8 and _MCAP_MAGIC.startswith(head))


def open_capture(path: str | Path, segment: str | None = None) -> Capture:
    """Open ``path`` (MCAP, pcap or pcapng); raises :class:`CaptureError`. ``segment``: only
    that session's records of a merged capture (see :class:`Capture`)."""
    return Capture(path, segment)


class Capture:
    """An opened capture; iterate it once for its records (see the module docstring).

    After iteration: ``truncated`` (the reason, or None), ``notes`` (what was skipped or
    reassembled, one line each), ``counts`` (records by kind and skips by reason),
    ``segments`` (the sessions of a merged capture, in order of appearance).

    Segments: an MCAP file merged from pytest-xdist workers (``traceio.merge``) holds one
    session per worker, each with its own node under test and runner. Every record of a
    segment says so (``segment``: ``gw0``, ...; None in an unmerged capture), its datagrams
    carry their own writer as ``recorder``, and its metadata records carry the segment in
    their data. With ``segment`` given, only that session's records are yielded (metadata
    records of other segments left out); datagram indexes stay the whole file's.
    """

    def __init__(self, path: str | Path, segment: str | None = None) -> None:
        self.path = Path(path)
        self.segment = segment
        self.segments: list[str] = []
        self.truncated: str | None = None
        self.corrupt = False  # the reading stopped at corruption (a failed CRC, garbage), not a cut
        self.counts: Counter[str] = Counter()
        self.linktypes: set[int] = set()
        self._fragments_open = 0
        name = str(self.path)
        head = head_of(self.path, 8, "a capture")[1]
        if head.startswith(_GZIP_MAGIC):
            try:
                with gzip.open(self.path, "rb") as g:
                    inner = g.read(4)
            except (OSError, EOFError, zlib.error) as exc:
                raise CaptureError(f"{name}: corrupt gzip stream: {exc}") from None
            kind = "pcapng" if inner == _PCAPNG_MAGIC else "pcap" if inner in _PCAP_MAGICS else None
            if kind is None:
                raise CaptureError(f"{name}: gzip'd file is not a pcap or pcapng capture")
            self.format = kind + ".gz"
            head = inner
        elif head == _MCAP_MAGIC:
            self.format = "mcap"
        elif _MCAP_MAGIC.startswith(head) and len(head) < 8:
            raise CaptureError(f"{name}: MCAP file cut inside its magic ({len(head)} bytes)")
        elif head[:4] == _PCAPNG_MAGIC:
            self.format = "pcapng"
        elif head[:4] in _PCAP_MAGICS:
            self.format = "pcap"
        else:
            raise CaptureError(f"{name}: not a capture (starts {head[:4].hex(' ')}); "
                               "mcp-capture reads MCAP, pcap and pcapng")
        self._reader: Any = None
        if self.format != "mcap":
            self._reader = self._open_packets(head[:4])

    # ------------------------------------------------------------------ public
    @property
    def notes(self) -> list[str]:
        c = self.counts
        out = []
        if c["fragments_reassembled"]:
            out.append(f"{c['fragments_reassembled']} IP-fragmented datagram(s) reassembled")
        if self._fragments_open:
            out.append(f"{self._fragments_open} IP-fragmented datagram(s) incomplete at the end "
                       "of the capture, dropped")
        for key, text in (("snaplen_cut", "UDP datagram(s) cut by the snap length, dropped"),
                          ("fragments_evicted", "IP fragment group(s) never completed, dropped"),
                          ("ipv6", "IPv6 packet(s) skipped (MCP travels on IPv4)"),
                          ("not_udp", "non-UDP or non-IP packet(s) skipped"),
                          ("udp_other", "UDP datagram(s) of other protocols skipped"),
                          ("bad_ip", "malformed IP/UDP header(s) skipped"),
                          ("trailing_bytes", "byte(s) after the MCAP footer ignored"),
                          ("mcap_bad_message", "MCAP message(s) not readable as our records, skipped"),
                          ("loopback_copy", "outgoing loopback copies skipped (seen again incoming)"),
                          ("unknown_interface", "pcapng packet(s) naming an interface the file does not "
                                                "describe, skipped")):
            if c[key]:
                out.append(f"{c[key]} {text}")
        for lt in sorted(self.linktypes - set(LINKS)):
            out.append(f"link type {lt} is not one mcp-capture reads; its packets were skipped")
        return out

    def __iter__(self) -> Iterator[Record]:
        read = 0
        try:
            for rec in self._mcap() if self.format == "mcap" else self._packets():
                if type(rec) is not Metadata:
                    read += 1
                yield rec
        finally:
            if self._reader is not None:
                self._reader.close()
        if self.truncated is not None:
            if self.corrupt and not read:
                # corruption before anything could be read: an error, never an empty "OK"
                raise CaptureError(f"{self.path}: {self.format} file corrupt, nothing could be read: "
                                   f"{self.truncated}")
            yield Truncated(self.truncated)

    def datagrams(self) -> Iterator[Datagram]:
        """Only the datagrams."""
        for rec in self:
            if type(rec) is Datagram:
                yield rec

    # ------------------------------------------------------------------ MCAP
    def _mcap(self) -> Iterator[Record]:
        """Records in log_time order: the recorder's threads may write a datagram a little
        after a later one (an ACK received while its command's record is being written), so
        records wait in a heap until the file has moved :data:`REORDER_NS` past them."""
        order: list[tuple[int, int, str, Any, Any]] = []  # (log_time, file position, kind, fields, segment)
        n = {"d": 0, "m": 0, "s": 0}
        #: the newest log_time of each session: a session's records are held until the file
        #: has moved past them in *that* session (a session written late, with the times its
        #: datagrams arrived -- a scenario run beside the main one, its traffic held until
        #: its case asks -- is put in order among itself, as its live monitor did)
        newest: dict[Any, int] = {}
        want = self.segment
        push, pop = heapq.heappush, heapq.heappop
        rec: Record
        for pos, (t, kind, fields) in enumerate(self._mcap_raw()):
            if kind == "meta":
                seg = fields[1].get("segment")
                if seg is not None and seg not in self.segments:
                    self.segments.append(seg)
                if want is None or seg in (None, want):
                    yield Metadata(*fields)
                continue
            seg = fields[_SEGMENT_FIELD[kind]] if kind in _SEGMENT_FIELD else None
            push(order, (t, pos, kind, fields, seg))
            if t > newest.get(seg, -1):
                newest[seg] = t
            while order and order[0][0] < newest[order[0][4]] - REORDER_NS:
                item = pop(order)
                if item[2] == "d":  # _mcap_record's, inline: most records are datagrams
                    i = n["d"]
                    n["d"] = i + 1
                    rec = Datagram(i, item[0], *item[3])
                else:
                    rec = self._mcap_record(item, n)
                if want is None or getattr(rec, "segment", None) == want:
                    yield rec
        while order:
            rec = self._mcap_record(heapq.heappop(order), n)
            if want is None or getattr(rec, "segment", None) == want:
                yield rec

    @staticmethod
    def _mcap_record(item: tuple[int, int, str, Any, Any], n: dict[str, int]) -> Record:
        t, _pos, kind, fields, _seg = item
        if kind == "d":
            n["d"] += 1
            return Datagram(n["d"] - 1, t, *fields)
        if kind == "m":
            n["m"] += 1
            return MavlinkFrame(n["m"] - 1, t, *fields)
        if kind == "v":
            return VehicleMark(t, *fields)
        if kind == "e":
            return StreamEvent(t, *fields)
        if kind == "s":
            n["s"] += 1
            return StreamFrame(n["s"] - 1, t, *fields)
        return CaseMark(t, *fields)

    def _mcap_raw(self) -> Iterator[tuple[int, str, Any]]:
        from mcap.records import Channel, Chunk, Header, Message
        from mcap.records import Metadata as McapMetadata

        from mcp_conform.traceio.mcap_chunks import Message as ChunkMessage
        from mcp_conform.traceio.mcap_chunks import chunk_records, stream_reader

        size = self.path.stat().st_size
        topics: dict[int, str] = {}
        library: str | None = None
        segments: dict[int, str] = {}  # channel -> its segment (merged captures)
        writers: dict[int, str] = {}  # channel -> its segment's writer
        seen = self.segments
        bursts = burst_total = 0
        b64 = a2b_base64
        loads, fast = _json_body, _datagram_body
        with open(self.path, "rb") as f:
            # chunks split by traceio.mcap_chunks: as mcap splits them, at C speed (issue 17)
            reader = stream_reader(f, max(size, 64))
            records = reader.records
            chunk: list[Any] = []
            at = 0
            while True:
                if at < len(chunk):
                    rec: Any = chunk[at]
                    at += 1
                else:
                    try:
                        rec = next(records)
                        if type(rec) is Chunk:
                            chunk, at = chunk_records(rec), 0
                            continue
                    except StopIteration:
                        rest = size - f.tell()
                        if rest > 0:
                            self.counts["trailing_bytes"] += rest
                        break
                    except Exception as exc:  # noqa: BLE001 - any failure past the magic is a cut or corrupt tail
                        if _out_of_memory(exc):  # the machine's limit, not the file's fault
                            raise CaptureError(f"{self.path}: out of memory reading it near byte {f.tell()} of {size} "
                                               f"({type(exc).__name__}: {exc})") from None
                        self.truncated, self.corrupt = _mcap_reason(exc, f.tell(), size)
                        break
                kind = type(rec)
                if kind is ChunkMessage or kind is Message:
                    topic = topics.get(rec.channel_id)
                    seg = segments.get(rec.channel_id)
                    lib = writers.get(rec.channel_id, library)
                    try:
                        datagram = topic == "/mcp/tx" or topic == "/mcp/rx"
                        body = (fast if datagram else loads)(rec.data)
                        if datagram:
                            peer = _parse_peer(body.get("peer"))
                            local = _parse_peer(body.get("local"))
                            tx = topic == "/mcp/tx"
                            rd = body.get("run_delay_ns")
                            yield rec.log_time, "d", (local if tx else peer, peer if tx else local,
                                                      b64(body["raw_base64"]), "tx" if tx else "rx", lib,
                                                      False, seg, rd if type(rd) is int and rd >= 0 else None)
                        elif topic == "/mcp/burst":
                            # a flood recorded as a count (traceio.recorder): datagram i is
                            # cycle[i % len(cycle)], times spread evenly over the burst
                            peer, local = _parse_peer(body.get("peer")), _parse_peer(body.get("local"))
                            tx = body.get("direction") == "tx"
                            count, t1, t2 = body["count"], int(body["first_t_ns"]), int(body["last_t_ns"])
                            bursts += 1
                            burst_total += self._burst_count(count, bursts, rec.log_time, burst_total)
                            cycle = [b64(c["raw_base64"]) for c in body["cycle"]]
                            src, dst = (local, peer) if tx else (peer, local)
                            for i in range(count if cycle else 0):
                                yield (t1 + (t2 - t1) * i // max(1, count - 1), "d",
                                       (src, dst, cycle[i % len(cycle)], "tx" if tx else "rx", lib,
                                        True, seg))
                        elif topic == "/mavlink":
                            yield rec.log_time, "m", (body.get("direction"), body.get("msg_type"),
                                                      b64(body["raw_base64"]), seg)
                        elif topic == "/vehicle":
                            drone = body.get("drone")
                            yield rec.log_time, "v", (str(body["kind"]),
                                                      drone if isinstance(drone, int) else None,
                                                      body.get("detail"), seg)
                        elif topic in _STREAM_FRAMES:
                            yield rec.log_time, "s", (_STREAM_FRAMES[topic], int(body["conn"]), body.get("name"),
                                                      body.get("problem"), b64(body["raw_base64"]))
                        elif topic in _STREAM_CONNS:
                            yield rec.log_time, "e", (str(body["event"]), int(body["conn"]),
                                                      _parse_peer(body.get("local")), _parse_peer(body.get("peer")),
                                                      body.get("by"), body.get("how"))
                        elif topic == "/conformance/case":
                            yield rec.log_time, "c", (str(body["case"]), str(body["event"]),
                                                      body.get("outcome"), tuple(body.get("rules") or ()),
                                                      seg)
                        else:
                            self.counts["mcap_other_topic"] += 1
                    except (ValueError, KeyError, TypeError, AttributeError, OverflowError, RecursionError):
                        self.counts["mcap_bad_message"] += 1  # RecursionError: JSON nested past the parser's depth
                elif kind is Channel:
                    topics[rec.id] = rec.topic
                    seg = rec.metadata.get("segment")
                    if seg:
                        segments[rec.id] = seg
                        if seg not in seen:
                            seen.append(seg)
                        if rec.metadata.get("library"):
                            writers[rec.id] = rec.metadata["library"]
                elif kind is Header:
                    library = rec.library or None
                elif kind is McapMetadata:
                    yield 0, "meta", (rec.name, dict(rec.metadata))

    def _burst_count(self, count: Any, n: int, t_ns: int, total: int) -> int:
        """A ``/mcp/burst`` record's ``count``, checked before it is expanded: an integer up to
        :data:`MAX_BURST`, all of the file's up to :data:`MAX_BURST_TOTAL` (else CaptureError,
        one line naming the file and the record); not an integer: a bad message (TypeError)."""
        if type(count) is not int or count < 0:
            raise TypeError("burst count")
        where = f"{self.path}: /mcp/burst record {n} (log time {t_ns} ns)"
        if count > MAX_BURST:
            raise CaptureError(f"{where} claims {count:,} datagrams; a burst holds at most {MAX_BURST:,} "
                               "(10 x MCP-ROB-7's flood): corrupt or crafted file")
        if total + count > MAX_BURST_TOTAL:
            raise CaptureError(f"{where} brings the file's bursts to {total + count:,} datagrams; at most "
                               f"{MAX_BURST_TOTAL:,} in one file: corrupt or crafted file")
        return count

    # ------------------------------------------------------------------ pcap / pcapng
    def _open_packets(self, magic: bytes) -> Any:
        name = str(self.path)
        self._stream: GuardedStream | None = None
        fd: IO[bytes] | None = None
        stream = None
        try:
            fd = open(self.path, "rb")  # noqa: SIM115 - closed with the reader
            if self.format.endswith(".gz"):
                stream = self._stream = GuardedStream.gzip(fd)
            else:
                stream = GuardedStream.plain(fd)
            return open_packets(stream, magic, self.linktypes)
        except (HeaderError, EOFError, OSError, zlib.error) as exc:
            if stream is not None:
                stream.close()
            elif fd is not None:
                fd.close()
            raise CaptureError(f"{name}: {self.format} file header unreadable "
                               f"(cut short or corrupt): {exc}") from None

    def _stream_failure(self, n_packet: int) -> str | None:
        """A gzip'd capture whose stream failed: why."""
        err = self._stream.error if self._stream is not None else None
        if err is None:
            return None
        if isinstance(err, DecompressionBomb):
            raise CaptureError(f"{self.path}: {err} (after packet {n_packet})")
        if isinstance(err, EOFError):  # the compressed stream ends early: a cut
            return f"gzip stream cut short after packet {n_packet}: {err}"
        self.corrupt = True
        return f"gzip stream corrupt after packet {n_packet} (the packets read may be damaged too): {err}"

    def raw_packets(self) -> Iterator[tuple[int, int, bytes, str | None, str | None]]:
        """(t_ns, link type, bytes, direction, interface name) of each packet record of a
        pcap or pcapng, stopping (``truncated``, ``corrupt``) where the file is cut or bad."""
        yield from self._reader
        self._packets_read()

    def _packets_read(self) -> None:
        """After the packets: what stopped the reading, if anything."""
        reader = self._reader
        self.counts["unknown_interface"] += reader.unknown_interface
        if reader.truncated is not None and self._stream is not None:
            self._stream.drain()  # garbage in a gzip'd capture: did the stream fail its CRC?
        # a gzip stream that failed (mid-way, or at its trailer's CRC after the last record)
        failure = self._stream_failure(reader.count)
        if failure is not None:
            self.truncated = failure
        else:
            self.truncated = reader.truncated
            self.corrupt = self.corrupt or reader.corrupt

    def _packets(self) -> Iterator[Datagram]:
        counts = self.counts
        links = LINKS
        frag = Reassembly(counts)
        known: set[tuple[str, int]] = set()
        mcp_ports = MCP_PORTS
        preamble = PREAMBLE
        pre_len = len(preamble)
        index = 0
        for t_ns, linktype, data, direction, recorder in self._reader:
            parse = links.get(linktype)
            if parse is None:
                counts["not_udp"] += 1
                continue
            got = parse(data, counts)
            if got is None:
                continue
            if got[0] is FRAGMENT:
                got = frag.add(got[1], got[2], t_ns)
                if got is None:
                    continue
            src, dst, payload, link_dir = got
            if link_dir is not None:
                direction = link_dir
            if payload[:pre_len] == preamble:
                known.add(src)
                known.add(dst)
            elif not (src in known or dst in known or dst[1] in mcp_ports):
                counts["udp_other"] += 1
                continue
            yield Datagram(index, t_ns, src, dst, payload, direction, recorder)
            index += 1
        self._packets_read()
        self._fragments_open = frag.open_groups()


def _out_of_memory(exc: BaseException) -> bool:
    """An allocation refused: Python's MemoryError, or a C decompressor's (lz4:
    ``ERROR_allocation_failed``) -- no evidence of a corrupt file."""
    return isinstance(exc, MemoryError) or "allocation_failed" in str(exc) or "Allocation error" in str(exc)


def _mcap_reason(exc: Exception, pos: int, size: int) -> tuple[str, bool]:
    """Why an MCAP file stopped being readable, and whether that is corruption (a failed
    CRC, a chunk that does not decompress) rather than a cut."""
    from mcap.exceptions import EndOfFile, RecordLengthLimitExceeded

    if isinstance(exc, EndOfFile) or pos >= size:
        return (f"file ends inside a record at byte {size} (no summary/footer): read up to the last whole chunk",
                False)
    if isinstance(exc, RecordLengthLimitExceeded):  # longer than the file: cut inside it
        return f"file ends inside a record (at byte {pos} of {size}): read up to the last whole chunk", False
    return f"corrupt record near byte {pos} of {size}: {type(exc).__name__}: {exc}", True


def _json_body(data: bytes) -> Any:
    """``json.loads(data)``: a body starting ``{`` is UTF-8 to ``json.detect_encoding`` (its
    first two bytes are no BOM and not zero), decoded so without asking it."""
    if data[:1] == b"{" and data[1:2] != b"\x00":
        return _decode_json(data.decode("utf-8", "surrogatepass"))
    return json.loads(data)


def _datagram_body(data: bytes) -> Any:
    """A ``/mcp/tx`` or ``/mcp/rx`` body as :func:`_json_body` reads it, through orjson where
    orjson gives the same (2.5 against 8.2 µs a body; check of 10^6 datagrams: 15.5 CPU s, 20 with
    json, issue 17). orjson refuses some of what json reads (NaN, ``1e999``, a lone surrogate,
    UTF-16): those go to json. It reads an integer outside 64 bits as a float, where json keeps
    the integer: of a datagram's body only strings and ``run_delay_ns`` are used, so a body
    whose ``run_delay_ns`` came out a float goes to json too."""
    try:
        body = _fast_loads(data)
    except JSONDecodeError:
        return _json_body(data)
    if type(body) is dict and type(body.get("run_delay_ns")) is float:
        return _json_body(data)
    return body


_decode_json = json.JSONDecoder().decode


def _parse_peer(peer: Any) -> tuple[str, int] | None:
    if not isinstance(peer, str) or ":" not in peer:
        return None
    return _peer(peer)


@lru_cache(maxsize=4096)
def _peer(peer: str) -> tuple[str, int] | None:
    """One tuple per distinct address: a capture of a million datagrams between a few peers
    keeps a few tuples, not two per datagram (issue 19: check of 10^6 violations <= 1 GB)."""
    host, _, port = peer.rpartition(":")
    try:
        return (host.strip("[]"), int(port))
    except ValueError:
        return None
