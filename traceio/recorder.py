"""MCAP recording of a run (docs/design.md "Captures"): the one capture format of mcp-conform.

Every producer writes it (the runner's ``--capture``, ``mcp-node --capture``, ``mcp-fuzz``)
and every ``mcp-capture`` command reads it. One file per run, five channels, every message
JSON (schema encoding ``jsonschema``, raw bytes with ``"contentEncoding": "base64"``; the
schemas are ``traceio.channels``'):

- ``/mcp/tx`` and ``/mcp/rx``: each datagram the recording endpoint (the runner, or the
  node) sent or received, decoded through ``spec.codec`` where it decodes (dst, src, seq,
  action name, a payload summary), else the ``DecodeError``'s rule and reason (and the
  header, when a whole one is there), plus the raw bytes as base64 and hex, the peer
  address and the recording socket's own (``local``) address;
- ``/mcp/burst``: a burst of datagrams sent too fast to record one by one (the flood of
  MCP-ROB-7): how many, to whom, the first and last send times, and the distinct datagrams
  in the order they were cycled (datagram ``i`` of the burst is ``cycle[i % len(cycle)]``);
- ``/mavlink``: frames on the autopilot link, both directions, from the autopilot's point
  of view (``rx``: the autopilot received it from the node; ``tx``: the autopilot sent it),
  with the decoded message (pymavlink's ``to_dict()``) beside the raw bytes;
- ``/conformance/case``: case start and end marks, the end with its outcome.

For Foxglove (issue 24; :mod:`traceio.fox`, schemas from ``foxglove-sdk``): the vehicle's
position (``/vehicle/location``, ``foxglove.LocationFix``, the Map panel) and attitude
(``/vehicle/attitude``, ``foxglove.PoseInFrame``) from the autopilot's GLOBAL_POSITION_INT
and ATTITUDE, and ``/log`` (``foxglove.Log``, the Log panel): case started, passed, failed
with its rules and evidence, and what a producer logs with :meth:`McapRecorder.log`.

An MCAP metadata record named ``mcp-conform`` (written first, so a truncated file keeps it)
holds the tool and spec versions, who recorded (``recorder``: runner, mcp-node, mcp-fuzz),
the target, role and seed where they apply. Where the runner spawned the node, a record
``mcp-conform run delay`` (:data:`RUN_DELAY_METADATA`) gives the node's run delay (D-7) as it
stopped it: a stall after the node's last datagram, which no datagram carries; a reader that
does not know it reads the file as before.

``log_time`` is the run clock (``time.time_ns()``) given by the caller, so a case's
``capture`` range in the JSON report finds its traffic. The recorder is thread-safe (the
driver's receiver thread calls it) and ``close()`` is idempotent; it is also called at
interpreter exit, so a run interrupted by an exception or SIGTERM leaves a valid file.
:class:`BackgroundRecorder` (same methods) hands the work to a writer process, for nodes
where recording must cost the hot path almost nothing. ``live`` (``--live``,
:mod:`traceio.live`): every message written is also handed, the same bytes, to a Foxglove
WebSocket server's feed; a recorder of no file (``path`` None) feeds only that.
"""

from __future__ import annotations

import base64
import json
import platform
import threading
import time
from collections.abc import Iterable, Mapping
from pathlib import Path
from typing import IO, Any

from mcap.writer import CompressionType, Writer

from mcp_conform.spec.codec import Action, DecodeError, MissionItem, decode, peek_header
from mcp_conform.traceio import fox
from mcp_conform.traceio.channels import (
    CHANNELS,
    HEX_LIMIT,
    STREAM_CHANNELS,
    StreamTopics,
    foxglove_channels,
    stream_channels,
    stream_topics,
)
from mcp_conform.traceio.files import ClosedAtExit
from mcp_conform.traceio.merge import SEGMENT

