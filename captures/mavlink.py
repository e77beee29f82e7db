"""``mcp-capture check|show|diff --protocol mavlink``: the capture tools MAVLink's profile names
(``spec.profiles``), which ``captures.cli.capture_tools`` hands each subcommand
(``captures.cli.CaptureTools``), as MCP's are ``captures.mcp`` and Nsqd's ``captures.nsqd``.
:func:`is_capture` is how the profile recognises its traces.

A trace is our MCAP's ``/mavlink`` channel (``mcp-conform --protocol mavlink --capture``; the
autopilot link of an MCP drone run) or a telemetry log (``.tlog``: MAVProxy, QGroundControl,
Mission Planner), read by ``traceio.mavlink``.

- ``check``: every frame judged by the MAVLink trace monitor (``judge.mavlink_monitor``), the
  judge a run's frames can be fed live too. A capture of ``mcp-conform`` says which role was
  under test (its metadata): that role's rules are judged; a tlog's every node is judged by
  its role (the vehicle's and the ground station's rules). Exit 0 no MUST broken (no SHOULD
  either under ``--strict``), 1 broken, 2 unreadable. ``--select``/``--exclude`` pick rules,
  ``--json OUT`` writes the result. A truncated trace is judged up to its last whole record
  and reads INCOMPLETE, never OK.
- ``show``: one line per frame (``--from``/``--to`` seconds, ``--case ID`` of our MCAP), the
  monitor's violations marked on their frames.
- ``diff``: the two traces' microservice conversations (commands, parameters, missions: which
  message with which values; heartbeats and telemetry streams left out, as are sequence
  numbers, target IDs and times), sender by sender (the vehicle's, the ground station's),
  aligned by ``difflib``. Exit 0 same, 1 different.
- ``export`` and ``replay`` are not MAVLink's (one line, exit 2).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from mcp_conform.captures import trace_tools as core
from mcp_conform.captures.trace_tools import Checked
from mcp_conform.judge.mavlink_monitor import MavlinkMonitor
from mcp_conform.judge.verdicts import of_mavlink
from mcp_conform.spec import MAVLINK
from mcp_conform.traceio.mavlink import MavFrame, MavTrace, is_mavlink_capture, open_trace
from mcp_conform.traceio.reader import CaptureError
from mcp_conform.traceio.traces import recorded

__all__ = ["PLUGIN", "is_capture", "judge_trace"]

DIALECT: Any = MAVLINK.dialect
#: the messages of the microservices a diff compares (the spec's services, HEARTBEAT and the
#: vehicle's periodic reports left out)
CONVERSATION = frozenset(m.name for m in MAVLINK.messages) - {"HEARTBEAT", "MISSION_CURRENT", "STATUSTEXT",
                                                              "MISSION_ITEM_REACHED"}
_NOT_COMPARED = {"mavpackettype", "target_system", "target_component"}


#: MAVLink's ``capture_detect``: a tlog, or our MCAP of a MAVLink run
is_capture = is_mavlink_capture


def _role_under_test(trace: MavTrace) -> str | None:
    """The role whose rules an MCAP is judged by: its run's (``mcp-conform --role``) when the
    run was MAVLink's; the vehicle's when it was another protocol's (the autopilot link of an
    MCP drone run: its other side is the node under test and the runner's own probes, which
    MAVLink's rules do not judge); None for a tlog (every node by its role)."""
    role = recorded(trace.path, "role") if trace.format == "mcap" else None
    return role if role is None or role in MAVLINK.roles else "vehicle"


def judge_trace(path: str | Path, *, keep: bool = False) -> core.Judged:
    """``path`` read and judged (``keep``: its frames kept, for show and diff)."""
    trace = open_trace(path)
    role = _role_under_test(trace)
    mon = MavlinkMonitor(roles=(role,) if role else ("vehicle", "gcs"), complete=trace.complete)
    j = core.judge_records(core.Judged(str(path), trace.format, mon, role), trace, MavFrame, keep=keep)
    if not j.count:
        raise CaptureError(f"{path}: no MAVLink frame in it (an MCAP of mcp-conform --protocol mavlink, "
                           "or a .tlog, holds them)")
    mon.finish()
    return j


