"""The judge's parameters: what a capture is judged with (MCP-ACK-1/2's window, the
retransmission timeout of MCP-RTX-1..3, the broadcast ID of D-1, the mission's drones and
challenge for MCP-FLOW-4/5/6, the waypoints for MCP-PAY), and the command-line options that set
them, shared by ``mcp-capture check`` and ``show``.

A value the user gave wins; the others are taken from the capture's own record of the run
(``Params.adopt``, ``Params.adopt_mission``), so that a run is judged offline with its live
timings. Bad values are :class:`traceio.files.UsageError` (one line, exit 2).
"""

from __future__ import annotations

import argparse
from dataclasses import dataclass
from typing import Any

from mcp_conform.spec.codec import BROADCAST_ID, MANAGER_ID
from mcp_conform.traceio.files import UsageError

__all__ = ["Params", "add_monitor_options", "params_from_args", "selected"]


@dataclass
class Params:
    """What a capture is judged with; ``given`` names the parameters the user set."""

    rto: float = 5.0
    ack_window: float = 2.0
    broadcast_id: int = BROADCAST_ID
    drones: tuple[int, ...] | None = None
    challenge: int | None = None
    challenge_source: str = "given"  # given | recorded (the run's, from the capture) | inferred | unknown
    challenge_note: str = ""
    waypoints: tuple[Any, ...] | None = None
    waypoints_file: str | None = None
    select: tuple[str, ...] = ()
    strict: bool = False
    complete: bool = False  # the trace holds every datagram the nodes exchanged
    #: ``rto`` is the nodes' own timeout, as the run that set them up declared it with the rto
    #: it recorded (``Monitor(rto_declared=)``; the check report's parameters carry it, schema 1.4)
    rto_declared: bool = False
    #: the parameters the user gave; the others are taken from the capture's own record of
    #: the run (our MCAP captures), so that a run is judged offline with its live timings
    given: frozenset[str] = frozenset()
    from_capture: tuple[str, ...] = ()  # the parameters taken from the capture

    def adopt(self, recorded: dict[str, Any]) -> None:
        """Take the run's recorded ``rto``, ``ack_window`` and ``broadcast_id`` where the user
        gave none (an unusable value is left alone): what the run's own monitor judged with --
        the rto as the nodes' declared timeout where the run said so (``rto_declared``)."""
        taken = []
        for key in ("rto", "ack_window"):
            v = recorded.get(key)
            if key not in self.given and isinstance(v, (int, float)) and 0 < v < 1e6:
                setattr(self, key, float(v))
                taken.append(key)
        if "rto" in taken and recorded.get("rto_declared") is True:  # the run's own, declared
            self.rto_declared = True
        v = recorded.get("broadcast_id")
        if "broadcast_id" not in self.given and isinstance(v, int) and 1 <= v <= 0xFFFF:
            self.broadcast_id = v
            taken.append("broadcast_id")
        self.from_capture = tuple(taken)

    def adopt_mission(self, challenge: int | None, items: tuple[Any, ...] | None) -> None:
        """The challenge and the items the run's manager was handed (a manager-role session's
        record), where the user gave none: what the run's monitor judged MCP-FLOW-4/5/6 by."""
        taken = []
        if challenge is not None and "challenge" not in self.given and self.challenge is None:
            self.challenge, self.challenge_source = challenge, "recorded"
            taken.append("challenge")
        if items is not None and self.waypoints is None:
            self.waypoints = items
            taken.append("waypoints")
        self.from_capture = (*self.from_capture, *taken)

    def to_json(self) -> dict[str, Any]:
        return {"from_capture": list(self.from_capture), "rto": self.rto, "ack_window": self.ack_window, "broadcast_id": self.broadcast_id,
                "drones": list(self.drones) if self.drones is not None else None,
                "challenge": self.challenge, "challenge_source": self.challenge_source,
                "challenge_note": self.challenge_note or None, "waypoints": self.waypoints_file,
                "select": list(self.select), "strict": self.strict, "complete": self.complete}