__all__ = [
    "CHANNELS",
    "FUZZ_RECORDER",
    "HEX_LIMIT",
    "METADATA_NAME",
    "NODE_METADATA",
    "RUN_DELAY_METADATA",
    "McapRecorder",
    "RecorderError",
    "STREAM_CHANNELS",
    "datagram_record",
    "foxglove_channels",
    "mavlink_type",
    "run_delay_metadata",
    "recorded_run_delay",
    "run_metadata",
    "summarize_payload",
]

PROFILE = "mcp-conform"
METADATA_NAME = "mcp-conform"
#: the recorder a fuzz finding's repro.mcap names (``mcp-capture replay`` reproduces those)
FUZZ_RECORDER = "mcp-fuzz"
#: The metadata record naming the node under test (``id``, ``address`` host:port) of a run.
NODE_METADATA = "mcp-conform node"
#: The metadata record of a node's run delay (D-7) read without a datagram -- as the runner
#: stops a spawned node (``harness.session_base``): ``id``, ``run_delay_ns``, ``t_ns`` (the run
#: clock). A stall after the node's last datagram shows only here (``Monitor.run_delay``).
RUN_DELAY_METADATA = "mcp-conform run delay"

#: case outcome -> foxglove.Log level of its end mark
_OUTCOME_LEVEL = {"passed": "info", "skipped": "info", "warned": "warning", "failed": "error", "error": "error"}
_MAX_ITEMS = 16  # payload summary: mission items listed in full up to this many


class RecorderError(Exception):
    """The capture file cannot be written (one line, names the file)."""


def _item(item: MissionItem) -> dict[str, Any]:
    return {k: (round(v, 7) if isinstance(v, float) else v) for k, v in item._asdict().items()}


def summarize_payload(payload: Any) -> Any:
    """A JSON-able summary of a decoded payload (see ``spec.codec.Message``)."""
    if payload is None or isinstance(payload, (int, str)):
        return payload
    if isinstance(payload, (bytes, bytearray)):
        return {"mavlink_frame_len": len(payload), "hex": bytes(payload).hex()}
    if isinstance(payload, MissionItem):
        return _item(payload)
    if isinstance(payload, (tuple, list)):
        items = [_item(i) if isinstance(i, MissionItem) else repr(i) for i in payload[:_MAX_ITEMS]]
        return {"count": len(payload), "items": items}
    return repr(payload)


def _action_name(code: int | None) -> str | None:
    if code is None:
        return None
    try:
        return Action(code).name
    except ValueError:
        return None


def _peer(addr: Any) -> str:
    if isinstance(addr, (tuple, list)) and len(addr) >= 2:
        return f"{addr[0] or '0.0.0.0'}:{addr[1]}"
    return "" if addr is None else str(addr)


def encode_body(body: Mapping[str, Any]) -> bytes:
    """A message's JSON body as the recorder writes it (compact separators)."""
    return json.dumps(body, separators=(",", ":")).encode()


def datagram_record(direction: str, data: bytes, addr: Any, local: Any = None) -> dict[str, Any]:
    """The JSON body of one ``/mcp/tx`` or ``/mcp/rx`` message (``addr``: the peer)."""
    data = bytes(data)
    rec: dict[str, Any] = {
        "direction": direction, "peer": _peer(addr), "local": _peer(local) if local else None,
        "length": len(data), "decoded": False,
        "dst": None, "src": None, "seq": None, "action": None, "action_name": None,
        "payload": None, "error_rule": None, "error_reason": None,
    }
    try:
        msg = decode(data)
    except DecodeError as exc:
        rec["error_rule"], rec["error_reason"] = exc.rule, exc.reason
        header = peek_header(data)
        if header is not None:
            rec["dst"], rec["src"], rec["seq"], rec["action"] = header
            rec["action_name"] = _action_name(header[3])
    except Exception as exc:  # a codec bug must not lose the datagram
        rec["error_rule"], rec["error_reason"] = None, f"{type(exc).__name__}: {exc}"
    else:
        rec.update(decoded=True, dst=msg.dst, src=msg.src, seq=msg.seq, action=int(msg.action),
                   action_name=_action_name(int(msg.action)), payload=summarize_payload(msg.payload))
    rec["raw_base64"] = base64.b64encode(data).decode("ascii")
    if len(data) <= HEX_LIMIT:
        rec["raw_hex"] = data.hex()
    return rec