def _node_line(n: dict[str, Any]) -> str:
    """One node of ``MavlinkMonitor.to_json()`` (its sessions summed)."""
    what = ""
    if n["type"] is not None:
        t, a = n["type"], n["autopilot"]
        types, stacks = DIALECT.enums["MAV_TYPE"], DIALECT.enums["MAV_AUTOPILOT"]
        what = f" {types[t].name if t in types else t}, {stacks[a].name if a in stacks else a},"
    return f"  {n['id']} {n['role'] or '?'}{what} {n['frames']} frame(s), {n['heartbeats']} HEARTBEAT(s)"


class _Mavlink(core.CapturePlugin):
    name, spec, a_capture, html_instead, EXPORTED = "mavlink", MAVLINK, "a MAVLink trace", "use --json", "frames"
    unchartered = "is not drawn for a MAVLink trace"
    unexported = ("a MAVLink trace is not exported as pcap (its frames have no UDP datagrams of their own; show and "
                  "diff read it as it is)")
    unreplayed = ("a MAVLink trace is not replayed here (judge it with check; a MAVLink fuzz finding replays with "
                  "mcp-fuzz --protocol mavlink --replay FINDING)")
    steps_called, steps_aside = "microservice message(s)", " (heartbeats and telemetry not compared)"

    def check(self, ns: Any) -> Checked:
        j = judge_trace(ns.file)
        mon = j.monitor
        v = of_mavlink(mon, core.selection(ns), strict=core.strict(ns), truncated=j.truncated)
        nodes = mon.to_json()["nodes"]
        notes = ([f"{mon.unattributed_bad} stretch(es) of bytes that are no frame (a tlog does not say who sent "
                  "them: not judged)"] if mon.unattributed_bad else []) + \
            ([] if mon.complete else ["MAV-HB-11 (sequence numbers) is judged only on a trace that holds every frame "
                                      "of its link (our MCAP): a tlog's gap may be a frame lost on the way"])
        seconds = ((mon.last_ns or 0) - j.first_ns) / 1e9
        who = f"the {j.role}'s rules" if j.role else "every node by its role"
        return core.checked(self, ns, v, [f"{j.path}: MAVLink trace ({j.format}), {j.count} frame(s) over "
                                          f"{seconds:.1f} s; judged: {who}", *(_node_line(n) for n in nodes[:30])],
                            {"path": j.path, "format": j.format, "truncated": j.truncated, "notes": notes,
                             "unattributed": mon.unattributed_bad, "duration_s": round(seconds, 9)},
                            {"complete": mon.complete, "roles": list(mon.roles)}, nodes, first_ns=j.first_ns,
                            own={"frames": j.count, "failed_count": v.counts}, more=lambda f: {"case": j.case_at(f.t_ns)},
                            line=lambda f: core.found_line(f"node {f.node} ({dict(f.more)['role']})", f, j.first_ns,
                                                           j.case_at(f.t_ns)))

    judged = staticmethod(judge_trace)

    def header(self, j: core.Judged) -> str:
        return f"{j.path}: MAVLink trace ({j.format}), {j.count} frame(s)"

    def frame_line(self, f: MavFrame, j: core.Judged) -> str:
        if f.bad:
            return f"#{f.index} bad data ({getattr(f.msg, 'reason', '?')}): {f.raw[:24].hex(' ')}"
        role = j.monitor.role_of(f.source) or "?"
        fields = {k: v for k, v in f.msg.to_dict().items() if k != "mavpackettype"}
        text = ", ".join(f"{k}={v}" for k, v in fields.items())
        return f"#{f.index} {f.source[0]}/{f.source[1]} {role} {f.name} v{f.version} seq {f.msg.get_seq()}: " \
               f"{text[:160]}{'…' if len(text) > 160 else ''}"

    def steps(self, j: core.Judged) -> dict[str, list[tuple[str, str]]]:
        """The microservice messages of a trace by the role of their sender, each role's in order:
        (key compared, line shown). Compared sender by sender, as MCP's diff does: the order
        between the two sides is the recorder's (an answer may be stamped before its request,
        ``judge.mavlink_monitor.ORDER_SLACK_S``), each side's own order is the sender's."""
        steps: dict[str, list[tuple[str, str]]] = {}
        for f in j.frames:
            if f.bad or f.name not in CONVERSATION:
                continue
            role = j.monitor.role_of(f.source) or "?"
            fields = {k: v for k, v in f.msg.to_dict().items() if k not in _NOT_COMPARED}
            text = f"{f.name} " + ", ".join(f"{k}={v}" for k, v in fields.items())
            steps.setdefault(role, []).append((text, f"#{f.index} +{(f.t_ns - j.first_ns) / 1e9:.3f}s {role} {text}"))
        return steps


PLUGIN = _Mavlink()