def add_monitor_options(p: argparse.ArgumentParser) -> None:
    p.add_argument("--rto", metavar="S", help="the nodes' retransmission timeout (default 5)")
    p.add_argument("--ack-window", metavar="S", help="how long 'no reply' is watched (default 2)")
    p.add_argument("--challenge", metavar="N", help="the mission's challenge, 1-3 (default: inferred "
                   "from the manager's commands)")
    p.add_argument("--drones", metavar="1,2,...", help="the drones of the mission (default: those seen)")
    p.add_argument("--waypoints", metavar="FILE", help="what the mission should carry (QGC WPL 110), "
                   "for MCP-FLOW-4/5/6 and MCP-PAY")
    p.add_argument("--broadcast-id", metavar="N", help="the broadcast MCP ID (default 65535, D-1)")
    p.add_argument("--select", metavar="PREFIX", action="append", default=[],
                   help="report only rules starting with PREFIX (MCP-ACK, ACK-1, ...); repeatable")
    p.add_argument("--exclude", metavar="PREFIX", action="append", default=[],
                   help="leave out rules starting with PREFIX; repeatable")
    p.add_argument("--strict", action="store_true", help="a violated SHOULD is a failure")
    p.add_argument("--complete", action="store_true", help="the capture holds every datagram the nodes "
                   "exchanged (taken on the one host where they all run): a missing ACK or retransmission "
                   "is then evidence (our MCAP captures are complete by nature)")


def _positive(name: str, text: str | None, default: float) -> float:
    if text is None:
        return default
    try:
        value = float(text)
    except ValueError:
        raise UsageError(f"{name}: not a number: {text!r}") from None
    if not value > 0 or value == float("inf"):
        raise UsageError(f"{name}: must be a positive number of seconds: {text!r}")
    return value


def _int(name: str, text: str, lo: int, hi: int) -> int:
    try:
        value = int(text, 0)
    except ValueError:
        raise UsageError(f"{name}: not an integer: {text!r}") from None
    if not lo <= value <= hi:
        raise UsageError(f"{name}: {value} is outside {lo}-{hi}")
    return value


def params_from_args(ns: argparse.Namespace) -> Params:
    p = Params(rto=_positive("--rto", ns.rto, 5.0), ack_window=_positive("--ack-window", ns.ack_window, 2.0),
               strict=bool(getattr(ns, "strict", False)),
               select=tuple(getattr(ns, "select", None) or ()) + tuple("!" + x for x in getattr(ns, "exclude", None) or ()),
               complete=bool(getattr(ns, "complete", False)),
               given=frozenset(k for k in ("rto", "ack_window", "broadcast_id", "drones", "challenge")
                               if getattr(ns, k, None) is not None))
    if getattr(ns, "broadcast_id", None) is not None:
        p.broadcast_id = _int("--broadcast-id", ns.broadcast_id, 1, 0xFFFF)
    if ns.challenge is not None:
        p.challenge = _int("--challenge", ns.challenge, 1, 3)
    if ns.drones is not None:
        words = [w for w in ns.drones.replace(" ", "").split(",") if w]
        if not words:
            raise UsageError(f"--drones: no drone IDs in {ns.drones!r}")
        ids = tuple(_int("--drones", w, 1, 0xFFFE) for w in words)
        if MANAGER_ID in ids or p.broadcast_id in ids or len(set(ids)) != len(ids):
            raise UsageError(f"--drones: IDs must be distinct drone IDs (not 0 or the broadcast ID): {ns.drones!r}")
        p.drones = ids
    if ns.waypoints is not None:
        from mcp_conform.spec.mission import WaypointFileError, load_waypoints

        try:
            p.waypoints = tuple(load_waypoints(ns.waypoints))
        except (WaypointFileError, OSError, ValueError) as exc:
            raise UsageError(f"--waypoints: {_one_line(exc)}") from None
        p.waypoints_file = str(ns.waypoints)
    return p


def _one_line(exc: BaseException) -> str:
    text = str(exc).strip().splitlines()
    return text[0] if text else type(exc).__name__


def selected(rule: str, select: tuple[str, ...]) -> bool:
    """Whether ``rule`` (MCP-ACK-1) matches one of the prefixes (MCP-ACK, ACK-1, ACK) and none
    of the excluded ones (``--exclude``, kept in ``select`` as ``!PREFIX``)."""
    if not select:
        return True
    short = rule[4:] if rule.startswith("MCP-") else rule
    chosen = [s for s in select if not s.startswith("!")]
    left_out = [s[1:] for s in select if s.startswith("!")]
    return ((not chosen or any(rule.startswith(s) or short.startswith(s) for s in chosen))
            and not any(rule.startswith(s) or short.startswith(s) for s in left_out))