_MAV_NAMES: dict[int, str] | None = None


def mavlink_type(frame: bytes) -> str | None:
    """The message name of a MAVLink v1/v2 frame from its msgid (ardupilotmega), else None."""
    global _MAV_NAMES
    if _MAV_NAMES is None:
        from pymavlink.dialects.v20 import ardupilotmega as mavlink2

        _MAV_NAMES = {mid: cls.msgname for mid, cls in mavlink2.mavlink_map.items()}
    if len(frame) >= 6 and frame[0] == 0xFE:
        msgid = frame[5]
    elif len(frame) >= 10 and frame[0] == 0xFD:
        msgid = frame[7] | frame[8] << 8 | frame[9] << 16
    else:
        return None
    return _MAV_NAMES.get(msgid)


def run_metadata(recorder: str, **values: Any) -> dict[str, str]:
    """The ``mcp-conform`` metadata record: tool and spec versions, who recorded, and
    ``values`` (target, role, seed, ...; None values are left out), all as strings."""
    from mcp_conform.spec import SPEC
    from mcp_conform.spec.about import TOOL_NAME, tool_version

    meta = {"tool": TOOL_NAME, "tool_version": tool_version(), "spec_version": SPEC.version,
            "spec_sha256": SPEC.sha256, "recorder": recorder, "host": platform.node(),
            "started_utc": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime())}
    for key, value in values.items():
        if value is not None:
            meta[key] = value if isinstance(value, str) else json.dumps(value)
    return meta


def run_delay_metadata(node_id: int, run_delay_ns: int, t_ns: int) -> dict[str, str]:
    """The :data:`RUN_DELAY_METADATA` record's values: node ``node_id`` had ``run_delay_ns``
    of run delay at ``t_ns``."""
    return {"id": str(int(node_id)), "run_delay_ns": str(int(run_delay_ns)), "t_ns": str(int(t_ns))}


def recorded_run_delay(values: Mapping[str, str]) -> tuple[int, int, int] | None:
    """``(t_ns, node_id, run_delay_ns)`` of a :data:`RUN_DELAY_METADATA` record's values;
    None where they do not read as one (a record written by something else is ignored)."""
    try:
        t_ns, node, ns = int(values["t_ns"]), int(values["id"]), int(values["run_delay_ns"])
    except (KeyError, ValueError):
        return None
    return (t_ns, node, ns) if ns >= 0 else None


#: the recorders open, closed at interpreter exit: an interrupted run still leaves valid files
OPEN = ClosedAtExit("close")


