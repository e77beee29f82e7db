"""Why a node never announced: what the runner observed during a startup that failed.

A drone application waits on its autopilot before it announces Mission_Ready (MCP-BLK-5:
"A drone announces Mission_Ready only once its autopilot reports a GPS fix"; DroneKit's
``is_armable``, MAVSDK's ``health().is_armable``, ...). When it never announces, "no
Mission_Ready within N s" alone leaves its author guessing; the runner saw more: whether the
node reached the simulated vehicle and over which transport, the frames it sent there, what
it asked the autopilot and what it was answered (the vehicle's ``request`` events,
``vehicle.records.describe_request``), whether the vehicle had a fix, and what reached the
runner. ``explain`` says that in a dozen lines at most, with a one-line hint. Where the runner
gave the node no vehicle (no ``--mavlink``, or attach mode: the node's autopilot is its own)
there are no vehicle records, and it says so (attach mode in three short lines, which the
session folds into the error's one line: an attached target's errors stay one line).
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Sequence
from typing import Any

from pymavlink.dialects.v20 import ardupilotmega as mavlink2

from mcp_conform.spec.codec import Action

__all__ = ["explain", "explain_session", "startup_detail"]

#: Distinct frame kinds and distinct requests listed before "and N more".
MAX_FRAME_KINDS = 8
MAX_REQUESTS = 4
#: Commands whose first parameter is a message id (MAVLink's "Command Protocol" pages:
#: MAV_CMD_REQUEST_MESSAGE, MAV_CMD_SET_MESSAGE_INTERVAL): named in the frame counts.
_MESSAGE_ID_COMMANDS = frozenset({mavlink2.MAV_CMD_REQUEST_MESSAGE, mavlink2.MAV_CMD_SET_MESSAGE_INTERVAL})


def _command_name(cmd: int) -> str:
    entry = mavlink2.enums["MAV_CMD"].get(cmd)
    return entry.name if entry is not None else f"MAV_CMD({cmd})"


def frame_kind(frame: Any) -> str:
    """A received frame's type; a command's also names the command (and the message it
    asks for): ``COMMAND_LONG MAV_CMD_REQUEST_MESSAGE(148 AUTOPILOT_VERSION)``."""
    if frame.msg_type not in ("COMMAND_LONG", "COMMAND_INT"):
        return str(frame.msg_type)
    cmd = int(frame.fields.get("command", -1))
    kind = f"{frame.msg_type} {_command_name(cmd)}"
    if cmd in _MESSAGE_ID_COMMANDS:
        msgid = int(frame.fields.get("param1", 0) or 0)
        cls = mavlink2.mavlink_map.get(msgid)
        kind += f"({msgid} {cls.msgname})" if cls is not None else f"({msgid})"
    return kind


def _counted(items: Sequence[str], limit: int) -> list[str]:
    """Distinct items in first-seen order with their counts, at most ``limit``."""
    counts = Counter(items)
    out = [f"{k} ×{n}" if n > 1 else k for k, n in counts.items()]
    if len(out) > limit:
        out = out[:limit] + [f"and {len(out) - limit} more"]
    return out


def _runner_side(datagrams: Sequence[Any], listen: str) -> str:
    if not datagrams:
        return f"to the runner: no datagram at {listen}"
    names = []
    for d in datagrams:
        try:
            names.append(Action(d.action).name if d.action is not None else "unreadable")
        except ValueError:
            names.append(f"action {d.action}")
    none = "" if "MISSION_READY" in names else ", none a Mission_Ready"  # (a later failure's: it did)
    return f"to the runner: {len(datagrams)} datagram(s){none}: " + ", ".join(_counted(names, MAX_FRAME_KINDS))


def _vehicle_lines(vehicle: Any, url: str, t0: float, fix_given_at: float | None,
                   fix_hold: float) -> tuple[list[str], bool, bool]:
    """(lines, connected, asked): the node's link to the vehicle, its frames, requests, fix."""
    lines: list[str] = []
    connects = vehicle.events("connect")
    if not connects:
        lines.append(f"autopilot: the node never connected to the simulated vehicle at {url} "
                     "(its {mavlink})")
    else:
        c = connects[0]
        link = (f"autopilot: the node connected to the simulated vehicle over "
                f"{c.detail.get('transport', '?')} from {c.detail.get('peer', '?')}, "
                f"{max(c.t - t0, 0.0):.1f} s after it started")
        if len(connects) > 1:
            link += f" ({len(connects)} connections)"
        gone = vehicle.events("disconnect")
        if gone and not vehicle.connected:
            link += f"; it went away {max(gone[-1].t - t0, 0.0):.1f} s after it started"
        lines.append(link)
        frames = [frame_kind(f) for f in vehicle.frames()]
        lines.append("it sent the vehicle: " + (", ".join(_counted(frames, MAX_FRAME_KINDS))
                                                 if frames else "no MAVLink frame"))
    asked = [_describe(e) for e in vehicle.events("request")]
    if asked:
        lines += [f"it asked: {a}" for a in _counted(asked, MAX_REQUESTS)]
    elif connects:
        lines.append("it asked the autopilot nothing (no command, mode or mission request)")
    fixes = vehicle.events("fix")
    since = fix_given_at if fix_given_at is not None else (fixes[-1].t if fixes else None)
    if vehicle.has_fix and since is not None:
        lines.append(f"the vehicle reported a 3D GPS fix from {max(since - t0, 0.0):.1f} s "
                     "after the node started")
    elif connects:
        lines.append(f"the vehicle had no GPS fix yet: the runner withholds it for {fix_hold:g} s after "
                     "the node connects (MCP-BLK-5: no Mission_Ready before the fix)")
    else:
        lines.append("the vehicle had no GPS fix: the runner gives it once the node has connected "
                     "to the vehicle (MCP-BLK-5 is watched until then)")
    return lines, bool(connects), bool(asked)


def _describe(event: Any) -> str:
    from mcp_conform.vehicle.records import describe_request

    return describe_request(event)


def explain(*, vehicle: Any, mavlink_url: str, mavlink: bool, spawned: bool,
            datagrams: Sequence[Any], t0: float, listen: str, exited: bool,
            fix_given_at: float | None = None, fix_hold: float = 0.0) -> list[str]:
    """What the runner observed while it waited for the node's Mission_Ready (``t0``: when
    the node started; ``datagrams``: what reached the runner meanwhile; ``exited``: the node
    process is gone; ``fix_given_at``: when the runner gave the vehicle its fix, ``fix_hold``
    how long after the node's connection it withholds it), ending with a one-line hint. At most a dozen lines."""
    lines: list[str] = []
    connected = asked = False
    if vehicle is not None:
        vlines, connected, asked = _vehicle_lines(vehicle, mavlink_url, t0, fix_given_at, fix_hold)
        lines += vlines
    elif spawned:
        lines.append("autopilot: none given (no --mavlink), so there are no vehicle records")
    else:
        lines.append("attach mode, so no vehicle records")
    lines.append(_runner_side(datagrams, listen))
    if exited:
        hint = "the node exited: its own words are below"
    elif vehicle is not None and not connected:
        hint = (f"the node never reached the vehicle: does it take the {{mavlink}} placeholder "
                f"({mavlink_url}) as its autopilot's address?")
    elif vehicle is not None and not datagrams:
        hint = ("the node connected to the vehicle but never sent a datagram to the runner: is it "
                "waiting for a readiness check" + (" (see what it asked above)?" if asked else "?"))
    elif datagrams:  # (one that announced it failed later: the error's line says how)
        hint = ("the node announced Mission_Ready: the error says what went wrong after it"
                if any(d.action == int(Action.MISSION_READY) for d in datagrams)
                else "the node speaks to the runner but never announced Mission_Ready")
    elif spawned and not mavlink:
        hint = ("the node sent the runner nothing: if it waits on an autopilot, run with --mavlink "
                "and give it {mavlink}")
    else:
        hint = "is the node running, and does it send there?"
    return lines + [f"hint: {hint}"]


def explain_session(session: Any, datagrams: Sequence[Any]) -> list[str]:
    """``explain`` for a ``harness.drone_session.Session`` in its first startup (``datagrams``: what
    reached the runner since it began); never raises: an explanation that cannot be read
    says so in one line, and the error it explains stands."""
    try:
        drv, node = session.driver, session.node
        return explain(vehicle=session.vehicle, mavlink_url=session.mavlink_url,
                       mavlink=bool(session.cfg.mavlink), spawned=session.spawned, datagrams=datagrams,
                       t0=session.startup_window[0], listen=f"{drv.listen[0] or '0.0.0.0'}:{drv.listen[1]}",
                       exited=node is not None and not node.alive(),
                       fix_given_at=session.startup_fix_at, fix_hold=session.fix_hold)
    except Exception as exc:  # noqa: BLE001  (an explanation never hides the error it explains)
        return [f"(what the runner observed could not be read: {type(exc).__name__}: {exc})"]


def startup_detail(session: Any) -> list[str]:
    """What the runner observed in a ``harness.drone_session.Session``'s first startup
    (:func:`explain_session` of what reached it since the startup began; [] after it), and where
    the node's first instance gave up short of MCP-RTX-1's copies and was restarted
    (``harness.drone_giveup``), what it did."""
    if session._startup_mark is None or session.driver is None:
        return []
    gave_up = getattr(session.startup, "gave_up", None)
    return (explain_session(session, session.driver.received(session._startup_mark))
            + ([f"MCP-RTX-1: its first instance: {gave_up}; restarted with its Mission_Ready ACKed at once"]
               if gave_up else []))