class McapRecorder:
    """Writes one MCAP file; every method may be called from any thread.

    ``metadata``: the ``mcp-conform`` metadata record (see :func:`run_metadata`), written
    first. ``local``: the recording socket's address, the default ``local`` of datagrams.
    ``live``: a feed (``traceio.live.LiveFeed``: ``publish(topic, data, t_ns)``) handed every
    message as it is written, the same bytes (``--live``); ``path`` None: no file, only the feed.
    """

    def __init__(self, path: str | Path | None, *, library: str = "mcp-conform",
                 metadata: Mapping[str, str] | None = None, local: Any = None, live: Any = None) -> None:
        self.path = Path(path) if path is not None else None
        self.local = local
        self._live = live
        self._lock = threading.Lock()
        self._closed = False
        self._fox = foxglove_channels()
        self.counts: dict[str, int] = {topic: 0 for topic in {**CHANNELS, **self._fox}}
        self._seq = 0
        self._channels: dict[str, int] = {}
        self._schemas: dict[str, int] = {}
        self.segment: str | None = None
        self._writer: Writer | None = None
        if self.path is None:
            OPEN.add(self)
            return
        try:
            self._file: IO[bytes] = open(self.path, "wb")  # noqa: SIM115 - closed in close()
        except OSError as exc:
            raise RecorderError(f"--capture: cannot write {str(self.path)!r}: {exc.strerror}") from None
        try:
            compression = CompressionType.LZ4
            import lz4  # noqa: F401
        except ImportError:
            compression = CompressionType.NONE
        self._writer = Writer(self._file, compression=compression, chunk_size=256 * 1024)
        self._writer.start(profile=PROFILE, library=library)
        if metadata:
            self._writer.add_metadata(METADATA_NAME, {str(k): str(v) for k, v in metadata.items()})
        self._register_channels({})
        OPEN.add(self)

    def _register_channels(self, metadata: Mapping[str, str]) -> None:
        if self._writer is None:
            return
        schemas = self._schemas
        for topic, (name, schema) in {**CHANNELS, **self._fox}.items():
            if name not in schemas:
                schemas[name] = self._writer.register_schema(
                    name=name, encoding="jsonschema", data=json.dumps(schema).encode())
            self._channels[topic] = self._writer.register_channel(
                topic=topic, message_encoding="json", schema_id=schemas[name], metadata=dict(metadata))

    def begin_segment(self, name: str, metadata: Iterable[tuple[str, Mapping[str, Any]]] = ()) -> None:
        """From now on every record belongs to session ``name`` of the file (its channels
        carry ``segment: name``, as a merged capture's workers' do: ``traceio.merge``), and
        so do the ``metadata`` records given (name, values): a reader gives each session
        apart and the judge judges each on its own (a run that restarts its node for a fresh
        mission: each mission is a session). Streams opened later (``/nsqd``) stay unsegmented."""
        with self._lock:
            if self._closed:
                return
            self._register_channels({SEGMENT: name})
            self.segment = name
            for md_name, values in metadata:
                if self._writer is not None:
                    self._writer.add_metadata(md_name, {**{str(k): str(v) for k, v in values.items()}, SEGMENT: name})

    # ------------------------------------------------------------------ writing
    @property
    def closed(self) -> bool:
        return self._closed

    def _write(self, topic: str, body: dict[str, Any], t_ns: int | None) -> None:
        self.write_encoded(topic, encode_body(body), t_ns)

    def write_encoded(self, topic: str, data: bytes, t_ns: int | None) -> None:
        """A message of ``topic`` whose JSON body is already ``encode_body``'s bytes (a
        generator of large captures, bench/, writes the bodies it varies without a
        ``json.dumps`` each)."""
        t = int(t_ns) if t_ns is not None else time.time_ns()
        with self._lock:
            if self._closed:
                return
            self._seq += 1
            if self._writer is not None:
                self._writer.add_message(channel_id=self._channels[topic], log_time=t, data=data,
                                         publish_time=t, sequence=self._seq)
            self.counts[topic] = self.counts.get(topic, 0) + 1
            if self._live is not None:  # the same bytes, in the same order (--live)
                try:
                    self._live.publish(topic, data, t)
                except Exception:  # noqa: BLE001 - a viewer's trouble never costs the capture
                    pass

    def datagram(self, direction: str, data: bytes, addr: Any, t_ns: int | None = None,
                 local: Any = None, run_delay: int | None = None) -> None:
        """One datagram: ``direction`` is ``tx`` (the recording endpoint sent it) or ``rx``;
        ``addr`` is the peer, ``local`` the recording socket (default: ``self.local``);
        ``run_delay``: its sender's run delay (ns) as it came, when known (MCP-RTX-3)."""
        if direction not in ("tx", "rx"):
            raise ValueError(f"datagram direction must be 'tx' or 'rx', not {direction!r}")
        record = datagram_record(direction, data, addr, self.local if local is None else local)
        if run_delay is not None:
            record["run_delay_ns"] = int(run_delay)
        self._write(f"/mcp/{direction}", record, t_ns)

    def burst(self, direction: str, cycle: Iterable[bytes], count: int, addr: Any,
              first_t_ns: int, last_t_ns: int, local: Any = None) -> None:
        """``count`` datagrams sent (or received) as one burst, cycling through ``cycle``."""
        if direction not in ("tx", "rx"):
            raise ValueError(f"burst direction must be 'tx' or 'rx', not {direction!r}")
        local = self.local if local is None else local
        datagrams = [datagram_record(direction, d, addr, local) for d in cycle]
        body = {"direction": direction, "peer": _peer(addr), "local": _peer(local) if local else None,
                "count": int(count), "first_t_ns": int(first_t_ns), "last_t_ns": int(last_t_ns),
                "cycle": datagrams}
        self._write("/mcp/burst", body, first_t_ns)

    def stream_frame(self, direction: str, raw: bytes, *, protocol: str, conn: int, peer: Any,
                     msg_id: int | None = None, name: str | None = None, fields: Mapping[str, Any] | None = None,
                     problem: str | None = None, t_ns: int | None = None) -> None:
        """Bytes on a connection of the stream protocol ``protocol`` (its ``tx``: one write of
        the runner; ``rx``: one frame of the backend; ``traceio.channels.stream_topics``), with
        what they decode to."""
        if direction not in ("tx", "rx"):
            raise ValueError(f"stream direction must be 'tx' or 'rx', not {direction!r}")
        topics = self._stream_channels(protocol)
        body = {"direction": direction, "conn": int(conn), "peer": _peer(peer), "msg_id": msg_id, "name": name,
                "fields": dict(fields) if fields is not None else None, "problem": problem, "length": len(raw),
                "raw_base64": base64.b64encode(bytes(raw)).decode("ascii")}
        self._write(topics.tx if direction == "tx" else topics.rx, body, t_ns)

    def stream_event(self, event: str, *, protocol: str, conn: int, peer: Any = None, local: Any = None,
                     by: str | None = None, how: str | None = None, t_ns: int | None = None) -> None:
        """A connection of the stream protocol ``protocol`` opened (``open``: its addresses) or
        closed (``close``: ``by`` client or backend, ``how`` fin or rst), on its ``conn`` topic."""
        if event not in ("open", "close"):
            raise ValueError(f"stream event must be 'open' or 'close', not {event!r}")
        topics = self._stream_channels(protocol)
        self._write(topics.conn, {"event": event, "conn": int(conn), "peer": _peer(peer),
                                   "local": _peer(local) if local else None, "by": by, "how": how}, t_ns)

    def _stream_channels(self, protocol: str) -> StreamTopics:
        """``protocol``'s stream topics, its channels registered at the first call."""
        topics = stream_topics(protocol)
        with self._lock:
            if self._closed or topics.tx in self._channels or self._writer is None:
                return topics
            schemas: dict[str, int] = {}
            for t, (sname, schema) in stream_channels(protocol).items():
                if sname not in schemas:
                    schemas[sname] = self._writer.register_schema(name=sname, encoding="jsonschema",
                                                                  data=json.dumps(schema).encode())
                self._channels[t] = self._writer.register_channel(topic=t, message_encoding="json",
                                                                  schema_id=schemas[sname])
                self.counts.setdefault(t, 0)
        return topics

    def impairment(self, decision: Any, data: bytes, t_ns: int | None = None) -> None:
        """What an impaired link did to ``data`` (a ``harness.impair.Decision``)."""
        body = {**decision.to_json(), "raw_base64": base64.b64encode(bytes(data)).decode("ascii")}
        self._write("/impair", body, t_ns)

    def vehicle_event(self, kind: str, t_ns: int | None = None, drone: int | None = None,
                      detail: str | None = None) -> None:
        """An event of the autopilot link the run's monitor was given (link, fix, fix_lost)."""
        self._write("/vehicle", {"kind": kind, "drone": drone, "detail": detail}, t_ns)

    def mavlink(self, direction: str, frame: bytes, t_ns: int | None = None,
                msg_type: str | None = None, drone: int | None = None) -> None:
        """One frame on the autopilot link (``rx``: the autopilot received it, ``tx``: sent)."""
        if direction not in ("tx", "rx"):
            raise ValueError(f"mavlink direction must be 'tx' or 'rx', not {direction!r}")
        raw = bytes(frame)
        t = int(t_ns) if t_ns is not None else time.time_ns()
        message, error = fox.mavlink_dict(raw)
        body = {"direction": direction, "msg_type": msg_type or mavlink_type(raw), "length": len(raw),
                "drone": drone, "message": message, "decode_error": error,
                "raw_base64": base64.b64encode(raw).decode("ascii")}
        self._write("/mavlink", body, t)
        if message is not None and direction == "tx" and self._fox:  # what the autopilot reports
            location = fox.location_body(t, message, drone)
            if location is not None:
                self._write(fox.LOCATION, location, t)
            attitude = fox.attitude_body(t, message, drone)
            if attitude is not None:
                self._write(fox.ATTITUDE, attitude, t)

    def log(self, message: str, level: str = "info", name: str = "mcp-conform", t_ns: int | None = None) -> None:
        """An event for Foxglove's Log panel (``/log``, ``foxglove.Log``): ``level`` debug,
        info, warning, error or fatal; ``name`` who logs it (runner, mcp-fuzz, ...)."""
        try:
            fox.log_level(level)  # a bad level is the caller's error (ValueError), SDK or not
        except ImportError:  # no foxglove-sdk: no /log channel either (self._fox is False)
            pass
        if self._fox:
            t = int(t_ns) if t_ns is not None else time.time_ns()
            self._write(fox.LOG, fox.log_body(t, level, message, name), t)

    def case_mark(self, case_id: str, event: str, t_ns: int | None = None,
                  outcome: str | None = None, rules: tuple[str, ...] | list[str] = (),
                  evidence: str | None = None) -> None:
        """A case's ``start`` or ``end`` (the end carries the outcome, and why it failed in
        ``evidence`` where the caller knows it), also as a line of ``/log``."""
        if event not in ("start", "end"):
            raise ValueError(f"case_mark event must be 'start' or 'end', not {event!r}")
        t = int(t_ns) if t_ns is not None else time.time_ns()
        body: dict[str, Any] = {"case": case_id, "event": event, "outcome": outcome, "rules": list(rules)}
        if evidence is not None:
            body["evidence"] = evidence
        self._write("/conformance/case", body, t)
        ruled = f" [{', '.join(rules)}]" if rules else ""
        if event == "start":
            self.log(f"{case_id}: started{ruled}", "info", "case", t)
        else:
            text = f"{case_id}: {outcome or 'ended'}{ruled}" + (f": {evidence}" if evidence else "")
            self.log(text, _OUTCOME_LEVEL.get(outcome or "", "info"), "case", t)

    def add_metadata(self, name: str, values: Mapping[str, Any]) -> None:
        """A further MCAP metadata record (string values), of the current session
        (:meth:`begin_segment`) if any."""
        with self._lock:
            if not self._closed and self._writer is not None:
                seg = {SEGMENT: self.segment} if self.segment is not None else {}
                self._writer.add_metadata(name, {**{str(k): str(v) for k, v in values.items()}, **seg})

    def close(self) -> None:
        """Write the summary and footer; safe to call more than once and from any thread."""
        with self._lock:
            if self._closed:
                return
            self._closed = True
            if self._writer is None:
                OPEN.discard(self)
                return
            try:
                self._writer.finish()
            finally:
                self._file.close()
                OPEN.discard(self)

    def __enter__(self) -> McapRecorder:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
